import os
import subprocess
import sys

import errno

import pytest
from typer.testing import CliRunner

from flows.cli import app
from schemas.errors import EXIT_BUSY, EXIT_ENVIRONMENT, EXIT_INTERRUPTED, EXIT_NOT_BUILT, Busy, NotBuilt
from schemas.manifest import manifest_hash
from tasks.manifests import load

from tests.support import MANIFESTS, REPO

runner = CliRunner()
GOOD = MANIFESTS / "conveyor_push.yaml"


def test_invalid_manifest_is_one_line_exit_2_and_nothing_written(tmp_path, data_root):
    bad = tmp_path / "bad.yaml"
    bad.write_text(GOOD.read_text().replace("resolution: [128, 128]", "resolution: [100000, 100000]"))
    for args in (["manifest", "validate", str(bad)], ["register", str(bad)], ["manifest", "hash", str(bad)]):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, args
        lines = [line for line in result.output.splitlines() if line.strip()]
        assert len(lines) == 1 and str(bad) in lines[0] and "cameras.0.resolution" in lines[0]
    assert not (data_root / "lineage.duckdb").exists()


def test_validate_hash_and_show():
    shipped = sorted(MANIFESTS.glob("*.yaml"))
    result = runner.invoke(app, ["manifest", "validate", *map(str, shipped)])
    assert len(shipped) >= 3 and result.exit_code == 0 and result.output.count("ok ") == len(shipped)
    result = runner.invoke(app, ["manifest", "hash", str(GOOD)])
    assert result.output.strip() == manifest_hash(load(GOOD))
    result = runner.invoke(app, ["manifest", "show", str(GOOD)])
    assert manifest_hash(load(GOOD)) in result.output and "controller_noise" in result.output


def test_evaluate_is_a_group_with_physics():
    result = runner.invoke(app, ["evaluate", "--help"])
    assert result.exit_code == 0 and "physics" in result.output


def test_unknown_audit_lists_the_available_ones(data_root):
    result = runner.invoke(app, ["audit", "no_such_audit"])
    assert result.exit_code == 2
    assert "unknown audit" in result.output and "ancestry" in result.output and "rejections" in result.output


def test_audit_without_warehouse_is_a_clear_error(data_root):
    for args in (["audit", "rejections", "--manifest", "a" * 64], ["summary"]):
        result = runner.invoke(app, args)
        assert result.exit_code == EXIT_NOT_BUILT and "no warehouse here yet (run a flow first)" in result.output


def test_console_script_runs():
    result = subprocess.run([sys.executable, "-m", "flows.cli", "manifest", "hash", str(GOOD)],
                            capture_output=True, text=True, cwd=REPO, timeout=120)
    assert result.returncode == 0 and len(result.stdout.strip()) == 64


def test_invalid_curate_config_is_one_line_exit_2_and_nothing_written(tmp_path, data_root):
    from tests.support import scene_frames, write_video

    video = write_video(tmp_path / "clip.mp4", scene_frames(0, n=8))
    bad = tmp_path / "curate.yaml"
    bad.write_text("scenes: {detectr: content}\n")
    for args in (["scenes", str(video)], ["inspect", str(video)], ["curate", str(video)]):
        result = runner.invoke(app, [*args, "--config", str(bad)])
        assert result.exit_code == 2, args
        lines = [line for line in result.output.splitlines() if line.strip()]
        assert len(lines) == 1 and str(bad) in lines[0] and "scenes.detectr" in lines[0], result.output
    assert not (data_root / "lineage.duckdb").exists()


def test_a_manifest_whose_robot_files_are_missing_is_refused_before_simulating(tmp_path, data_root, monkeypatch):
    monkeypatch.setenv("WORLDLINE_ROBOTS_ROOT", str(tmp_path / "robots"))
    manifest = tmp_path / "ur5e.yaml"
    manifest.write_text((MANIFESTS / "bin_pick_dim_forklift.yaml").read_text().replace(
        "robot: builtin_arm", "robot: ur5e\n  mjcf: universal_robots_ur5e/ur5e.xml"))
    for args in (["simulate", str(manifest)], ["panels", str(manifest)], ["evaluate", "policies", str(manifest)],
                 ["evaluate", "physics", str(manifest)], ["train-policy", str(manifest)], ["loop", str(manifest)]):
        result = runner.invoke(app, args)
        lines = [line for line in result.output.splitlines() if line.strip()]
        assert result.exit_code == 2 and len(lines) == 1, (args, result.output)
        assert str(manifest) in lines[0] and "embodiment.mjcf 'universal_robots_ur5e/ur5e.xml'" in lines[0]
    assert not (data_root / "lineage.duckdb").exists()


def test_audit_takes_an_id_prefix_and_refuses_an_unknown_format(prefect_harness, data_root):
    assert runner.invoke(app, ["register", str(GOOD)]).exit_code == 0
    digest = manifest_hash(load(GOOD))
    full = runner.invoke(app, ["audit", "manifest_artifacts", "--manifest", digest, "--format", "json"])
    short = runner.invoke(app, ["audit", "manifest_artifacts", "--manifest", digest[:12], "--format", "json"])
    assert full.exit_code == short.exit_code == 0 and digest in full.output and short.output == full.output
    bad = runner.invoke(app, ["audit", "manifest_artifacts", "--manifest", digest, "--format", "xml"])
    assert bad.exit_code == 2 and "one of table, csv, json" in bad.output
    for option, given in (("--manifest", "deadbeef" * 2), ("--manifest", "f" * 64), ("--artifact", "nope")):
        audit = "runs" if option == "--manifest" else "ancestry"
        unknown = runner.invoke(app, ["audit", audit, option, given])  # printed 0 rows, exit 0
        assert unknown.exit_code == 2 and unknown.output.strip() == f"{option} {given}: no such {option[2:]} in lineage"


def test_prefect_logs_an_input_error_in_one_line_from_the_cli():
    import logging

    from flows.cli import _InputErrorsInOneLine

    def record(error):
        try:
            raise error
        except Exception:
            return logging.LogRecord("prefect.flow_runs", logging.ERROR, __file__, 1, "failed", None, sys.exc_info())

    refused, crashed = record(FileNotFoundError("x.yaml: no such file")), record(RuntimeError("a bug"))
    assert _InputErrorsInOneLine().filter(refused) and _InputErrorsInOneLine().filter(crashed)
    assert refused.exc_info is None and "Traceback" not in logging.Formatter().format(refused)
    assert crashed.exc_info is not None and "Traceback" in logging.Formatter().format(crashed)
    # what the CLI states again as it exits (in the same words) does not reach the terminal twice
    from flows.console import ConsoleLog
    from schemas.errors import EnvironmentFault

    faulted, full = record(EnvironmentFault("r/lineage.duckdb: damaged")), record(OSError(28, "No space left", "/r/x"))
    for kept in (faulted, full):
        assert _InputErrorsInOneLine().filter(kept) and kept.exc_info is None and kept.restated
        assert not ConsoleLog().filter(kept)  # the API's handler has no such filter: Prefect's UI keeps the line
    assert not refused.restated and ConsoleLog().filter(refused) and ConsoleLog().filter(crashed)


def test_a_failed_flow_from_the_cli_ends_without_traceback_or_binding_noise(tmp_path):
    fake = tmp_path / "fake.parquet"
    fake.write_text("hello\n")
    env = {**os.environ, "WORLDLINE_DATA_ROOT": str(tmp_path / "root")}
    result = subprocess.run([sys.executable, "-m", "flows.cli", "tokenize", str(fake), "--steps", "1"],
                            capture_output=True, text=True, cwd=REPO, env=env, timeout=300)
    output = result.stdout + result.stderr
    assert result.returncode == 2 and f"{fake}: " in output, output
    assert "Traceback" not in output and "nanobind" not in output, output


def test_a_wrong_setting_is_named_in_one_line(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    for env, problem in (({"WORLDLINE_WORKERS": "abc"}, "WORLDLINE_WORKERS='abc': Input should be a valid integer"),
                         ({"WORLDLINE_DATA_ROOT": str(a_file)}, f"Prefect's home {a_file}/prefect")):
        inherited = {k: v for k, v in os.environ.items() if k != "PREFECT_HOME"}  # set by this session
        result = subprocess.run([sys.executable, "-m", "flows.cli", "summary"], capture_output=True, text=True,
                                cwd=REPO, env={**inherited, **env}, timeout=120)
        assert result.returncode == 2 and result.stderr.strip().splitlines() == [result.stderr.strip()], result.stderr
        assert problem in result.stderr


def test_curate_refuses_folders_without_videos(tmp_path, data_root):
    (tmp_path / "empty").mkdir()
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "readme.txt").write_text("no footage here")
    result = runner.invoke(app, ["curate", str(tmp_path / "empty"), str(tmp_path / "notes")])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1 and "no videos there" in lines[0], result.output
    assert not (data_root / "lineage.duckdb").exists()


# -- issue 26: each exit code, and one line for each -----------------------------------------------
def _lines(result) -> list[str]:
    return [line for line in result.output.splitlines() if line.strip()]


def test_a_busy_data_root_is_exit_4_in_one_line_before_prefect_starts(data_root, monkeypatch):
    from tests.warehouse.test_lock import hold_in_another_process

    holder = hold_in_another_process(data_root, 30)
    monkeypatch.setenv("WORLDLINE_LOCK_TIMEOUT", "1")
    try:
        result = runner.invoke(app, ["register", str(GOOD)])
    finally:
        holder.kill()
        holder.wait()
    lines = _lines(result)
    assert result.exit_code == EXIT_BUSY, result.output
    assert lines[0] == f"{data_root}: another worldline process (pid {holder.pid}, command -c {data_root} 30) is " \
                       "writing; waiting up to 1 s"
    assert lines[1:] == [f"{data_root}: another worldline process (pid {holder.pid}, command -c {data_root} 30) "
                         "is writing; waited 1 s (WORLDLINE_LOCK_TIMEOUT)"]
    assert not (data_root / "lineage.duckdb").exists() and not (data_root / "prefect" / "prefect.db").exists()


def test_a_damaged_warehouse_raised_inside_the_flow_is_exit_5_in_one_line(prefect_harness, tmp_path):
    """recorded_run refuses the warehouse inside the flow run (EnvironmentFault); Prefect hands
    the error back to the command as itself, which ends with its line and its code. The command
    uses the session's Prefect API (no temporary server of its own to start: ~20 s saved)."""
    import numpy as np
    from prefect.settings import PREFECT_API_URL

    root = tmp_path / "root"
    root.mkdir()
    damaged = root / "lineage.duckdb"
    damaged.write_bytes(np.random.default_rng(5).integers(0, 256, 300_000, np.uint8).tobytes())
    env = {k: v for k, v in os.environ.items() if not k.startswith(("WORLDLINE_", "PREFECT_"))}
    result = subprocess.run([sys.executable, "-m", "flows.cli", "register", str(GOOD)], capture_output=True, text=True,
                            cwd=REPO, env={**env, "WORLDLINE_DATA_ROOT": str(root),
                                           "PREFECT_API_URL": PREFECT_API_URL.value()}, timeout=300)
    assert result.returncode == EXIT_ENVIRONMENT, result.stdout + result.stderr
    assert result.stderr.strip().splitlines()[-1].startswith(f"{damaged}: the warehouse is damaged (")
    assert "Traceback" not in result.stdout + result.stderr


@pytest.mark.parametrize("error, code, line", [
    (Busy("root: another worldline process (pid 1, command x) is writing; waited 60 s"), EXIT_BUSY,
     "root: another worldline process (pid 1, command x) is writing; waited 60 s"),
    (NotBuilt("no token shards: run `worldline tokenize` first"), EXIT_NOT_BUILT,
     "no token shards: run `worldline tokenize` first"),
    (OSError(errno.ENOSPC, "No space left on device", "/data/shards/x.parquet"), EXIT_ENVIRONMENT,
     "disk full: /data/shards/x.parquet"),
    (OSError(errno.EDQUOT, "Disk quota exceeded", "/data/x"), EXIT_ENVIRONMENT, "disk full: /data/x"),
    (KeyboardInterrupt(), EXIT_INTERRUPTED, "interrupted by SIGINT"),  # whatever Prefect printed it as
])
def test_what_a_command_raises_sets_its_exit_code_and_one_line(data_root, monkeypatch, error, code, line):
    import flows.register

    def flow(path):
        raise error

    monkeypatch.setattr(flows.register, "register", flow)
    result = runner.invoke(app, ["register", str(GOOD)])
    assert result.exit_code == code, result.output
    assert _lines(result) == ([line] if line else []), result.output


def test_sigterm_raised_as_terminated_is_exit_143(data_root, monkeypatch):
    import flows.register
    from flows.ephemeral import Terminated

    def flow(path):
        raise Terminated()

    monkeypatch.setattr(flows.register, "register", flow)
    result = runner.invoke(app, ["register", str(GOOD)])
    assert result.exit_code == 143 and _lines(result) == ["interrupted by SIGTERM"], result.output


def test_other_errors_keep_their_traceback(data_root, monkeypatch):
    import flows.register

    def flow(path):
        raise OSError(errno.EACCES, "Permission denied", "/x")

    monkeypatch.setattr(flows.register, "register", flow)
    result = runner.invoke(app, ["register", str(GOOD)])
    assert result.exit_code == 1 and isinstance(result.exception, PermissionError)


def test_validate_refuses_a_robot_file_that_leaves_the_robots_root(tmp_path, monkeypatch):
    root, outside = tmp_path / "robots", tmp_path / "outside"
    (root / "arm").mkdir(parents=True)
    outside.mkdir()
    (outside / "arm.xml").write_text("<mujoco/>")
    (root / "arm" / "arm.xml").symlink_to(outside / "arm.xml")
    monkeypatch.setenv("WORLDLINE_ROBOTS_ROOT", str(root))
    text = (MANIFESTS / "bin_pick_dim_forklift.yaml").read_text()
    manifest = tmp_path / "arm.yaml"
    manifest.write_text(text.replace("  robot: builtin_arm\n", "  robot: ur5e\n  mjcf: arm/arm.xml\n"))
    result = runner.invoke(app, ["manifest", "validate", str(manifest)])
    assert result.exit_code == 2, result.output
    line, = result.output.strip().splitlines()
    assert line.startswith(f"{manifest}: embodiment.mjcf 'arm/arm.xml': ") and "outside the robots root" in line
    (root / "arm" / "arm.xml").unlink()  # a robot file missing here is the machine's matter, not the manifest's
    assert runner.invoke(app, ["manifest", "validate", str(manifest)]).exit_code == 0

"""`worldline export lerobot`: a summary line and exit 0; damaged episodes named and exit 1;
mismatched cameras, an occupied --out and unknown sources refused in one line with exit 2; the
task text from the manifest YAML, or from lineage for a manifest named by hash or folder."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pandas as pd
import pytest
from typer.testing import CliRunner

import flows.cli_export  # noqa: F401  (registers `export`, as flows/cli.py does)
from flows.cli import app
from schemas.settings import Settings
from tasks import manifests
from warehouse.store import Warehouse

from tests.support import REPO
from tests.tasks.export.episodes import INSTRUCTION, manifest_file, simulate

pytestmark = pytest.mark.slow  # simulates MuJoCo episodes
runner = CliRunner()


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("root")
    manifest = manifest_file(root / "manifests")
    other = manifest_file(root / "manifests", camera="side", resolution=(48, 32), name="side.yaml")
    return {"root": root, "manifest": manifest, "digest": simulate(root, manifest, seeds=(1, 2)),
            "other": other, "other_digest": simulate(root, other, seeds=(3,))}


@pytest.fixture
def at(world, monkeypatch):
    monkeypatch.setenv("WORLDLINE_DATA_ROOT", str(world["root"]))
    return world


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def _tasks(out) -> list[str]:
    return list(pd.read_parquet(out / "meta" / "tasks.parquet").index)


def test_export_of_a_manifest_writes_the_dataset_and_says_so(at, tmp_path):
    out = tmp_path / "dataset"
    result = runner.invoke(app, ["export", "lerobot", str(at["manifest"]), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert _lines(result.output) == [f"2 episodes (60 frames, 1 tasks) written to {out} as a LeRobot v3.0 dataset; "
                                     "0 damaged episodes skipped"]
    assert _tasks(out) == [INSTRUCTION]
    assert json.loads((out / "meta" / "info.json").read_text())["total_frames"] == 60


def test_the_task_text_of_a_manifest_named_by_hash_comes_from_lineage(at, tmp_path):
    bare = tmp_path / "bare"
    assert runner.invoke(app, ["export", "lerobot", at["digest"][:12], "--out", str(bare)]).exit_code == 0
    assert _tasks(bare) == ["push"]  # lineage has never seen the manifest: meta.json's task kind
    warehouse = Settings().warehouse_path
    try:
        with Warehouse(warehouse) as store:
            store.write(manifests.lineage(manifests.load(at["manifest"])))
        known = tmp_path / "known"
        episodes = at["root"] / "episodes" / at["digest"][:12]
        assert runner.invoke(app, ["export", "lerobot", str(episodes), "--out", str(known)]).exit_code == 0
        assert _tasks(known) == [INSTRUCTION]
    finally:
        for leftover in warehouse.parent.glob(warehouse.name + "*"):
            leftover.unlink()


def test_a_damaged_episode_is_named_the_rest_exported_exit_1(at, tmp_path):
    episodes = tmp_path / "episodes"
    source = at["root"] / "episodes" / at["digest"][:12]
    for name in ("episode_000000", "episode_000001"):
        shutil.copytree(source / name, episodes / name)
    (episodes / "episode_000001" / "steps.parquet").write_bytes(b"\x00" * 64)
    result = runner.invoke(app, ["export", "lerobot", str(episodes), "--out", str(tmp_path / "out")])
    assert result.exit_code == 1
    lines = _lines(result.output)
    assert lines[0].startswith(f"skipped {episodes / 'episode_000001' / 'steps.parquet'}: unreadable")
    assert lines[1].startswith("1 episodes (30 frames, 1 tasks) written to") and "1 damaged episodes skipped" in lines[1]


@pytest.mark.parametrize("case", ["cameras", "occupied", "unknown"])
def test_bad_input_is_one_line_exit_2_and_nothing_written(at, tmp_path, case):
    out = tmp_path / "out"
    args = [str(at["manifest"]), str(at["other"])]
    if case == "occupied":
        out.mkdir()
        (out / "keep.txt").write_text("mine")
        args = [str(at["manifest"])]
    elif case == "unknown":
        args = [str(tmp_path / "nowhere.yaml")]
    result = runner.invoke(app, ["export", "lerobot", *args, "--out", str(out)])
    assert result.exit_code == 2
    lines = _lines(result.output)
    assert len(lines) == 1, lines
    expected = {"cameras": "different cameras", "occupied": "not empty", "unknown": "no such file or folder"}[case]
    assert expected in lines[0]
    if case == "cameras":
        assert at["digest"][:12] in lines[0] and at["other_digest"][:12] in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == (["out"] if case == "occupied" else [])


def test_the_console_script_lists_the_export_command():
    done = subprocess.run([str(REPO / ".venv" / "bin" / "worldline"), "export", "--help"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0 and "lerobot" in done.stdout


@pytest.mark.parametrize("sig, code", [("SIGTERM", 143), ("SIGINT", 130)])
def test_a_signal_while_writing_leaves_no_staging_folder(at, tmp_path, sig, code):
    """SIGTERM killed an export outright (no handler): its staging folder beside --out stayed,
    and the next export, under another pid, never removed it."""
    out = tmp_path / "dataset"
    script = f"""
import os, signal, sys
import tasks.export.lerobot as lerobot
write = lerobot.write_lerobot
def interrupted(*args, **kwargs):
    write(*args, **kwargs)  # the staging folder is full: the signal comes before it is published
    os.kill(os.getpid(), signal.{sig})
lerobot.write_lerobot = interrupted
sys.argv = ["worldline", "export", "lerobot", {str(at["manifest"])!r}, "--out", {str(out)!r}]
from flows.cli import main
main()
"""
    done = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "WORLDLINE_DATA_ROOT": str(at["root"])})
    assert done.returncode == code, done.stderr[-2000:]
    assert _lines(done.stderr)[-1] == f"interrupted by {sig}" and "Traceback" not in done.stderr
    assert list(tmp_path.iterdir()) == []  # neither the dataset nor its staging folder

"""Bad paths given to `worldline` are refused in one line naming the file or option, exit 2,
never a traceback: a video too small to judge (`inspect`), an `--out` of `controls` that is not
a folder or cannot be made, a `--data-root` (or WORLDLINE_DATA_ROOT) that is a file or cannot be made."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from flows.cli import app
from schemas.errors import EXIT_INVALID

from tests.support import REPO, scene_frames, write_video

runner = CliRunner()


def lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def tree(folder: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else None for p in sorted(folder.rglob("*"))}


def test_inspect_of_a_video_too_small_to_judge_is_one_line_exit_2(tmp_path, data_root):
    # 2 x 2 px, five seconds of one colour: one scene, whose frames the filters cannot judge
    video = write_video(tmp_path / "tiny.mp4", [np.full((2, 2, 3), 120, np.uint8)] * 150, fps=30)
    for fmt in ("table", "json"):
        result = runner.invoke(app, ["inspect", str(video), "--format", fmt])
        assert result.exit_code == EXIT_INVALID, (result.output, result.exception)
        said = lines(result.output)
        assert len(said) == 1 and said[0].startswith(f"{video}: ") and "16x16" in said[0], result.output
    assert not (data_root / "lineage.duckdb").exists()


@pytest.fixture
def clip(tmp_path) -> Path:
    return write_video(tmp_path / "clip.mp4", scene_frames(0, n=8))


def _refused(args: list[str], folder: Path, data_root: Path) -> str:
    before = tree(folder)
    result = runner.invoke(app, args)
    assert result.exit_code == EXIT_INVALID, (result.output, result.exception)
    said = lines(result.output)
    assert len(said) == 1 and said[0].startswith("--out "), result.output
    assert tree(folder) == before  # nothing written: no controls, no folders, no lineage
    assert not (data_root / "lineage.duckdb").exists()
    return said[0]


def test_controls_out_that_is_a_file_is_refused_before_any_work(tmp_path, clip, data_root):
    taken = tmp_path / "taken"
    taken.write_text("mine\n")
    said = _refused(["controls", str(clip), "--out", str(taken)], tmp_path, data_root)
    assert said == f"--out {taken}: exists and is not a folder"
    said = _refused(["controls", str(clip), "--out", str(taken / "sub" / "dir")], tmp_path, data_root)
    assert said == f"--out {taken / 'sub' / 'dir'}: cannot be created: {taken} is not a folder"
    assert taken.read_text() == "mine\n"


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="no /proc here")
def test_controls_out_that_cannot_be_created_is_refused_before_any_work(tmp_path, clip, data_root):
    said = _refused(["controls", str(clip), "--out", "/proc/self/nope"], tmp_path, data_root)
    assert said.startswith("--out /proc/self/nope: cannot be created in /proc/self: ")
    assert not Path("/proc/self/nope").exists()


def test_controls_out_check_takes_new_and_existing_folders_and_leaves_nothing(tmp_path):
    from flows.cli_controls import check_out

    (tmp_path / "there").mkdir()
    for folder in (tmp_path / "there", tmp_path / "new" / "deeper", Path("relative-not-there")):
        check_out(str(folder))
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["there"] and not Path("relative-not-there").exists()
    assert not any((tmp_path / "there").iterdir())


def _worldline(args: list[str], **env: str | None) -> subprocess.CompletedProcess:
    """The real command in its own process (a variable is read on import); None drops a variable."""
    env = {k: v for k, v in {**os.environ, "COLUMNS": "200", **env}.items() if v is not None}
    return subprocess.run([sys.executable, "-m", "flows.cli", *args], capture_output=True, text=True, cwd=REPO,
                          timeout=300, env=env)


@pytest.mark.parametrize("where", ["file", "proc"])
@pytest.mark.parametrize("given", ["option", "variable"])
def test_a_data_root_that_cannot_be_a_folder_is_one_line_exit_2(tmp_path, where, given):
    if where == "proc" and not Path("/proc").is_dir():
        pytest.skip("no /proc here")
    root = tmp_path / "a file" if where == "file" else Path("/proc/nope")
    if where == "file":
        root.write_text("mine\n")
    if given == "option":  # PREFECT_HOME as flows/__init__.py set it from the (good) variable: it follows the option
        result = _worldline(["--data-root", str(root), "summary"])
    else:
        result = _worldline(["summary"], WORLDLINE_DATA_ROOT=str(root), PREFECT_HOME=None)
    assert result.returncode == EXIT_INVALID, result.stderr
    said = lines(result.stdout + result.stderr)
    assert len(said) == 1 and "Traceback" not in result.stderr, result.stderr
    assert f"{root}/prefect" in said[0] and "cannot be created" in said[0]
    if given == "option":
        assert said[0].startswith(f"--data-root {root}: ")
    if where == "file":
        assert root.read_text() == "mine\n"

"""The LeRobot export of simulated episodes: its layout and values checked against the episode
files, damaged episodes left out and named, mismatched episodes and occupied folders refused,
and the real `lerobot` package (.venv-lerobot, built by `make lerobot-env`) loading the export
and iterating it through a DataLoader with decoded video frames."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import av
import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from schemas.errors import InvalidInput, StepMissing
from tasks.export.frames import steps_at
from tasks.export.run import export_lerobot

from tests.support import REPO
from tests.tasks.export.episodes import INSTRUCTION, manifest_file, simulate

pytestmark = pytest.mark.slow  # simulates MuJoCo episodes
LEROBOT_PYTHON = REPO / ".venv-lerobot" / "bin" / "python"
# `make lerobot-env` writes .installed-lerobot-<version> once lerobot and its decoder import.
LEROBOT_READY = any((REPO / ".venv-lerobot").glob(".installed-lerobot-*"))
CAMERA = "observation.images.overhead"


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A data root with two episodes of one manifest and one of a manifest whose camera differs."""
    root = tmp_path_factory.mktemp("root")
    manifest = manifest_file(root / "manifests")
    digest = simulate(root, manifest, seeds=(1, 2))
    other = manifest_file(root / "manifests", camera="side", resolution=(48, 32), name="side.yaml")
    other_digest = simulate(root, other, seeds=(3,))
    return {"root": root, "manifest": manifest, "digest": digest, "other": other, "other_digest": other_digest,
            "episodes": root / "episodes" / digest[:12]}


@pytest.fixture(scope="module")
def exported(world, tmp_path_factory):
    out = tmp_path_factory.mktemp("exports") / "dataset"
    result = export_lerobot([str(world["manifest"])], out, world["root"])
    return result, out


def _frames(path: Path) -> list[np.ndarray]:
    with av.open(str(path)) as container:
        return [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]


def test_layout_and_info_are_lerobot_v3(exported):
    result, out = exported
    assert result.skipped == [] and result.exported.episodes == 2 and result.exported.frames == 60
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 30 and info["robot_type"] == "builtin_arm"
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (2, 60, 1)
    assert info["splits"] == {"train": "0:2"}
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert info["video_path"] == "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    features = info["features"]
    for name in ("timestamp", "frame_index", "episode_index", "index", "task_index"):
        assert features[name]["shape"] == [1]
    assert features["observation.state"]["dtype"] == features["action"]["dtype"] == "float32"
    video = features[CAMERA]
    assert video["dtype"] == "video" and video["shape"] == [48, 64, 3]
    assert video["info"]["video.codec"] == "h264" and video["info"]["video.pix_fmt"] == "yuv420p"
    for number in (0, 1):
        assert (out / f"videos/{CAMERA}/chunk-000/file-{number:03d}.mp4").is_file()
    assert sorted(p.name for p in out.parent.iterdir()) == ["dataset"]  # no temporary folder left


def test_rows_are_the_steps_in_force_at_each_video_frame(exported, world):
    _, out = exported
    table = pq.read_table(out / "data/chunk-000/file-000.parquet")
    assert str(table.schema.field("observation.state").type) == "fixed_size_list<element: float>[16]"
    data = table.to_pydict()
    assert data["index"] == list(range(60)) and data["episode_index"] == [0] * 30 + [1] * 30
    assert data["frame_index"] == list(range(30)) * 2 and data["task_index"] == [0] * 60
    np.testing.assert_allclose(data["timestamp"][:30], np.arange(30) / 30, atol=1e-6)
    steps = pq.read_table(world["episodes"] / "episode_000001" / "steps.parquet").to_pydict()
    k = np.floor(np.arange(30) / 30 * 50 + 1e-6).astype(int)  # 50 Hz steps, 30 fps frames
    pos, vel, action = (np.array(steps[c], np.float64)[k] for c in ("joint_pos", "joint_vel", "action"))
    state = np.array(data["observation.state"][30:])
    assert state.dtype == np.float64 and np.array_equal(state, np.concatenate([pos, vel], 1).astype(np.float32))
    assert np.array_equal(np.array(data["action"][30:]), action.astype(np.float32))
    assert np.array_equal(np.array(steps["time"])[k] <= np.arange(30) / 30 + 1e-6, np.ones(30, bool))


def test_steps_at_is_sample_and_hold():
    step_times = np.arange(50) / 50
    frame_times = np.arange(30) / 30
    k = steps_at(step_times, frame_times)
    assert list(k[:7]) == [0, 1, 3, 5, 6, 8, 10]  # frame 3 (0.1 s) and step 5 (0.1 s) are the same instant
    assert np.all(step_times[k] <= frame_times + 1e-6) and np.all(frame_times - step_times[k] < 1 / 50)
    assert list(steps_at(np.array([0.5, 1.0]), np.array([0.0, 0.7, 2.0]))) == [0, 0, 1]


def test_meta_tasks_episodes_and_stats(exported, world):
    _, out = exported
    tasks = pd.read_parquet(out / "meta" / "tasks.parquet")
    assert list(tasks.index) == [INSTRUCTION] and list(tasks["task_index"]) == [0]
    episodes = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [e["episode_index"] for e in episodes] == [0, 1]
    assert [(e["dataset_from_index"], e["dataset_to_index"], e["length"]) for e in episodes] == [(0, 30, 30), (30, 60, 30)]
    assert episodes[1][f"videos/{CAMERA}/file_index"] == 1 and episodes[1][f"videos/{CAMERA}/to_timestamp"] == 1.0
    assert episodes[0]["tasks"] == [INSTRUCTION]
    stats = json.loads((out / "meta" / "stats.json").read_text())
    data = pq.read_table(out / "data/chunk-000/file-000.parquet").to_pydict()
    state = np.array(data["observation.state"], np.float64)
    np.testing.assert_allclose(stats["observation.state"]["mean"], state.mean(0), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(stats["observation.state"]["std"], state.std(0), rtol=1e-6, atol=1e-9)
    assert stats["observation.state"]["count"] == [60] and stats["index"]["max"] == [59.0]
    image = stats[CAMERA]
    assert np.array(image["mean"]).shape == (3, 1, 1) and image["count"] == [60]
    # per channel over every pixel of every frame (64 x 48 is under the subsampling size)
    pixels = np.concatenate([np.stack(_frames(world["episodes"] / f"episode_{i:06d}" / "overhead.mp4"))
                             for i in (0, 1)]).reshape(-1, 3) / 255.0
    np.testing.assert_allclose(np.array(image["mean"]).ravel(), pixels.mean(0), atol=1e-9)
    np.testing.assert_allclose(np.array(image["std"]).ravel(), pixels.std(0), atol=1e-9)
    np.testing.assert_allclose(np.array(image["min"]).ravel(), pixels.min(0))
    assert episodes[0][f"stats/{CAMERA}/count"] == [30]
    provenance = json.loads((out / "meta" / "worldline.json").read_text())["episodes"]
    assert [p["manifest_hash"] for p in provenance] == [world["digest"]] * 2


def test_videos_are_copied_when_lerobot_can_seek_them(exported, world):
    result, out = exported
    assert (result.exported.copied, result.exported.encoded) == (2, 0)
    source = world["episodes"] / "episode_000000" / "overhead.mp4"
    assert (out / f"videos/{CAMERA}/chunk-000/file-000.mp4").read_bytes() == source.read_bytes()


def test_a_video_lerobot_could_not_seek_is_encoded_again(world, tmp_path):
    episodes = tmp_path / "episodes"
    shutil.copytree(world["episodes"] / "episode_000000", episodes / "episode_000000")
    video = episodes / "episode_000000" / "overhead.mp4"
    frames = _frames(video)
    with av.open(str(video), "w") as container:  # yuv444p, which lerobot's info and many decoders do not take
        stream = container.add_stream("libx264", rate=30)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv444p"
        for image in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")))
        container.mux(stream.encode())
    result = export_lerobot([str(episodes)], tmp_path / "out", world["root"])
    assert (result.exported.copied, result.exported.encoded) == (0, 1)
    written = tmp_path / "out" / f"videos/{CAMERA}/chunk-000/file-000.mp4"
    with av.open(str(written)) as container:
        stream = container.streams.video[0]
        assert (stream.codec_context.name, stream.codec_context.pix_fmt) == ("h264", "yuv420p")
        times = [f.time for f in container.decode(stream)]
    np.testing.assert_allclose(times, np.arange(30) / 30, atol=1e-5)
    again = _frames(written)
    assert len(again) == 30 and np.abs(again[10].astype(int) - frames[10]).mean() < 8  # 4:2:0 chroma on 64 x 48


def test_damaged_episodes_are_skipped_and_named_the_rest_exported(world, tmp_path):
    episodes = tmp_path / "episodes"
    for i in (0, 1):
        shutil.copytree(world["episodes"] / f"episode_{i:06d}", episodes / f"episode_{i:06d}")
    shutil.copytree(world["episodes"] / "episode_000000", episodes / "episode_000002")
    shutil.copytree(world["episodes"] / "episode_000000", episodes / "episode_000003")
    cut = episodes / "episode_000001" / "overhead.mp4"
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size // 2])
    (episodes / "episode_000002" / "steps.parquet").write_bytes(b"not parquet")
    (episodes / "episode_000003" / "overhead.mp4").unlink()
    result = export_lerobot([str(episodes)], tmp_path / "out", world["root"])
    assert result.exported.episodes == 1 and len(result.skipped) == 3
    assert str(cut) in result.skipped[0]
    assert "episode_000002/steps.parquet: unreadable" in result.skipped[1]
    assert "episode_000003/overhead.mp4: missing" in result.skipped[2]
    assert json.loads((tmp_path / "out/meta/info.json").read_text())["total_episodes"] == 1


def test_episodes_with_different_cameras_are_refused_in_one_line(world, tmp_path):
    with pytest.raises(InvalidInput) as refused:
        export_lerobot([str(world["manifest"]), str(world["other"])], tmp_path / "out", world["root"])
    line = str(refused.value)
    assert "\n" not in line and "different cameras" in line
    assert world["digest"][:12] in line and world["other_digest"][:12] in line
    assert "overhead 64x48@30" in line and "side 48x32@30" in line
    assert not (tmp_path / "out").exists() and list(tmp_path.iterdir()) == []


def test_the_destination_is_never_overwritten_silently(world, exported, tmp_path):
    _, out = exported
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    with pytest.raises(InvalidInput, match="not empty"):
        export_lerobot([str(world["episodes"])], busy, world["root"])
    with pytest.raises(InvalidInput, match="not an export of this tool"):
        export_lerobot([str(world["episodes"])], busy, world["root"], overwrite=True)
    assert (busy / "notes.txt").read_text() == "mine"
    # Another tool's LeRobot dataset (no meta/worldline.json) was deleted whole by --overwrite.
    theirs = tmp_path / "theirs"
    (theirs / "meta").mkdir(parents=True)
    (theirs / "meta" / "info.json").write_text('{"codebase_version": "v2.1"}')
    (theirs / "raw.bin").write_bytes(b"theirs")
    with pytest.raises(InvalidInput, match="not an export of this tool"):
        export_lerobot([str(world["episodes"])], theirs, world["root"], overwrite=True)
    assert (theirs / "raw.bin").read_bytes() == b"theirs"
    earlier = tmp_path / "earlier"
    shutil.copytree(out, earlier)
    with pytest.raises(InvalidInput, match="--overwrite"):
        export_lerobot([world["other_digest"]], earlier, world["root"])
    # The user's own files inside an earlier export were deleted with it, without a word.
    (earlier / "NOTES.md").write_text("mine")
    (earlier / "mywork").mkdir()
    (earlier / "mywork" / "a.txt").write_text("mine")
    with pytest.raises(InvalidInput, match=r"holds files an export does not write \(NOTES.md, mywork/a.txt\)"):
        export_lerobot([world["other_digest"]], earlier, world["root"], overwrite=True)
    assert (earlier / "NOTES.md").read_text() == "mine" and (earlier / "mywork" / "a.txt").read_text() == "mine"
    shutil.rmtree(earlier / "mywork")
    (earlier / "NOTES.md").unlink()
    export_lerobot([world["other_digest"]], earlier, world["root"], overwrite=True)
    assert json.loads((earlier / "meta/info.json").read_text())["features"]["observation.images.side"]["shape"] == [32, 48, 3]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["busy", "earlier", "theirs"]


def test_every_file_an_export_writes_is_one_overwrite_may_replace(exported):
    from tasks.export.lerobot import EXPORT_FILES

    _, out = exported
    files = [p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()]
    assert files and [f for f in files if not EXPORT_FILES.fullmatch(f)] == []


def test_what_appears_at_the_destination_while_exporting_is_not_replaced(world, tmp_path, monkeypatch):
    """A folder made at --out while the export ran (or another export's) was deleted, without --overwrite."""
    from tasks.export import lerobot

    out = tmp_path / "out"
    write = lerobot.write_lerobot

    def meanwhile(*args, **kwargs):
        done = write(*args, **kwargs)
        out.mkdir()
        (out / "mine.txt").write_text("mine")  # the user, or a second export, got there first
        return done

    monkeypatch.setattr(lerobot, "write_lerobot", meanwhile)
    with pytest.raises(InvalidInput, match="not empty"):
        export_lerobot([str(world["episodes"])], out, world["root"])
    assert (out / "mine.txt").read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_destination_that_cannot_be_made_and_a_killed_exports_staging(world, tmp_path):
    taken = tmp_path / "afile"
    taken.write_text("mine")
    with pytest.raises(InvalidInput, match=r"afile/ds: cannot be created \((File exists|Not a directory)"):
        export_lerobot([str(world["episodes"])], taken / "ds", world["root"])
    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real")
    with pytest.raises(InvalidInput, match="link: a symlink; --out names the folder"):
        export_lerobot([str(world["episodes"])], tmp_path / "link", world["root"])
    dead = tmp_path / ".ds.export-999999999.tmp"  # what a SIGKILLed export left (no such process)
    (dead / "videos").mkdir(parents=True)
    export_lerobot([str(world["episodes"])], tmp_path / "ds", world["root"])
    assert not dead.exists() and taken.read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "ds", "link", "real"]


def test_sources_that_name_no_episodes_are_refused(world, tmp_path):
    with pytest.raises(InvalidInput, match="no such file or folder"):
        export_lerobot([str(tmp_path / "missing")], tmp_path / "out", world["root"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(InvalidInput, match="no episodes in this folder"):
        export_lerobot([str(tmp_path / "empty")], tmp_path / "out", world["root"])
    with pytest.raises(StepMissing, match="run `worldline simulate` first"):
        export_lerobot(["0123456789abcdef"], tmp_path / "out", world["root"])


@pytest.mark.skipif(not LEROBOT_READY, reason=".venv-lerobot is absent (`make lerobot-env` builds it; see "
                    "docs/export.md): the real lerobot package is not there to load the export")
def test_the_real_lerobot_package_loads_the_export_and_iterates_batches(exported, world, tmp_path):
    _, out = exported
    env = {**os.environ, "HF_HOME": str(tmp_path / "hf"), "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}
    env.pop("PYTHONPATH", None)
    done = subprocess.run([str(LEROBOT_PYTHON), str(Path(__file__).with_name("lerobot_reads.py")), str(out)],
                          capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    read = json.loads(done.stdout.strip().splitlines()[-1])
    assert read["lerobot"].startswith("0.4") and read["decoder"] == "torchcodec"
    assert (read["len"], read["episodes"], read["fps"], read["tasks"]) == (60, 2, 30, [INSTRUCTION])
    assert read["shapes"][CAMERA] == [3, 48, 64] and read["dtypes"][CAMERA] == "torch.float32"
    assert read["shapes"]["observation.state"] == [16] and read["dtypes"]["action"] == "torch.float32"
    assert read["stats"][CAMERA]["mean"] == [3, 1, 1]
    rows = read["rows"]
    assert rows["index"] == list(range(60)) and rows["task"] == [INSTRUCTION] * 60
    data = pq.read_table(out / "data/chunk-000/file-000.parquet").to_pydict()
    assert rows["observation.state"] == data["observation.state"] and rows["action"] == data["action"]
    # the decoded frames are the episode's frames at each row's timestamp
    ours = np.concatenate([np.stack(_frames(world["episodes"] / f"episode_{i:06d}" / "overhead.mp4"))
                           for i in (0, 1)]).astype(np.float64) / 255.0
    np.testing.assert_allclose(np.array(rows["image_mean"]), ours.mean(axis=(1, 2)), atol=0.01)
    first = np.array(rows["image_first"]).transpose(1, 2, 0)
    assert np.abs(first - ours[0]).mean() < 0.01

"""Episode files: readable, complete, deterministic; lineage links manifest -> episode -> videos."""

import json

import av
import numpy as np
import pyarrow.parquet as pq
import pytest

from schemas.manifest import manifest_hash
from tasks.manifests import load
from tasks.sim.episode import rollout
from tasks.sim.files import episode_lineage, write_episode

from tests.support import MANIFESTS


@pytest.fixture(scope="module")
def manifest():
    m = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    cams = tuple(c.model_copy(update={"resolution": (64, 48)}) for c in m.cameras)
    return m.model_copy(update={"horizon_s": 1.0, "cameras": cams})


@pytest.fixture(scope="module")
def episode(manifest):
    return rollout(manifest, 7)


def test_files_match_the_episode(tmp_path, manifest, episode):
    digest = manifest_hash(manifest)
    files = write_episode(episode, tmp_path, digest, 0)
    assert set(files.videos) == {c.name for c in manifest.cameras}
    for cam in manifest.cameras:
        with av.open(str(files.videos[cam.name])) as container:
            frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
        assert len(frames) == episode.frames[cam.name].shape[0] == int(manifest.horizon_s * cam.fps)
        assert frames[0].shape == (cam.resolution[1], cam.resolution[0], 3)
        # lossy, but close to what was rendered
        assert np.abs(frames[5].astype(int) - episode.frames[cam.name][5]).mean() < 6
    table = pq.read_table(files.table)
    assert table.num_rows == episode.steps
    assert np.array_equal(np.array(table["action"].to_pylist()), episode.action)
    meta = json.loads(files.meta.read_text())
    assert meta["manifest_hash"] == digest and meta["seed"] == 7 and meta["success"] == episode.success


def test_same_seed_same_bytes_other_seed_differs(tmp_path, manifest, episode):
    digest = manifest_hash(manifest)
    again = rollout(manifest, 7)
    assert np.array_equal(again.action, episode.action) and np.array_equal(again.joint_pos, episode.joint_pos)
    for cam, frames in episode.frames.items():
        assert np.array_equal(again.frames[cam], frames), cam
    a = write_episode(episode, tmp_path / "a", digest, 0)
    b = write_episode(again, tmp_path / "b", digest, 0)
    for cam in a.videos:
        assert a.videos[cam].read_bytes() == b.videos[cam].read_bytes(), cam
    assert a.table.read_bytes() == b.table.read_bytes()
    assert a.meta.read_text() == b.meta.read_text()
    other = rollout(manifest, 8)
    assert not np.array_equal(other.action, episode.action)


def test_lineage_links_manifest_episode_videos(tmp_path, manifest, episode):
    digest = manifest_hash(manifest)
    files = write_episode(episode, tmp_path, digest, 3)
    batch = episode_lineage(files, digest, "stage", tmp_path)
    kinds = sorted(a.kind for a in batch.artifacts)
    assert kinds == ["episode"] + ["episode_video"] * len(manifest.cameras)
    ep = next(a for a in batch.artifacts if a.kind == "episode")
    assert {(e.parent_id, e.child_id) for e in batch.edges} >= {(digest, ep.artifact_id)}
    assert all(not a.uri.startswith("/") for a in batch.artifacts)
    assert {m.name for m in batch.metrics} == {"success", "steps"}


def test_an_episode_missing_a_cameras_frames_is_refused(tmp_path, manifest):
    partial = rollout(manifest, 7, record=("wrist",))
    with pytest.raises(ValueError, match="no frames of camera.s. front_left, front_right"):
        write_episode(partial, tmp_path, manifest_hash(manifest), 0)
    assert not any(tmp_path.iterdir())

"""curate runs both guards by default: faces hidden in kept clips, captions checked, every decision in lineage."""

import pytest

from flows.curate import curate
from schemas.settings import Settings
from tasks.curate.shards import read_shard
from tasks.guard.clip import find_faces
from tasks.guard.config import GuardConfig
from warehouse.store import Warehouse


@pytest.fixture
def carphone(shared_data):
    return shared_data / "videos" / "carphone_pristine.mp4"


def test_faces_are_hidden_and_recorded(prefect_harness, data_root, carphone):
    summary = curate([str(carphone)])
    assert summary["clips"] == 1
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, clips = wh.query("SELECT artifact_id, uri, attrs->>'tags' FROM artifacts WHERE kind = 'clip'")
        _, metrics = wh.query("SELECT name, count(*), sum(value) FROM metrics WHERE name LIKE 'guard_face%' "
                              "GROUP BY name ORDER BY name")
    (clip_id, uri, tags), = clips
    assert "guard:faces_hidden" in tags
    per_frame = dict((name, (n, total)) for name, n, total in metrics)
    assert per_frame["guard_face_boxes"][0] >= 60  # a box on most of the 120 frames, detected or carried
    assert per_frame["guard_faces_frames"] == (1, per_frame["guard_face_boxes"][0])
    assert find_faces(data_root / uri, GuardConfig()) == ()  # searched on every frame: no face left


def test_a_rerun_keeps_the_guard_tag_of_the_clip_it_reuses(prefect_harness, data_root, carphone):
    first = curate([str(carphone)])
    again = curate([str(carphone)])  # the clip file is reused, not encoded again
    assert again["shards"] == first["shards"]  # the same bytes, so the same content-addressed name
    table = read_shard(data_root / again["shards"][0])
    assert "guard:faces_hidden" in table.column("tags").to_pylist()[0]


def test_a_blocked_caption_rejects_the_clip(prefect_harness, data_root, carphone, tmp_path):
    config = tmp_path / "guard.yaml"
    config.write_text("guard: {blocklist: [footage], enabled: true}\n")
    summary = curate([str(carphone)], config=str(config))
    assert summary["clips"] == 0 and summary["counts"]["guard_text/blocked_term"] == 1
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, rows = wh.query("SELECT stage, reason FROM rejections")
    assert rows == [("guard_text", "blocked_term")]

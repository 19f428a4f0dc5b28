"""Guard decisions become warehouse rows that the writer accepts."""

from tasks.guard.config import GuardConfig
from tasks.guard.faces import FaceDecision
from tasks.guard.lineage import face_attrs, face_decisions, text_decisions
from tasks.guard.text import scan_fields
from warehouse.store import Warehouse

CLIP = "c" * 24


def test_text_and_face_decisions_round_trip(tmp_path):
    matches = scan_fields({"caption": "a robot with a gun", "prompt": "fine"})
    blocked = text_decisions(CLIP, matches, manifest_hash="m" * 64)
    (rej,) = blocked.rejections
    assert (rej.stage, rej.reason) == ("guard_text", "blocked_term") and rej.detail.startswith("caption: 'gun'")
    clean = text_decisions("d" * 24, [])
    assert clean.rejections == [] and clean.metrics[0].value == 0

    decisions = [FaceDecision(3, (1, 2, 30, 30)), FaceDecision(3, (40, 2, 30, 30), False), FaceDecision(5, (1, 2, 30, 30))]
    rows = face_decisions(CLIP, decisions)
    per_frame = {m.step: m for m in rows.metrics if m.name == "guard_face_boxes"}
    assert {k: v.value for k, v in per_frame.items()} == {3: 2.0, 5: 1.0}
    assert per_frame[3].attrs["boxes"] == [[1, 2, 30, 30, True], [40, 2, 30, 30, False]]
    summary = {m.name: m.value for m in rows.metrics if m.step == 0 and m.name != "guard_face_boxes"}
    assert summary == {"guard_faces_frames": 2.0, "guard_faces_boxes": 3.0}
    assert face_attrs(decisions, GuardConfig())["guard"]["faces_frames"] == 2

    with Warehouse(tmp_path / "w.duckdb") as wh:
        wh.write(blocked.extend(clean).extend(rows))
        got = wh.con.execute("SELECT reason, detail FROM rejections WHERE stage = 'guard_text'").fetchall()
        assert got == [("blocked_term", rej.detail)]
        n = wh.con.execute("SELECT count(*) FROM metrics WHERE name LIKE 'guard_%'").fetchone()[0]
        assert n == 2 + 4

"""Guard decisions as lineage rows: no table of their own.

- Text (pre-guard): one metric ``guard_text_matches`` per checked subject (0 when clean), and
  when anything matched, one rejection at stage ``guard_text``, reason ``blocked_term``,
  detail listing every ``field: 'term' (found '...')``.
- Faces (post-guard): per frame with a hidden face, metric ``guard_face_boxes`` at step =
  frame index, value = boxes, ``attrs.boxes`` = [[x, y, w, h, detected], ...]; per subject,
  summary metrics ``guard_faces_frames`` and ``guard_faces_boxes`` at step 0 (written even
  when 0, so "guarded, nothing found" differs from "never guarded"); ``face_attrs`` gives the
  same summary for the guarded clip's artifact attrs.
"""

from __future__ import annotations

from schemas.records import LineageBatch, MetricRecord, RejectionRecord
from tasks.guard.config import GuardConfig
from tasks.guard.faces import FaceDecision
from tasks.guard.text import TextMatch

TEXT_STAGE = "guard_text"
FACE_STAGE = "guard_faces"


def text_decisions(subject_id: str, matches: list[tuple[str, TextMatch]], stage_run_id: str | None = None,
                   manifest_hash: str | None = None) -> LineageBatch:
    """``matches`` as ``scan_fields`` returns them (field, match) for one subject (a manifest
    hash, a clip id for its caption, a panel id for its prompt)."""
    metric = MetricRecord(subject_id=subject_id, name="guard_text_matches", value=float(len(matches)),
                          stage_run_id=stage_run_id, manifest_hash=manifest_hash,
                          attrs={"terms": sorted({m.term for _, m in matches})})
    batch = LineageBatch(metrics=[metric])
    if matches:
        detail = "; ".join(f"{field}: {m.term!r} (found {m.found!r}, {m.how})" for field, m in matches)
        batch.rejections.append(RejectionRecord(
            artifact_id=subject_id, stage=TEXT_STAGE, reason="blocked_term", scores={"matches": float(len(matches))},
            detail=detail[:2000], stage_run_id=stage_run_id, manifest_hash=manifest_hash))
    return batch


def face_attrs(decisions: list[FaceDecision] | tuple[FaceDecision, ...], config: GuardConfig) -> dict:
    """Summary for the guarded artifact's attrs."""
    return {"guard": {"faces_boxes": len(decisions), "faces_frames": len({d.frame for d in decisions}),
                      "method": config.method, "min_face": config.min_face, "detect_every": config.detect_every,
                      "enabled": config.enabled}}


def face_decisions(subject_id: str, decisions: list[FaceDecision] | tuple[FaceDecision, ...],
                   stage_run_id: str | None = None, manifest_hash: str | None = None) -> LineageBatch:
    by_frame: dict[int, list[FaceDecision]] = {}
    for d in decisions:
        by_frame.setdefault(d.frame, []).append(d)
    rows = [MetricRecord(subject_id=subject_id, name="guard_face_boxes", step=frame, value=float(len(ds)),
                         stage_run_id=stage_run_id, manifest_hash=manifest_hash,
                         attrs={"boxes": [[*d.box, d.detected] for d in ds]})
            for frame, ds in sorted(by_frame.items())]
    rows += [MetricRecord(subject_id=subject_id, name="guard_faces_frames", value=float(len(by_frame)),
                          stage_run_id=stage_run_id, manifest_hash=manifest_hash),
             MetricRecord(subject_id=subject_id, name="guard_faces_boxes", value=float(len(decisions)),
                          stage_run_id=stage_run_id, manifest_hash=manifest_hash)]
    return LineageBatch(metrics=rows)

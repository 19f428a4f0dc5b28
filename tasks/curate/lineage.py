"""Lineage records of a curation run: raw videos, clips kept and rejected, quarantined inputs.

Paths enter records through ``schemas.paths.escaped``: a file name that is not UTF-8 is
recorded with ``\\xff``-style escapes (issue 26)."""

from __future__ import annotations

from schemas.hashing import stable_id
from schemas.paths import escaped
from schemas.records import ArtifactRecord, ClipRecord, EdgeRecord, LineageBatch, MetricRecord, RejectionRecord, raw_video_id


def _clip_attrs(clip: ClipRecord) -> dict:
    return {"source_id": clip.source_id, "start_frame": clip.start_frame, "end_frame": clip.end_frame,
            "start_s": round(clip.start_s, 6), "end_s": round(clip.end_s, 6), "fps": clip.fps,
            "width": clip.width, "height": clip.height, "tags": list(clip.tags), "caption": clip.caption,
            "dedup_group": clip.dedup_group, "phash": clip.phash}


def raw_video(source: str, sha256: str, size: int, manifest_hash: str | None, stage_run_id: str,
              attrs: dict | None = None) -> LineageBatch:
    art = ArtifactRecord(artifact_id=raw_video_id(sha256), kind="raw_video", uri=escaped(source), sha256=sha256,
                         bytes=size, manifest_hash=manifest_hash, stage_run_id=stage_run_id,
                         attrs=escaped(attrs or {}))
    batch = LineageBatch(artifacts=[art])
    if manifest_hash:
        batch.edges.append(EdgeRecord(parent_id=manifest_hash, child_id=art.artifact_id, relation="curated_under"))
    return batch


def quarantined(source: str, sha256: str | None, stage: str, reason: str, detail: str,
                manifest_hash: str | None, stage_run_id: str) -> LineageBatch:
    """An input that could not be curated: its artifact (by content when readable) and why."""
    source, detail = escaped(source), escaped(detail)
    artifact_id = raw_video_id(sha256) if sha256 else stable_id("unreadable_input", source)
    art = ArtifactRecord(artifact_id=artifact_id, kind="raw_video", uri=source, sha256=sha256,
                         manifest_hash=manifest_hash, stage_run_id=stage_run_id, attrs={"quarantined": True})
    rej = RejectionRecord(artifact_id=artifact_id, stage=stage, reason=reason, detail=detail[:2000],
                          manifest_hash=manifest_hash, stage_run_id=stage_run_id)
    batch = LineageBatch(artifacts=[art], rejections=[rej])
    if manifest_hash:
        batch.edges.append(EdgeRecord(parent_id=manifest_hash, child_id=artifact_id, relation="curated_under"))
    return batch


def clips(records: list[ClipRecord], stage_run_id: str) -> LineageBatch:
    """Each clip as an artifact under its raw video; rejected ones with their reason and scores."""
    batch = LineageBatch()
    for clip in records:
        batch.artifacts.append(ArtifactRecord(
            artifact_id=clip.clip_id, kind="clip", uri=clip.uri, sha256=clip.sha256, bytes=clip.bytes,
            manifest_hash=clip.manifest_hash, stage_run_id=stage_run_id, attrs=_clip_attrs(clip)))
        batch.edges.append(EdgeRecord(parent_id=clip.source_id, child_id=clip.clip_id, relation="split_from"))
        if not clip.kept:
            detail = f"duplicate of {clip.dedup_group}" if clip.reject_stage == "dedup" else None
            batch.rejections.append(RejectionRecord(
                artifact_id=clip.clip_id, stage=clip.reject_stage or "unknown", reason=clip.reject_reason or "unknown",
                scores=dict(clip.scores), detail=detail, manifest_hash=clip.manifest_hash, stage_run_id=stage_run_id))
    return batch


def stage_metrics(subject: str, values: dict[str, float], stage_run_id: str, manifest_hash: str | None) -> list[MetricRecord]:
    return [MetricRecord(subject_id=subject, name=k, value=float(v), stage_run_id=stage_run_id,
                         manifest_hash=manifest_hash) for k, v in sorted(values.items())]

"""A behaviour-cloning checkpoint in lineage, as train-policy and the loop record it: the
checkpoint artifact (its weights file), the edges into it, and its training loss per step."""

from __future__ import annotations

from pathlib import Path

from schemas.hashing import sha256_file
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, MetricRecord


def checkpoint_lineage(checkpoint_id: str, weights: Path, root: Path, stage_run_id: str, digest: str | None,
                       attrs: dict, parents: list[tuple[str, str]], loss: str, history: list[dict]) -> LineageBatch:
    """``parents`` as (parent id, relation); ``loss`` names the metric of the history's losses."""
    return LineageBatch(
        artifacts=[ArtifactRecord(artifact_id=checkpoint_id, kind="checkpoint", uri=weights.relative_to(root).as_posix(),
                                  sha256=sha256_file(str(weights)), bytes=weights.stat().st_size,
                                  manifest_hash=digest, stage_run_id=stage_run_id,
                                  attrs={"model": "bc-policy", **attrs})],  # attrs may name another model
        edges=[EdgeRecord(parent_id=parent, child_id=checkpoint_id, relation=relation) for parent, relation in parents],
        metrics=[MetricRecord(subject_id=checkpoint_id, name=loss, step=h["step"], value=h["loss"],
                              stage_run_id=stage_run_id, manifest_hash=digest) for h in history])

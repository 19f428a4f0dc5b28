"""A panel's lineage: panel.json's body, and the panel (panel.json) <- its variant manifests
and episodes; panel -> contact sheet and video, with the face post-guard's decisions."""

from __future__ import annotations

from pathlib import Path

from schemas import paths
from schemas.hashing import sha256_file, stable_id
from schemas.panel import PanelSpec, panel_hash
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch
from tasks.guard.config import GuardConfig
from tasks.guard.lineage import face_attrs, face_decisions
from tasks.panels import sheet


def panel_body(spec: PanelSpec, panel_id: str, episodes: dict, root: Path, camera: str, world_model: str | None,
               media: sheet.PanelMedia) -> dict:
    rel = lambda p: Path(p).relative_to(root).as_posix()  # noqa: E731
    variants = []
    for pv, cell in zip(spec.variants, spec.grid.cells):
        eps = [episodes[(pv.cell, i)] for i in range(len(pv.seeds))]
        variants.append({"cell": pv.cell, "manifest_hash": pv.manifest_hash,
                         "stressors": sorted({s.kind for s in cell.stressors} | {f"-{k}" for k in cell.drop}),
                         "episodes": [{"index": f.index, "seed": f.seed, "success": f.success, "reason": f.reason,
                                       "episode_id": eid, "table": rel(f.table), "video": rel(f.videos[camera])}
                                      for f, eid in eps]})
    return {"format": "worldline-panel/1", "panel_id": panel_id, "panel_hash": panel_hash(spec),
            "spec": spec.model_dump(mode="json"), "camera": camera, "world_model": world_model,
            "contact_sheet": rel(media.sheet), "video": rel(media.video), "variants": variants}


def panel_lineage(spec: PanelSpec, panel_id: str, body: dict, media: sheet.PanelMedia, episodes: dict, root: Path,
                  stage_run_id: str, digest: str, guard: GuardConfig | None) -> LineageBatch:
    """panel (panel.json) <- variant manifests and episodes; panel -> contact sheet and video."""
    spec_file = paths.resolve(root, paths.PANEL_SPEC, panel_id=panel_id)
    attrs = {"name": spec.name, "panel_hash": body["panel_hash"], "contract_hash": spec.contract_hash,
             "cells": [v.cell for v in spec.variants], "seeds": list(spec.variants[0].seeds),
             "world_model": body["world_model"], "guard": guard is not None}
    batch = LineageBatch(artifacts=[ArtifactRecord(
        artifact_id=panel_id, kind="panel", uri=spec_file.relative_to(root).as_posix(),
        sha256=sha256_file(str(spec_file)), bytes=spec_file.stat().st_size, manifest_hash=digest,
        stage_run_id=stage_run_id, attrs=attrs)])
    batch.edges += [EdgeRecord(parent_id=pv.manifest_hash, child_id=panel_id, relation="panel_variant")
                    for pv in spec.variants]
    batch.edges += [EdgeRecord(parent_id=eid, child_id=panel_id, relation="panel_episode")
                    for _, eid in episodes.values()]
    for role, path, faces in (("contact_sheet", media.sheet, media.sheet_faces), ("video", media.video, media.video_faces)):
        sha = sha256_file(str(path))
        child = stable_id("panel_media", panel_id, role, sha)
        extra = face_attrs(faces, guard) if guard is not None else {"guard": {"enabled": False}}
        batch.artifacts.append(ArtifactRecord(artifact_id=child, kind="panel", uri=Path(path).relative_to(root).as_posix(),
                                              sha256=sha, bytes=Path(path).stat().st_size, manifest_hash=digest,
                                              stage_run_id=stage_run_id, attrs={"role": role, "panel_id": panel_id,
                                                                                **extra}))
        batch.edges.append(EdgeRecord(parent_id=panel_id, child_id=child, relation="rendered"))
        if guard is not None:  # the post-guard's decisions, even when it found nothing
            batch.extend(face_decisions(child, faces, stage_run_id, digest))
    return batch

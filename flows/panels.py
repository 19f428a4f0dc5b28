"""panels: a manifest x a stressor grid -> variant manifests -> simulator episodes (and, with a
world model, its rollouts) -> contact sheet PNG + panel MP4, both guards, all in lineage."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.lookup import verified_file, verified_world_model
from flows.params import PanelEpisodes
from flows.recording import RunContext, recorded_run
from flows.report import markdown_table, progress, publish, write_json
from flows.runners import task_runner
from flows.simulate import simulate_episode
from schemas import paths
from schemas.hashing import content_hash, sha256_file, stable_id
from schemas.manifest import ScenarioManifest
from schemas.panel import PanelSpec, StressorGrid, panel_hash
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, StageRunRecord
from schemas.settings import Settings
from tasks import manifests
from tasks.guard.config import GuardConfig
from tasks.guard.faces import guard_frames
from tasks.guard.lineage import face_attrs, face_decisions, text_decisions
from tasks.guard.text import scan_fields
from tasks.panels import sheet
from tasks.panels.grid import default_grid, expand, load_grid
from tasks.panels.world import WorldModelRequest, world_model_rollout
from tasks.sim import files

load_manifest = task(manifests.load, name="load-manifest")
# Inputs are whole videos: hashing them for a cache key would cost more than it saves.
render_media = task(sheet.write_panel_media, name="render-panel", retries=1, cache_policy=NO_CACHE)
STAGE = "panel"
# Panels are simulator or generated footage at contract resolution: search every 5th frame
# (curate's default) for faces of 20 px and more.
PANEL_GUARD = GuardConfig(detect_every=5)


def resolve_grid(parent: ScenarioManifest, grid: str | None, episodes: int | None) -> StressorGrid:
    chosen = load_grid(grid) if grid else default_grid(parent)
    if episodes is not None:
        chosen = StressorGrid.model_validate({**chosen.model_dump(mode="json"), "episodes": episodes})
    return chosen


def panel_id_of(spec: PanelSpec, world_model_sha: str | None) -> str:
    return stable_id("panel", panel_hash(spec), world_model_sha or "")


def read_episode(root: Path, digest: str, index: int) -> files.EpisodeFiles | None:
    """A finished episode from its files (meta.json is written last), or None."""
    meta = paths.resolve(root, paths.EPISODE_META, manifest_hash=digest, index=index)
    if not meta.is_file():
        return None
    body = json.loads(meta.read_text())
    videos = {c: paths.resolve(root, paths.EPISODE_VIDEO, manifest_hash=digest, index=index, camera=c)
              for c in body["cameras"]}
    table = paths.resolve(root, paths.EPISODE_TABLE, manifest_hash=digest, index=index)
    if not table.is_file() or not all(v.is_file() for v in videos.values()):
        return None
    return files.EpisodeFiles(index=index, seed=body["seed"], directory=meta.parent, videos=videos, table=table,
                              meta=meta, success=body["success"], reason=body["reason"], steps=body["steps"],
                              stressor_values=body.get("stressors", {}))


def simulate_variants(run: RunContext, spec: PanelSpec, variants: list[ScenarioManifest]) -> dict:
    """Every variant x seed, as `simulate` would (same stage and keys, so episodes it already
    made are reused); returns {(cell, index): (EpisodeFiles, episode artifact id)}."""
    root = run.settings.data_root
    todo, out = {}, {}
    for pv, variant in zip(spec.variants, variants):
        for index in range(len(pv.seeds)):
            key = stable_id("episode", pv.manifest_hash, str(index))
            done = read_episode(root, pv.manifest_hash, index) if not run.pending("simulate", [key]) else None
            if done is not None:  # reused: its files must still be the ones lineage recorded (issue 26)
                verified_file(run.warehouse, root, done.table, "episode", "episode")
                for video in done.videos.values():
                    verified_file(run.warehouse, root, video, "episode_video", "episode video")
                out[(pv.cell, index)] = done
            else:
                todo[(pv.cell, index)] = (key, pv.manifest_hash, time.perf_counter(),
                                          simulate_episode.submit(variant, pv.manifest_hash, index, root))
    with progress(len(todo), f"simulate panel {spec.name}") as bar:
        for (cell, index), (key, digest, t0, future) in todo.items():
            written, success, reason = future.result()
            bar.advance()
            stage = StageRunRecord(stage_run_id=run.stage_run_id("simulate", key), run_id=run.run_id, stage="simulate",
                                   input_key=key, manifest_hash=digest, n_in=1, n_out=1,
                                   seconds=round(time.perf_counter() - t0, 3),
                                   attrs={"index": index, "success": success, "reason": reason, "panel_cell": cell})
            run.write(LineageBatch(stage_runs=[stage]).extend(
                files.episode_lineage(written, digest, stage.stage_run_id, root)))
            out[(cell, index)] = written
    digests = {pv.cell: pv.manifest_hash for pv in spec.variants}
    # The id episode_lineage gives: a hash of the manifest, the index and the step table.
    return {k: (f, stable_id("episode", digests[k[0]], str(f.index), sha256_file(str(f.table))))
            for k, f in out.items()}


def primary_camera(manifest: ScenarioManifest, camera: str | None) -> str:
    names = [c.name for c in manifest.cameras]
    if camera is not None and camera not in names:
        raise ValueError(f"camera {camera!r} is not in manifest {manifest.name} (it has {', '.join(names)})")
    return camera or next((c.name for c in manifest.cameras if c.mount == "world"), names[0])


def world_request(episode: files.EpisodeFiles, variant: ScenarioManifest, camera: str, fps: float,
                  frames: np.ndarray) -> WorldModelRequest:
    """The world model starts where the episode starts and gets its actions."""
    table = pq.read_table(episode.table, columns=["action"])
    actions = np.asarray(table.column("action").to_pylist(), np.float64)
    control_hz = float(table.schema.metadata[b"control_hz"]) if table.schema.metadata else 50.0
    return WorldModelRequest(camera=camera, context=frames[:1], actions=actions, control_hz=control_hz, fps=fps,
                             frames=len(frames), text=world_text(variant))


def world_text(variant: ScenarioManifest) -> str:
    from tasks.world.data import episode_text

    return episode_text(variant.task.instruction, [s.kind for s in variant.stressors])


@task(name="world-model-rollout", retries=0, cache_policy=NO_CACHE)
def rollout_world_model(checkpoint: str, request: WorldModelRequest, guard: GuardConfig,
                        root: Path) -> tuple[np.ndarray, list]:
    """The world model's frames for one episode, with the face post-guard applied to them."""
    generated = world_model_rollout(checkpoint, request, root)
    if not guard.enabled:
        return generated, []
    return guard_frames(np.ascontiguousarray(generated), guard)


@flow(name="panels", log_prints=True, task_runner=task_runner())
def panels(manifest: str, grid: str | None = None, episodes: PanelEpisodes | None = None,
           world_model: str | None = None, camera: str | None = None, guard: bool = True) -> dict:
    """A matched panel of ``manifest`` over ``grid`` (a YAML StressorGrid; default: one
    stressor at a time), ``episodes`` seeds per cell (default: the grid's)."""
    settings = Settings()
    root = settings.data_root
    parent = load_manifest(Path(manifest))
    spec, variants = expand(parent, resolve_grid(parent, grid, episodes))
    cam = primary_camera(parent, camera)
    fps = next(c.fps for c in parent.cameras if c.name == cam)
    guard_config = PANEL_GUARD.model_copy(update={"enabled": guard})
    wm_sha = content_hash({"checkpoint": str(Path(world_model).resolve())}) if world_model else None
    panel_id = panel_id_of(spec, wm_sha)
    params = {"manifest": manifest, "grid": grid, "episodes": episodes, "world_model": world_model,
              "camera": cam, "guard": guard}
    with recorded_run("panels", settings, parent, source_uri=manifest, params=params) as run:
        verified_world_model(run.warehouse, root, world_model)  # before any rollout reads it
        batch = LineageBatch()
        for pv, variant in zip(spec.variants, variants):
            batch.extend(manifests.lineage(variant))
            if guard:  # the pre-guard's decision on every variant, and on the grid's own text
                batch.extend(text_decisions(pv.manifest_hash, scan_fields(variant, guard_config),
                                            manifest_hash=pv.manifest_hash))
        if guard:
            batch.extend(text_decisions(panel_id, scan_fields(spec.grid, guard_config), manifest_hash=run.manifest_hash))
        run.write(batch)
        if batch.rejections:
            raise ValueError(f"panel {spec.name}: blocked text: {batch.rejections[0].detail}")

        episodes_by_cell = simulate_variants(run, spec, variants)
        key = stable_id(STAGE, panel_id, guard_config.model_dump_json(), cam)
        folder = paths.resolve(root, paths.PANEL_DIR, panel_id=panel_id)
        spec_file = paths.resolve(root, paths.PANEL_SPEC, panel_id=panel_id)
        if run.pending(STAGE, [key]) or not spec_file.is_file():
            t0 = time.perf_counter()
            rows, world_batch = [], LineageBatch()
            for pv, variant in zip(spec.variants, variants):
                ep, _ = episodes_by_cell[(pv.cell, 0)]
                frames = sheet.read_frames(ep.videos[cam])
                world = None
                if world_model:
                    world, found = rollout_world_model(world_model, world_request(ep, variant, cam, fps, frames),
                                                       guard_config, root)
                    subject = stable_id("world_rollout", panel_id, pv.cell, "0")
                    if guard:
                        world_batch.extend(face_decisions(subject, found, manifest_hash=pv.manifest_hash))
                outcomes = [episodes_by_cell[(pv.cell, i)][0] for i in range(len(pv.seeds))]
                wins = sum(o.success for o in outcomes)
                rows.append(sheet.SheetRow(pv.cell, frames, world,
                                           note=f"sim {wins}/{len(outcomes)} ok\nseed {pv.seeds[0]}: "
                                                f"{'ok' if outcomes[0].success else 'fail'}"))
            media = render_media(rows, folder / "contact_sheet.png", folder / "panel.mp4", fps,
                                 guard_config if guard else None)
            body = panel_body(spec, panel_id, episodes_by_cell, root, cam, world_model, media)
            write_json(spec_file, body)
            stage = StageRunRecord(stage_run_id=run.stage_run_id(STAGE, key), run_id=run.run_id, stage=STAGE,
                                   input_key=key, manifest_hash=run.manifest_hash,
                                   n_in=len(episodes_by_cell), n_out=3, seconds=round(time.perf_counter() - t0, 3),
                                   attrs={"panel_id": panel_id, "cells": len(spec.variants)})
            run.write(LineageBatch(stage_runs=[stage]).extend(world_batch).extend(
                panel_lineage(spec, panel_id, body, media, episodes_by_cell, root, stage.stage_run_id,
                              run.manifest_hash, guard_config if guard else None)))
        body = json.loads(spec_file.read_text())
        table = [(v["cell"], v["manifest_hash"][:12], ", ".join(s for s in v["stressors"]) or "none",
                  f"{sum(e['success'] for e in v['episodes'])}/{len(v['episodes'])}") for v in body["variants"]]
        publish("panels", f"{spec.name}: {len(spec.variants)} variants x {len(spec.variants[0].seeds)} seeds",
                markdown_table(("cell", "variant manifest", "stressors", "simulator successes"), table)
                + f"\n\ncontact sheet `{body['contact_sheet']}`, video `{body['video']}`",
                "the panel's variants and their simulator outcomes")
        print(f"panel {panel_id} ({spec.name}): " + "; ".join(f"{c} {s}" for c, _, _, s in table))
        return {"panel_id": panel_id, "panel_hash": body["panel_hash"], "contract_hash": spec.contract_hash,
                "uri": spec_file.relative_to(root).as_posix(), "manifest_hash": run.manifest_hash,
                "contact_sheet": body["contact_sheet"], "video": body["video"], "variants": body["variants"]}


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

"""panels: a manifest x a stressor grid -> variant manifests -> simulator episodes (and, with a
world model, its rollouts) -> contact sheet PNG + panel MP4, both guards, all in lineage."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.params import PanelEpisodes
from flows.params_policy import PanelsParams
from flows.recording import RunContext, recorded_run
from flows.report import markdown_table, progress, publish, write_json
from flows.runners import task_runner
from flows.simulate import simulate_episode
from schemas import paths
from schemas.hashing import content_hash, sha256_file, stable_id
from schemas.manifest import ScenarioManifest
from schemas.panel import PanelSpec, panel_hash
from schemas.records import LineageBatch
from schemas.settings import Settings
from tasks import manifests
from tasks.guard.config import GuardConfig
from tasks.guard.faces import guard_frames
from tasks.guard.lineage import face_decisions, text_decisions
from tasks.guard.text import scan_fields
from tasks.lookup import verified_episode, verified_world_model
from tasks.panels import sheet
from tasks.panels.grid import expand, primary_camera, resolve_grid
from tasks.panels.lineage import panel_body, panel_lineage
from tasks.panels.world import WorldModelRequest, world_model_rollout, world_request
from tasks.sim import files
from tasks.video import read_frames

load_manifest = task(manifests.load, name="load-manifest")
# Inputs are whole videos: hashing them for a cache key would cost more than it saves.
render_media = task(sheet.write_panel_media, name="render-panel", retries=1, cache_policy=NO_CACHE)
STAGE = "panel"
# Panels are simulator or generated footage at contract resolution: search every 5th frame
# (curate's default) for faces of 20 px and more.
PANEL_GUARD = GuardConfig(detect_every=5)


def panel_id_of(spec: PanelSpec, world_model_sha: str | None) -> str:
    return stable_id("panel", panel_hash(spec), world_model_sha or "")


def simulate_variants(run: RunContext, spec: PanelSpec, variants: list[ScenarioManifest]) -> dict:
    """Every variant x seed, as `simulate` would (same stage and keys, so episodes it already
    made are reused); returns {(cell, index): (EpisodeFiles, episode artifact id)}."""
    root = run.settings.data_root
    todo, out = {}, {}
    for pv, variant in zip(spec.variants, variants):
        for index in range(len(pv.seeds)):
            stage = run.stage("simulate", stable_id("episode", pv.manifest_hash, str(index)),
                              manifest_hash=pv.manifest_hash)
            done = files.read_episode(root, pv.manifest_hash, index) if stage.done else None
            if done is not None:  # reused: its files must still be the ones lineage recorded (issue 26)
                verified_episode(run.warehouse, root, done)
                out[(pv.cell, index)] = done
            else:
                todo[(pv.cell, index)] = (stage, simulate_episode.submit(variant, pv.manifest_hash, index, root))
    with progress(len(todo), f"simulate panel {spec.name}") as bar:
        for (cell, index), (stage, future) in todo.items():
            written, success, reason, _ = future.result()
            bar.advance()
            stage.finish(1, 1, files.episode_lineage(written, stage.manifest_hash, stage.id, root),
                         attrs={"index": index, "success": success, "reason": reason, "panel_cell": cell})
            out[(cell, index)] = written
    digests = {pv.cell: pv.manifest_hash for pv in spec.variants}
    # The id episode_lineage gives: a hash of the manifest, the index and the step table.
    return {k: (f, stable_id("episode", digests[k[0]], str(f.index), sha256_file(str(f.table))))
            for k, f in out.items()}


@task(name="world-model-rollout", retries=0, cache_policy=NO_CACHE)
def rollout_world_model(checkpoint: str, request: WorldModelRequest, guard: GuardConfig,
                        root: Path, device: str | None = None) -> tuple[np.ndarray, list]:
    """The world model's frames for one episode, with the face post-guard applied to them."""
    generated = world_model_rollout(checkpoint, request, root, device=device)
    if not guard.enabled:
        return generated, []
    return guard_frames(np.ascontiguousarray(generated), guard)


def render_panel(run: RunContext, spec: PanelSpec, variants: list[ScenarioManifest], panel_id: str,
                 episodes_by_cell: dict, cam: str, fps: float, world_model: str | None,
                 guard: GuardConfig | None, device: str | None = None) -> Path:
    """panel.json, the contact sheet and the panel video (the world model's rollouts beside the
    simulator's, with the face guards unless ``guard`` is None), unless done before."""
    root = run.settings.data_root
    guard_config = guard or PANEL_GUARD.model_copy(update={"enabled": False})
    key = stable_id(STAGE, panel_id, guard_config.model_dump_json(), cam)
    folder = paths.resolve(root, paths.PANEL_DIR, panel_id=panel_id)
    spec_file = paths.resolve(root, paths.PANEL_SPEC, panel_id=panel_id)
    stage = run.stage(STAGE, key, [spec_file])
    if stage.done:
        return spec_file
    rows, world_batch = [], LineageBatch()
    for pv, variant in zip(spec.variants, variants):
        ep, _ = episodes_by_cell[(pv.cell, 0)]
        frames = read_frames(ep.videos[cam])
        world = None
        if world_model:
            world, found = rollout_world_model(world_model, world_request(ep, variant, cam, fps, frames),
                                               guard_config, root, device)
            subject = stable_id("world_rollout", panel_id, pv.cell, "0")
            if guard is not None:
                world_batch.extend(face_decisions(subject, found, manifest_hash=pv.manifest_hash))
        outcomes = [episodes_by_cell[(pv.cell, i)][0] for i in range(len(pv.seeds))]
        wins = sum(o.success for o in outcomes)
        rows.append(sheet.SheetRow(pv.cell, frames, world,
                                   note=f"sim {wins}/{len(outcomes)} ok\nseed {pv.seeds[0]}: "
                                        f"{'ok' if outcomes[0].success else 'fail'}"))
    media = render_media(rows, folder / "contact_sheet.png", folder / "panel.mp4", fps, guard)
    body = panel_body(spec, panel_id, episodes_by_cell, root, cam, world_model, media)
    write_json(spec_file, body)
    stage.finish(len(episodes_by_cell), 3, world_batch.extend(
        panel_lineage(spec, panel_id, body, media, episodes_by_cell, root, stage.id, run.manifest_hash, guard)),
        attrs={"panel_id": panel_id, "cells": len(spec.variants)})
    return spec_file


@flow(name="panels", log_prints=True, task_runner=task_runner())
def panels(manifest: str, grid: str | None = None, episodes: PanelEpisodes | None = None,
           world_model: str | None = None, camera: str | None = None, guard: bool = True,
           device: str | None = None) -> dict:
    """A matched panel of ``manifest`` over ``grid`` (a YAML StressorGrid; default: one
    stressor at a time), ``episodes`` seeds per cell (default: the grid's). ``device``: where
    the world model rolls out (``tasks.device``; it changes no id)."""
    checks = PanelsParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    root = settings.data_root
    if world_model:  # before anything runs or is written
        checks.check_world(manifests.load(Path(manifest)), world_model, root, flow=True)
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
        spec_file = render_panel(run, spec, variants, panel_id, episodes_by_cell, cam, fps, world_model,
                                 guard_config if guard else None, device)
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

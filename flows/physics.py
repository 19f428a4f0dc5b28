"""evaluate-physics: a post-trained world model against MuJoCo on held-out seeds (issue 8).

held-out seeds -> rollout + segmentation replay -> the tokenizer's codes and reconstruction
-> world-model rollouts from every window with the true and with shuffled actions -> per
horizon: PSNR and SSIM against the floor (last reconstructed context frame held) and the
ceiling (the reconstruction), the package's position error (px, cm) and mask IoU where it
moves [-> Sampson error between cameras]; next-frame scores from the true frames on the
held-out and on trained-on episodes (memorising) -> table, plots, quality checks, lineage.
"""

from __future__ import annotations

import json
from pathlib import Path

from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.heldout import heldout_setup
from flows.params import Horizon, PanelEpisodes, SamplerSteps, Seed
from flows.params_world import HELDOUT_FIRST_SEED, PhysicsParams
from flows.recording import recorded_run
from flows.report import progress, publish
from schemas import paths
from schemas.settings import Settings
from tasks import manifests
from tasks.lookup import verified_artifact
from tasks.world import evaluation, physics, report
from tasks.world.data import episode_text
from tasks.world.geometry import PinholeCamera

STAGE = "evaluate_physics"
# `worldline simulate` uses seeds seed..seed+N-1 (the shipped manifests' seeds are under 100),
# train-policy seed+1000.. and seed+2000..: 10,000 and up are seeds no training run has seen.

render_heldout = task(evaluation.render_heldout, name="render-heldout", retries=1, cache_policy=NO_CACHE)
predict_heldout = task(evaluation.predict_heldout, name="predict-heldout", cache_policy=NO_CACHE)


@flow(name="evaluate-physics", log_prints=True)
def evaluate_physics(manifest: str, world_model: str | None = None, tokenizer: str | None = None,
                     episodes: PanelEpisodes = 10,
                     first_seed: Seed = HELDOUT_FIRST_SEED, camera: str | None = None,
                     horizon: Horizon = 4,
                     context: int | None = None, stride: int = 2, move_threshold_cm: float = 2.0,
                     shuffle_seed: int = 0, sampler_steps: SamplerSteps = 8) -> dict:
    """Evaluate ``world_model`` (a post-trained checkpoint folder or id of either family; default
    the newest) on ``episodes`` held-out seeds from ``first_seed`` of ``manifest``: windows of
    ``context`` latent frames (default the model's window less ``horizon``) predict ``horizon``
    more. ``sampler_steps``: a diffusion world model's Euler steps per sample (it enters a
    diffusion evaluation's id only)."""
    PhysicsParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    root = settings.data_root.resolve()
    scenario = manifests.load(Path(manifest))
    world = [c for c in scenario.cameras if c.mount == "world"]
    if not world:
        raise ValueError(f"{manifest}: no world-mounted camera; the physics check needs a fixed camera")
    primary = next((c for c in world if c.name == camera), None) if camera else world[0]
    if primary is None:
        raise ValueError(f"{manifest}: no world-mounted camera {camera!r} (has {', '.join(c.name for c in world)})")
    others = [c.name for c in world if c.name != primary.name and c.fps == primary.fps]
    seeds = list(range(first_seed, first_seed + episodes))
    params = {"manifest": manifest, "world_model": world_model, "tokenizer": tokenizer, "episodes": episodes,
              "first_seed": first_seed, "camera": primary.name, "horizon": horizon, "context": context,
              "stride": stride, "move_threshold_cm": move_threshold_cm, "shuffle_seed": shuffle_seed}
    with recorded_run("evaluate-physics", settings, scenario, source_uri=manifest, params=params) as run:
        setup = heldout_setup(run, STAGE, params, world_model, tokenizer, seeds, horizon, context, sampler_steps)
        wm_folder, config, tok_folder, size, every, context = (setup.wm_folder, setup.config, setup.tok_folder,
                                                               setup.size, setup.every, setup.context)
        wm_id, tok_id, key, evaluation_id = setup.wm_id, setup.tok_id, setup.key, setup.evaluation_id
        result_path = paths.resolve(root, paths.PHYSICS_RESULT, evaluation_id=evaluation_id)
        stage = run.stage(STAGE, key, [result_path])
        if stage.done:
            verified_artifact(run.warehouse, result_path, evaluation_id)  # read back: must be lineage's bytes
            result = json.loads(result_path.read_text())
            print(f"evaluation {evaluation_id} done before: {result_path}")
            return result["summary"]

        rendered = []
        with progress(len(seeds), f"simulate held-out episodes of {scenario.name}") as bar:
            for seed in seeds:
                rendered.append(render_heldout(scenario, seed, primary.name, others))
                bar.advance()
        per_camera = {name: [(seed, truths[name]) for seed, truths in zip(seeds, rendered)]
                      for name in [primary.name, *others]}
        cameras = {c.name: PinholeCamera.from_manifest(c) for c in world}
        text = episode_text(scenario.task.instruction, [s.kind for s in scenario.stressors])
        windows, memorising, per_frame = predict_heldout(wm_folder, tok_folder, per_camera, cameras, size, text, context, horizon,
                                          stride, move_threshold_cm / 100, shuffle_seed,
                                              evaluation.trained_folders(config, root),
                                          tok_id, root, sampler_steps)
        main = windows[primary.name]
        if not main:
            raise ValueError(f"episodes of {scenario.horizon_s} s are too short for {context} + {horizon} "
                             "latent frames")
        rows = physics.horizon_table(main)
        checks = {"beats_floor": physics.check_beats_floor(rows, every, every),
                  "actions_matter": physics.check_actions_matter(rows, every),
                  "psnr_between_floor_and_ceiling": physics.check_psnr_between(rows, every)}
        reported = sorted({r["horizon"] for r in rows if r["horizon"] % every == 0})
        sampson = evaluation.two_view_rows(windows, primary.name, cameras, reported)
        counts = {**evaluation.window_counts(main, seeds), "rollout_s_per_frame": round(per_frame, 4)}
        body = report.report_body(rows, every, checks, counts, sampson, memorising)
        files = report.write_outputs(root, evaluation_id, rows, main, every, body)
        summary = {"run_id": run.run_id, "evaluation_id": evaluation_id, "world_model_id": wm_id,
                   "tokenizer_id": tok_id, "folder": str(files["result"].parent),
                   "checks": {k: v["passed"] for k, v in checks.items()},
                   **{k: v for k, v in counts.items() if k != "untracked"}, "context": context, "horizon": horizon}
        files["result"].write_text(json.dumps({"summary": summary, "params": params, "rows": rows, "sampson": sampson,
                                               "checks": checks, "counts": counts,
                                               "windows": [{"key": w.key, "moved": w.moved, "tracked": w.tracked,
                                                            **w.info} for w in main],
                                               "teacher_forced": memorising}, indent=1, default=float))
        stage.finish(len(seeds), 1, report.evaluation_lineage(
            root, evaluation_id, files, stage.id, wm_id, tok_id, run.manifest_hash,
            {"evaluation": "physics", "seeds": seeds, "camera": primary.name, **summary["checks"]},
            report.metrics(rows, sampson, checks, every, memorising)), attrs={"evaluation_id": evaluation_id})
        publish("physics", f"{scenario.name}: world model {wm_id[:12]} on {len(seeds)} held-out episodes",
                body, "world model against the simulator: per-horizon image, position and IoU errors")
        print(f"evaluation {evaluation_id}: " + ", ".join(f"{k} {'passed' if v else 'failed'}"
                                                          for k, v in summary["checks"].items()))
    return summary

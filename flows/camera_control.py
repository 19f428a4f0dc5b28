"""evaluate-camera: camera control, a post-trained world model of a rig whose action is its
cameras' motion, against the simulator on held-out seeds (issue 33 point 3).

held-out seeds (their own jittered trajectories) -> rollout + the camera's pose at every frame
-> the tokenizer's codes and reconstruction -> world-model rollouts from every window with the
commanded and with shuffled actions -> the camera trajectory re-estimated frame to frame (KLT
matches, the essential matrix of a rig turning about world z, the known intrinsics) -> per horizon: rotation and
translation-direction error of the simulator's frames, the ceiling, the model, the shuffled
actions and copy-last-frame -> table, check, lineage.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.heldout import heldout_setup
from flows.params import Horizon, PanelEpisodes, SamplerSteps, Seed
from flows.params_world import HELDOUT_FIRST_SEED, CameraParams
from flows.recording import recorded_run
from flows.report import progress, publish
from schemas import paths
from schemas.settings import Settings
from tasks import manifests
from tasks.lookup import verified_artifact
from tasks.tokenize import tokens
from tasks.world import camera_control, heldout, report
from tasks.world.data import episode_text
from tasks.world.family import load_world_model

STAGE = "evaluate_camera"

render_heldout = task(camera_control.render_heldout, name="render-camera-heldout", retries=1, cache_policy=NO_CACHE)


@task(name="predict-camera-heldout", cache_policy=NO_CACHE)
def predict(wm_folder: Path, tok_folder: Path, truths: list[tuple[int, heldout.Truth]], camera, size: int, text: str,
            context: int, horizon: int, stride: int, shuffle_seed: int, sampler_steps: int) -> tuple[list, dict]:
    """The windows of every held-out episode, and each episode's true frames at the model's size."""
    import torch

    torch.set_num_threads(min(2, torch.get_num_threads()))
    model, tokenizer = load_world_model(wm_folder), tokens.load_checkpoint(tok_folder)
    if not model.config.action_conditioned:
        raise ValueError(f"{wm_folder}: not post-trained with actions; give a post-trained world model")
    prepared = [heldout.prepare(f"seed{seed}", t, camera, tokenizer, size, model.config.action_dim, text,
                                totals=model.config.action_totals) for seed, t in truths]
    windows = heldout.predict(model, tokenizer, prepared, context, horizon, stride, shuffle_seed=shuffle_seed,
                              sampler_steps=sampler_steps)
    return windows, {p.key: p.frames for p in prepared}


@flow(name="evaluate-camera", log_prints=True)
def evaluate_camera(manifest: str, world_model: str | None = None, tokenizer: str | None = None,
                    episodes: PanelEpisodes = 10, first_seed: Seed = HELDOUT_FIRST_SEED, camera: str | None = None,
                    horizon: Horizon = 4, context: int | None = None, stride: int = 2, shuffle_seed: int = 0,
                    sampler_steps: SamplerSteps = 8) -> dict:
    """Evaluate ``world_model`` (either family; default the newest post-trained) on ``episodes``
    held-out seeds of ``manifest`` seen through ``camera`` (one riding on the base): does the
    camera move in its frames as the commanded motion moved it in the simulator's?"""
    CameraParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    root = settings.data_root.resolve()
    scenario = manifests.load(Path(manifest))
    riding = camera_control.moving_cameras(scenario)
    if not riding:
        raise ValueError(f"{manifest}: no camera rides on the base; camera control needs a moving camera")
    name = camera or riding[0]
    if name not in riding:
        raise ValueError(f"{manifest}: no camera {name!r} riding on the base (has {', '.join(riding)})")
    seeds = list(range(first_seed, first_seed + episodes))
    params = {"manifest": manifest, "world_model": world_model, "tokenizer": tokenizer, "episodes": episodes,
              "first_seed": first_seed, "camera": name, "horizon": horizon, "context": context, "stride": stride,
              "shuffle_seed": shuffle_seed}
    with recorded_run("evaluate-camera", settings, scenario, source_uri=manifest, params=params) as run:
        setup = heldout_setup(run, STAGE, params, world_model, tokenizer, seeds, horizon, context, sampler_steps)
        wm_folder, tok_folder, size, every, context = (setup.wm_folder, setup.tok_folder, setup.size, setup.every,
                                                       setup.context)
        wm_id, tok_id, key, evaluation_id = setup.wm_id, setup.tok_id, setup.key, setup.evaluation_id
        files = {"result": paths.resolve(root, paths.CAMERA_RESULT, evaluation_id=evaluation_id),
                 "report": paths.resolve(root, paths.CAMERA_REPORT, evaluation_id=evaluation_id)}
        stage = run.stage(STAGE, key, [files["result"]])
        if stage.done:
            verified_artifact(run.warehouse, files["result"], evaluation_id)
            print(f"evaluation {evaluation_id} done before: {files['result']}")
            return json.loads(files["result"].read_text())["summary"]

        rendered = []
        with progress(len(seeds), f"simulate held-out episodes of {scenario.name}") as bar:
            for seed in seeds:
                rendered.append(render_heldout(scenario, seed, name))
                bar.advance()
        truths = [(seed, truth) for seed, (truth, _) in zip(seeds, rendered)]
        poses = {f"seed{seed}": cams for seed, (_, cams) in zip(seeds, rendered)}
        text = episode_text(scenario.task.instruction, [s.kind for s in scenario.stressors])
        started = time.perf_counter()
        windows, frames = predict(wm_folder, tok_folder, truths, poses[f"seed{seeds[0]}"][0], size, text, context,
                                  horizon, stride, shuffle_seed, sampler_steps)
        # Per generated frame, the encoding and decoding included: true and shuffled actions, every window.
        per_frame = (time.perf_counter() - started) / max(1, 2 * len(windows) * every * horizon)
        if not windows:
            raise ValueError(f"episodes of {scenario.horizon_s} s are too short for {context} + {horizon} "
                             "latent frames")
        horizons = list(range(every, every * horizon + 1, every))
        rows = camera_control.window_rows(windows, frames, poses, horizons, size)
        table = camera_control.motion_table(rows)
        check = camera_control.check_beats_copy_last(table, rows=rows)
        counts = {"episodes": len(seeds), "seeds": f"{seeds[0]}..{seeds[-1]}", "windows": len(windows),
                  "camera": name, "rollout_s_per_frame": round(per_frame, 4)}
        body = camera_control.report_body(table, check, counts)
        files["result"].parent.mkdir(parents=True, exist_ok=True)
        files["report"].write_text(f"# camera-control evaluation {evaluation_id}\n\n{body}")
        summary = {"run_id": run.run_id, "evaluation_id": evaluation_id, "world_model_id": wm_id,
                   "tokenizer_id": tok_id, "folder": str(files["result"].parent),
                   "checks": {"beats_copy_last": check["passed"]}, **counts, "context": context, "horizon": horizon}
        files["result"].write_text(json.dumps({"summary": summary, "params": params, "table": table, "check": check,
                                               "rows": rows}, indent=1, default=float))
        metrics = [(f"camera/{r['source']}/rotation_error_deg/h{r['horizon']}", r["rotation_mean_deg"])
                   for r in table if r["source"] in ("model", "floor", "ceiling", "simulator")]
        metrics.append(("camera/check/beats_copy_last", float(check["passed"])))
        stage.finish(len(seeds), 1, report.evaluation_lineage(
            root, evaluation_id, files, stage.id, wm_id, tok_id, run.manifest_hash,
            {"evaluation": "camera", "seeds": seeds, "camera": name, **summary["checks"]}, metrics),
            attrs={"evaluation_id": evaluation_id})
        publish("camera", f"{scenario.name}: world model {wm_id[:12]} on {len(seeds)} held-out episodes", body,
                "camera motion re-estimated from generated frames against the commanded motion")
        print(f"evaluation {evaluation_id}: beats copy-last {'passed' if check['passed'] else 'failed'}")
    return summary

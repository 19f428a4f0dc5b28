"""evaluate-rig: a multi-view rig, a world model post-trained on the rig's tiled video (all views
generated together), against the simulator on held-out seeds (issue 33 point 4).

held-out seeds (their own jittered trajectories) -> rollout of the rig's cameras with each view's
pose and depth -> the tiled frames' codes and reconstruction -> world-model rollouts from every
window with the commanded and with shuffled actions -> per horizon and source: the rig's
ego-motion from all views (metric, cm) against the simulator's and the commanded motion, each pair
of neighbouring views' agreement and Sampson error -> tables, check, lineage.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.camera_control import predict
from flows.heldout import heldout_setup
from flows.params import Horizon, PanelEpisodes, SamplerSteps, Seed
from flows.params_world import HELDOUT_FIRST_SEED, RigParams
from flows.recording import recorded_run
from flows.report import progress, publish
from schemas import paths
from schemas.settings import Settings
from tasks import manifests
from tasks.lookup import verified_artifact
from tasks.world import report, rig_views
from tasks.world.data import episode_text
from tasks.world.geometry import PinholeCamera

STAGE = "evaluate_rig"

render_heldout = task(rig_views.render_heldout, name="render-rig-heldout", retries=1, cache_policy=NO_CACHE)


@flow(name="evaluate-rig", log_prints=True)
def evaluate_rig(manifest: str, world_model: str | None = None, tokenizer: str | None = None,
                 episodes: PanelEpisodes = 10, first_seed: Seed = HELDOUT_FIRST_SEED, rig: str | None = None,
                 horizon: Horizon = 2, context: int | None = None, stride: int = 2, shuffle_seed: int = 0,
                 sampler_steps: SamplerSteps = 8) -> dict:
    """Evaluate ``world_model`` (either family; default the newest post-trained), trained on the
    tiled video of ``rig``, on ``episodes`` held-out seeds of ``manifest``: does the rig move in
    its generated views as the commanded motion moved it, and do the views agree?"""
    RigParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    root = settings.data_root.resolve()
    scenario = manifests.load(Path(manifest))
    if not scenario.rigs:
        raise ValueError(f"{manifest}: no rig (`rigs:`); a multi-view evaluation needs one")
    name = rig or scenario.rigs[0].name
    layout = scenario.rig(name)
    if layout is None:
        raise ValueError(f"{manifest}: no rig {name!r} (has {', '.join(r.name for r in scenario.rigs)})")
    seeds = list(range(first_seed, first_seed + episodes))
    params = {"manifest": manifest, "world_model": world_model, "tokenizer": tokenizer, "episodes": episodes,
              "first_seed": first_seed, "rig": name, "horizon": horizon, "context": context, "stride": stride,
              "shuffle_seed": shuffle_seed}
    with recorded_run("evaluate-rig", settings, scenario, source_uri=manifest, params=params) as run:
        setup = heldout_setup(run, STAGE, params, world_model, tokenizer, seeds, horizon, context, sampler_steps)
        if setup.config.get("camera") not in (None, name):
            raise ValueError(f"{setup.wm_folder}: post-trained on camera {setup.config['camera']!r}, not on rig "
                             f"{name!r}")
        wm_folder, tok_folder, size, every, context = (setup.wm_folder, setup.tok_folder, setup.size, setup.every,
                                                       setup.context)
        wm_id, tok_id, key, evaluation_id = setup.wm_id, setup.tok_id, setup.key, setup.evaluation_id
        files = {"result": paths.resolve(root, paths.RIG_RESULT, evaluation_id=evaluation_id),
                 "report": paths.resolve(root, paths.RIG_REPORT, evaluation_id=evaluation_id)}
        stage = run.stage(STAGE, key, [files["result"]])
        if stage.done:
            verified_artifact(run.warehouse, files["result"], evaluation_id)
            print(f"evaluation {evaluation_id} done before: {files['result']}")
            return json.loads(files["result"].read_text())["summary"]

        truths = {}
        with progress(len(seeds), f"simulate held-out episodes of {scenario.name}") as bar:
            for seed in seeds:
                truths[f"seed{seed}"] = render_heldout(scenario, seed, name)
                bar.advance()
        first = truths[f"seed{seeds[0]}"]
        side = first.truth.frames.shape[1]
        # prepare() only sizes this camera to the model's frames; the measures use each view's own.
        tiled = PinholeCamera.from_fovy(side, side, 90.0, [0, 0, 0], [[1, 0, 0], [0, 1, 0], [0, 0, 1]])
        text = episode_text(scenario.task.instruction, [s.kind for s in scenario.stressors])
        started = time.perf_counter()
        windows, _ = predict(wm_folder, tok_folder, [(seed, truths[f"seed{seed}"].truth) for seed in seeds], tiled,
                             size, text, context, horizon, stride, shuffle_seed, sampler_steps)
        per_frame = (time.perf_counter() - started) / max(1, 2 * len(windows) * every * horizon)
        if not windows:
            raise ValueError(f"episodes of {scenario.horizon_s} s are too short for {context} + {horizon} "
                             "latent frames")
        horizons = list(range(every, every * horizon + 1, every))
        rows = rig_views.window_rows(windows, truths, horizons)
        ego, views = rig_views.ego_table(rows), rig_views.views_table(rows)
        check = rig_views.check_beats_copy_last(ego, rows)
        counts = {"episodes": len(seeds), "seeds": f"{seeds[0]}..{seeds[-1]}", "windows": len(windows), "rig": name,
                  "views": len(layout.cameras), "rollout_s_per_frame": round(per_frame, 4)}
        body = rig_views.report_body(ego, views, check, counts)
        files["result"].parent.mkdir(parents=True, exist_ok=True)
        files["report"].write_text(f"# multi-view rig evaluation {evaluation_id}\n\n{body}")
        summary = {"run_id": run.run_id, "evaluation_id": evaluation_id, "world_model_id": wm_id,
                   "tokenizer_id": tok_id, "folder": str(files["result"].parent),
                   "checks": {"beats_copy_last": check["passed"]}, **counts, "context": context, "horizon": horizon}
        files["result"].write_text(json.dumps({"summary": summary, "params": params, "ego": ego, "views": views,
                                               "check": check, "rows": rows}, indent=1, default=float))
        metrics = [(f"rig/{r['source']}/{label}/h{r['horizon']}", r[key]) for r in ego
                   for label, key in (("ego_error_cm", "ego_mean_cm"), ("command_error_cm", "command_mean_cm"))
                   if r[key] is not None]
        metrics.append(("rig/check/beats_copy_last", float(check["passed"])))
        stage.finish(len(seeds), 1, report.evaluation_lineage(
            root, evaluation_id, files, stage.id, wm_id, tok_id, run.manifest_hash,
            {"evaluation": "rig", "seeds": seeds, "rig": name, **summary["checks"]}, metrics),
            attrs={"evaluation_id": evaluation_id})
        publish("rig", f"{scenario.name}: world model {wm_id[:12]} on {len(seeds)} held-out episodes", body,
                "a rig's ego-motion and its views' agreement from generated frames")
        print(f"evaluation {evaluation_id}: beats copy-last {'passed' if check['passed'] else 'failed'}")
    return summary

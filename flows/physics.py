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
import time
from dataclasses import replace
from pathlib import Path
from typing import Annotated

import numpy as np
from prefect import flow, task
from prefect.cache_policies import NO_CACHE
from pydantic import Field

from flows.lookup import verified_artifact, verified_file, world_model_folder
from flows.params import PanelEpisodes, Seed
from flows.recording import RunContext, recorded_run
from flows.report import markdown_table, publish
from schemas import paths
from schemas.hashing import content_hash, sha256_file, stable_id
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, MetricRecord, StageRunRecord
from schemas.settings import Settings
from tasks import manifests
from tasks.tokenize import tokens
from tasks.world import checkpoints, data, heldout, physics, plots
from tasks.world.data import CodeSequence, episode_text, read_meta
from tasks.world.geometry import PinholeCamera, sampson_table
from tasks.world.train import teacher_forced, window_length

STAGE = "evaluate_physics"
# `worldline simulate` uses seeds seed..seed+N-1 (the shipped manifests' seeds are under 100),
# train-policy seed+1000.. and seed+2000..: 10,000 and up are seeds no training run has seen.
HELDOUT_FIRST_SEED = 10_000


def _artifact_id(run: RunContext, path: Path, kind: str, attrs: dict) -> str:
    """The lineage id of a checkpoint file, checked against the sha256 lineage recorded for it
    (TamperedArtifact); one lineage has never seen is recorded now as an external input (a
    checkpoint brought from elsewhere may be evaluated; its row says it has no lineage here)."""
    root = run.settings.data_root.resolve()
    artifact_id, _, digest = verified_file(run.warehouse, root, path, kind, kind)
    if artifact_id is not None:
        return artifact_id
    uri = path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)
    artifact_id = stable_id(kind, uri, digest)
    run.write(LineageBatch(artifacts=[ArtifactRecord(artifact_id=artifact_id, kind=kind, uri=uri, sha256=digest,
                                                     bytes=path.stat().st_size,
                                                     attrs={**attrs, "registered_by": "evaluate-physics",
                                                            "external": True})]))
    return artifact_id


def trained_folders(config: dict, root: Path) -> list[Path]:
    """The episode folders a post-trained checkpoint saw (its config lists them) that are still here."""
    folders = [Path(uri) if Path(uri).is_absolute() else root / uri for uri in config.get("episodes", [])]
    return [folder for folder in folders if (folder / "meta.json").is_file()]


def trained_seeds(config: dict, root: Path) -> set[int]:
    """Seeds of the episodes a post-trained checkpoint saw."""
    return {int(read_meta(folder)["seed"]) for folder in trained_folders(config, root)}


@task(name="render-heldout", retries=1, cache_policy=NO_CACHE)
def render_heldout(scenario, seed: int, camera: str, others: list[str]) -> dict[str, heldout.Truth]:
    """The primary camera's truth (with the package's masks) and the other cameras' frames,
    all checked against the rollout's own renders."""
    from tasks.sim.episode import rollout

    ep = rollout(scenario, seed)
    truth = heldout.render_truth(scenario, seed, camera)
    if not np.array_equal(truth.frames, ep.frames[camera]):
        raise RuntimeError(f"seed {seed}: the segmentation replay renders other frames than the rollout")
    return {camera: truth, **{c: replace(truth, camera=c, frames=ep.frames[c], masks=None) for c in others}}


@task(name="predict-heldout", cache_policy=NO_CACHE)
def predict_heldout(wm_folder: Path, tok_folder: Path, per_camera: dict[str, list[tuple[int, heldout.Truth]]],
                    cameras: dict[str, PinholeCamera], size: int, text: str, context: int, horizon: int, stride: int,
                    move_m: float, shuffle_seed: int, trained: list[Path], tokenizer_id: str, root: Path
                    ) -> tuple[dict[str, list[physics.Window]], dict]:
    """Windows per camera: encode, fit colours (primary camera), roll out with true and shuffled
    actions. And teacher-forced next-frame scores on the primary camera's held-out episodes
    beside as many of the episodes the model trained on (``trained``, that camera)."""
    import torch

    torch.set_num_threads(min(2, torch.get_num_threads()))
    model, tokenizer = checkpoints.load_checkpoint(wm_folder), tokens.load_checkpoint(tok_folder)
    if not model.config.action_conditioned:
        raise ValueError(f"{wm_folder}: not post-trained with actions; give a post-trained world model")
    out, memorising = {}, {}
    for name, truths in per_camera.items():
        prepared = [heldout.prepare(f"seed{seed}", t, cameras[name], tokenizer, size, model.config.action_dim, text,
                                    totals=model.config.action_totals)
                    for seed, t in truths]
        out[name] = heldout.predict(model, tokenizer, prepared, context, horizon, stride, move_m, shuffle_seed)
        if not memorising:  # the primary camera comes first
            held = [CodeSequence(p.key, p.codes, p.text, p.actions) for p in prepared]
            window = window_length(held, model.config.max_frames)
            memorising["held_out"] = teacher_forced(model, held, window, stride)
            seen = data.load_episodes(trained[:len(prepared)], tokenizer, size, [name], model.config.action_dim,
                                      text, tokenizer_id, root, model.config.action_totals)
            if any(s.frames >= window for s in seen):
                memorising["trained"] = teacher_forced(model, seen, window, stride)
    return out, memorising


def _fmt(v, digits=2) -> str:
    return "" if v is None else f"{v:.{digits}f}"


def _detail(check: dict) -> str:
    def rounded(v):
        return [rounded(x) for x in v] if isinstance(v, list) else round(v, 3) if isinstance(v, float) else v
    return json.dumps({k: rounded(v) for k, v in check.items() if k != "passed"})


def report_body(rows: list[dict], every: int, checks: dict, counts: dict, sampson: list[dict],
                memorising: dict | None = None) -> str:
    by = {(r["horizon"], r["method"]): r for r in rows}
    hs = sorted({h for h, _ in by if h % every == 0})
    ms = physics.METHODS
    image = markdown_table(["h"] + [f"PSNR {m}" for m in ms] + [f"SSIM {m}" for m in ms],
                           [[h] + [_fmt(by[h, m]["psnr"]) for m in ms] + [_fmt(by[h, m]["ssim"], 3) for m in ms]
                            for h in hs])
    where = markdown_table(["h"] + [f"px {m}" for m in ms] + [f"cm {m}" for m in ms] + [f"IoU {m}" for m in ms]
                           + ["tracked"],
                           [[h] + [_fmt(by[h, m]["pos_err_px"]) for m in ms]
                            + [_fmt(by[h, m]["pos_err_cm"]) for m in ms]
                            + [_fmt(by[h, m]["iou"], 3) for m in ms] + [by[h, "model"]["tracked"]] for h in hs])
    text = (f"{counts['episodes']} held-out episodes (seeds {counts['seeds']}), {counts['windows']} windows, "
            f"{counts['moving']} where the package moves, {counts['tracked']} of those tracked by colour"
            + (f"; not tracked: {counts['untracked']}" if counts["untracked"] else "") + "\n\n"
            f"### image similarity (all windows)\n\n{image}\n\n"
            f"### package position (windows where it moves)\n\n{where}\n\n### checks\n\n"
            + markdown_table(("check", "passed", "detail"),
                             [(k, "yes" if v["passed"] else "no", _detail(v)) for k, v in checks.items()]))
    if memorising:
        text += ("\n\n### next frame from the true frames: held-out against trained-on episodes\n\n"
                 "A model that has memorised its episodes scores far better on them than on new ones.\n\n"
                 + markdown_table(("episodes", "windows", "loss (nats)", "accuracy", "changed codes right"),
                                  [(name.replace("_", " "), f["windows"], _fmt(f["loss"], 3), _fmt(f["accuracy"], 3),
                                    _fmt(f["changed_accuracy"], 3)) for name, f in memorising.items()]))
    if sampson:
        text += "\n\n### Sampson error between cameras (px, ORB matches)\n\n" + markdown_table(
            ("pair", "h", "source", "matches", "mean", "median"),
            [(r["pair"], r["horizon"], r["source"], r["matches"], _fmt(r["mean_px"]), _fmt(r["median_px"]))
             for r in sampson])
    return text


def _metrics(rows: list[dict], sampson: list[dict], checks: dict, every: int,
             memorising: dict | None = None) -> list[tuple[str, float]]:
    out = []
    for r in rows:
        if r["horizon"] % every:
            continue
        prefix = "physics" if r["method"] == "model" else f"physics/{r['method']}"
        for key in ("psnr", "ssim", "pos_err_px", "pos_err_cm", "iou", "found"):
            if r[key] is not None:
                out.append((f"{prefix}/{key}/h{r['horizon']}", r[key]))
    for r in sampson:
        if r["median_px"] is not None:
            prefix = "physics" if r["source"] == "model" else f"physics/{r['source']}"
            out.append((f"{prefix}/sampson_median_px/{r['pair']}/h{r['horizon']}", r["median_px"]))
            out.append((f"{prefix}/sampson_mean_px/{r['pair']}/h{r['horizon']}", r["mean_px"]))
    out += [(f"physics/check/{k}", float(v["passed"])) for k, v in checks.items()]
    out += [(f"physics/teacher_forced/{name}/{key}", f[key]) for name, f in (memorising or {}).items()
            for key in ("loss", "accuracy", "changed_accuracy") if np.isfinite(f[key])]
    return out


def two_view_rows(windows: dict[str, list[physics.Window]], primary: str, cameras: dict[str, PinholeCamera],
                  horizons: list[int]) -> list[dict]:
    """Sampson error between the primary camera and each other one: simulator, ceiling, model."""
    main, rows = windows[primary], []
    for name, other in windows.items():
        if name == primary:
            continue
        views = {source: [(a.true, b.true) if source == "simulator" else (a.outputs[source], b.outputs[source])
                          for a, b in zip(main, other)] for source in ("simulator", "ceiling", "model")}
        rows += [{"pair": f"{primary}-{name}", **r}
                 for r in sampson_table(views, cameras[primary], cameras[name], horizons)]
    return rows


def window_counts(main: list[physics.Window], seeds: list[int]) -> dict:
    untracked = sorted({f"{w.info['episode']} (colour fit IoU: "
                        + ", ".join(f"{k} {_fmt(v)}" for k, v in w.info["fit_iou"].items()) + ")"
                        for w in main if w.true_colour is None or w.decoded_colour is None})
    return {"episodes": len(seeds), "seeds": f"{seeds[0]}..{seeds[-1]}", "windows": len(main),
            "moving": sum(w.moved for w in main), "tracked": sum(w.tracked for w in main),
            "untracked": ", ".join(untracked)}


def write_outputs(root: Path, evaluation_id: str, rows: list[dict], main: list[physics.Window], every: int,
                  body: str) -> dict[str, Path]:
    """The report (markdown) and the plots; returns every file's path, and where the result JSON goes."""
    files = {"result": paths.resolve(root, paths.PHYSICS_RESULT, evaluation_id=evaluation_id),
             "report": paths.resolve(root, paths.PHYSICS_REPORT, evaluation_id=evaluation_id),
             **{name: paths.resolve(root, paths.PHYSICS_PLOT, evaluation_id=evaluation_id, plot=name)
                for name in ("error_vs_horizon", "strip")}}
    files["result"].parent.mkdir(parents=True, exist_ok=True)
    plots.error_plot(rows).save(files["error_vs_horizon"])
    shown = ([w for w in main if w.tracked] or [w for w in main if w.moved] or main)[:3]  # the package moving
    strip = [(f"{w.key} {label}", w.true if label == "true" else w.frames(label))
             for w in shown for label in ("true", "ceiling", "model", "shuffled")]
    plots.frame_strip(strip, list(range(every, len(main[0].true) + 1, every))).save(files["strip"])
    files["report"].write_text(f"# physics evaluation {evaluation_id}\n\n{body}\n")
    return files


def evaluation_lineage(root: Path, evaluation_id: str, files: dict[str, Path], stage: StageRunRecord, wm_id: str,
                       tok_id: str, manifest_hash: str, attrs: dict, metrics: list[tuple[str, float]]) -> LineageBatch:
    """The evaluation (its result JSON) with edges from the world model, its tokenizer and the
    manifest; its plots as reports; its metrics."""
    def record(kind: str, artifact_id: str, path: Path, extra: dict) -> ArtifactRecord:
        return ArtifactRecord(artifact_id=artifact_id, kind=kind, uri=path.relative_to(root).as_posix(),
                              sha256=sha256_file(str(path)), bytes=path.stat().st_size, manifest_hash=manifest_hash,
                              stage_run_id=stage.stage_run_id, attrs=extra)

    report_uri = files["report"].relative_to(root).as_posix()
    batch = LineageBatch(stage_runs=[stage],
                         artifacts=[record("evaluation", evaluation_id, files["result"],
                                           {**attrs, "report_uri": report_uri})],
                         edges=[EdgeRecord(parent_id=wm_id, child_id=evaluation_id, relation="evaluated"),
                                EdgeRecord(parent_id=tok_id, child_id=evaluation_id, relation="decoded_by"),
                                EdgeRecord(parent_id=manifest_hash, child_id=evaluation_id, relation="evaluated_on")])
    for name in ("error_vs_horizon", "strip"):
        plot_id = stable_id("report", evaluation_id, name)
        batch.artifacts.append(record("report", plot_id, files[name], {"plot": name}))
        batch.edges.append(EdgeRecord(parent_id=evaluation_id, child_id=plot_id, relation="plotted"))
    batch.metrics += [MetricRecord(subject_id=evaluation_id, name=n, value=float(v), stage_run_id=stage.stage_run_id,
                                   manifest_hash=manifest_hash) for n, v in metrics]
    return batch


@flow(name="evaluate-physics", log_prints=True)
def evaluate_physics(manifest: str, world_model: str | None = None, tokenizer: str | None = None,
                     episodes: PanelEpisodes = 10,
                     first_seed: Seed = HELDOUT_FIRST_SEED, camera: str | None = None,
                     horizon: Annotated[int, Field(ge=1, le=64)] = 4,
                     context: int | None = None, stride: int = 2, move_threshold_cm: float = 2.0,
                     shuffle_seed: int = 0) -> dict:
    """Evaluate ``world_model`` (a post-trained checkpoint folder or id; default the newest) on
    ``episodes`` held-out seeds from ``first_seed`` of ``manifest``: windows of ``context``
    latent frames (default the model's window less ``horizon``) predict ``horizon`` more."""
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
        wm_folder = world_model_folder(run.warehouse, root, world_model)
        config = checkpoints.read_config(wm_folder)
        overlap = trained_seeds(config, root) & set(seeds)
        if overlap:
            raise ValueError(f"seeds {sorted(overlap)} trained this world model: evaluate on held-out seeds")
        tok_folder = Path(tokenizer) if tokenizer else root / config["tokenizer"]
        size, window = int(config["size"]), int(config["world_model"]["max_frames"])
        every = int(config["world_model"]["temporal_compression"])  # report every latent step
        context = context or max(1, window - horizon)
        wm_id = _artifact_id(run, wm_folder / checkpoints.WEIGHTS_FILE, "checkpoint", {"model": "world_model"})
        tok_id = _artifact_id(run, tok_folder / tokens.WEIGHTS_FILE, "checkpoint", {"model": "tokenizer"})
        meaning = {**params, "world_model": wm_id, "tokenizer": tok_id, "context": context}  # not the paths
        key = stable_id(STAGE, wm_id, tok_id, run.manifest_hash, content_hash(meaning))
        evaluation_id = stable_id("evaluation", key)
        result_path = paths.resolve(root, paths.PHYSICS_RESULT, evaluation_id=evaluation_id)
        if not run.pending(STAGE, [key]) and result_path.is_file():
            verified_artifact(run.warehouse, result_path, evaluation_id)  # read back: must be lineage's bytes
            result = json.loads(result_path.read_text())
            print(f"evaluation {evaluation_id} done before: {result_path}")
            return result["summary"]

        t0 = time.perf_counter()
        rendered = [render_heldout(scenario, seed, primary.name, others) for seed in seeds]
        per_camera = {name: [(seed, truths[name]) for seed, truths in zip(seeds, rendered)]
                      for name in [primary.name, *others]}
        cameras = {c.name: PinholeCamera.from_manifest(c) for c in world}
        text = episode_text(scenario.task.instruction, [s.kind for s in scenario.stressors])
        windows, memorising = predict_heldout(wm_folder, tok_folder, per_camera, cameras, size, text, context, horizon,
                                          stride, move_threshold_cm / 100, shuffle_seed, trained_folders(config, root),
                                          tok_id, root)
        main = windows[primary.name]
        if not main:
            raise ValueError(f"episodes of {scenario.horizon_s} s are too short for {context} + {horizon} "
                             "latent frames")
        rows = physics.horizon_table(main)
        checks = {"beats_floor": physics.check_beats_floor(rows, every, every),
                  "actions_matter": physics.check_actions_matter(rows, every),
                  "psnr_between_floor_and_ceiling": physics.check_psnr_between(rows, every)}
        reported = sorted({r["horizon"] for r in rows if r["horizon"] % every == 0})
        sampson = two_view_rows(windows, primary.name, cameras, reported)
        counts = window_counts(main, seeds)
        body = report_body(rows, every, checks, counts, sampson, memorising)
        files = write_outputs(root, evaluation_id, rows, main, every, body)
        summary = {"run_id": run.run_id, "evaluation_id": evaluation_id, "world_model_id": wm_id,
                   "tokenizer_id": tok_id, "folder": str(files["result"].parent),
                   "checks": {k: v["passed"] for k, v in checks.items()},
                   **{k: v for k, v in counts.items() if k != "untracked"}, "context": context, "horizon": horizon}
        files["result"].write_text(json.dumps({"summary": summary, "params": params, "rows": rows, "sampson": sampson,
                                               "checks": checks, "counts": counts,
                                               "windows": [{"key": w.key, "moved": w.moved, "tracked": w.tracked,
                                                            **w.info} for w in main],
                                               "teacher_forced": memorising}, indent=1, default=float))
        stage = StageRunRecord(stage_run_id=run.stage_run_id(STAGE, key), run_id=run.run_id, stage=STAGE,
                               input_key=key, manifest_hash=run.manifest_hash, n_in=len(seeds), n_out=1,
                               seconds=round(time.perf_counter() - t0, 3), attrs={"evaluation_id": evaluation_id})
        run.write(evaluation_lineage(root, evaluation_id, files, stage, wm_id, tok_id, run.manifest_hash,
                                     {"evaluation": "physics", "seeds": seeds, "camera": primary.name,
                                      **summary["checks"]}, _metrics(rows, sampson, checks, every, memorising)))
        publish("physics", f"{scenario.name}: world model {wm_id[:12]} on {len(seeds)} held-out episodes",
                body, "world model against the simulator: per-horizon image, position and IoU errors")
        print(f"evaluation {evaluation_id}: " + ", ".join(f"{k} {'passed' if v else 'failed'}"
                                                          for k, v in summary["checks"].items()))
    return summary

"""The physics evaluation's report: its markdown body, its plots and files, and its lineage
(the evaluation with edges from the world model, its tokenizer and the manifest; plots; metrics)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from schemas import paths
from schemas.hashing import sha256_file, stable_id
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, MetricRecord
from tasks.tables import markdown_table
from tasks.world import physics, plots


def fmt(v, digits=2) -> str:
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
                           [[h] + [fmt(by[h, m]["psnr"]) for m in ms] + [fmt(by[h, m]["ssim"], 3) for m in ms]
                            for h in hs])
    where = markdown_table(["h"] + [f"px {m}" for m in ms] + [f"cm {m}" for m in ms] + [f"IoU {m}" for m in ms]
                           + ["tracked"],
                           [[h] + [fmt(by[h, m]["pos_err_px"]) for m in ms]
                            + [fmt(by[h, m]["pos_err_cm"]) for m in ms]
                            + [fmt(by[h, m]["iou"], 3) for m in ms] + [by[h, "model"]["tracked"]] for h in hs])
    text = (f"{counts['episodes']} held-out episodes (seeds {counts['seeds']}), {counts['windows']} windows, "
            f"{counts['moving']} where the package moves, {counts['tracked']} of those tracked by colour"
            + (f"; not tracked: {counts['untracked']}" if counts["untracked"] else "")
            + (f"; {counts['rollout_s_per_frame']:.4f} s of rollout per generated frame (decoding included)"
               if counts.get("rollout_s_per_frame") is not None else "") + "\n\n"
            f"### image similarity (all windows)\n\n{image}\n\n"
            f"### package position (windows where it moves)\n\n{where}\n\n### checks\n\n"
            + markdown_table(("check", "passed", "detail"),
                             [(k, "yes" if v["passed"] else "no", _detail(v)) for k, v in checks.items()]))
    if memorising:
        text += ("\n\n### next frame from the true frames: held-out against trained-on episodes\n\n"
                 "A model that has memorised its episodes scores far better on them than on new ones.\n\n"
                 + markdown_table(("episodes", "windows", "loss (nats)", "accuracy", "changed codes right"),
                                  [(name.replace("_", " "), f["windows"], fmt(f["loss"], 3), fmt(f["accuracy"], 3),
                                    fmt(f["changed_accuracy"], 3)) for name, f in memorising.items()]))
    if sampson:
        text += "\n\n### Sampson error between cameras (px, ORB matches)\n\n" + markdown_table(
            ("pair", "h", "source", "matches", "mean", "median"),
            [(r["pair"], r["horizon"], r["source"], r["matches"], fmt(r["mean_px"]), fmt(r["median_px"]))
             for r in sampson])
    return text


def metrics(rows: list[dict], sampson: list[dict], checks: dict, every: int,
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


def evaluation_lineage(root: Path, evaluation_id: str, files: dict[str, Path], stage_run_id: str, wm_id: str,
                       tok_id: str, manifest_hash: str, attrs: dict, metrics: list[tuple[str, float]]) -> LineageBatch:
    """The evaluation (its result JSON) with edges from the world model, its tokenizer and the
    manifest; its plots as reports; its metrics."""
    def record(kind: str, artifact_id: str, path: Path, extra: dict) -> ArtifactRecord:
        return ArtifactRecord(artifact_id=artifact_id, kind=kind, uri=path.relative_to(root).as_posix(),
                              sha256=sha256_file(str(path)), bytes=path.stat().st_size, manifest_hash=manifest_hash,
                              stage_run_id=stage_run_id, attrs=extra)

    report_uri = files["report"].relative_to(root).as_posix()
    batch = LineageBatch(artifacts=[record("evaluation", evaluation_id, files["result"],
                                           {**attrs, "report_uri": report_uri})],
                         edges=[EdgeRecord(parent_id=wm_id, child_id=evaluation_id, relation="evaluated"),
                                EdgeRecord(parent_id=tok_id, child_id=evaluation_id, relation="decoded_by"),
                                EdgeRecord(parent_id=manifest_hash, child_id=evaluation_id, relation="evaluated_on")])
    for name in [n for n in ("error_vs_horizon", "strip") if n in files]:
        plot_id = stable_id("report", evaluation_id, name)
        batch.artifacts.append(record("report", plot_id, files[name], {"plot": name}))
        batch.edges.append(EdgeRecord(parent_id=evaluation_id, child_id=plot_id, relation="plotted"))
    batch.metrics += [MetricRecord(subject_id=evaluation_id, name=n, value=float(v), stage_run_id=stage_run_id,
                                   manifest_hash=manifest_hash) for n, v in metrics]
    return batch

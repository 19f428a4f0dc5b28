"""Fit the video-type filter's rendered-versus-camera model and report how it generalises.

Training clips:
- real videos nobody here made: every file of ``../shared/data/videos-dev`` (labels.json) and
  ``../shared/data/videos`` (labels in ``bench/curate_real.py``), cut at their labelled hard
  cuts into windows of at most ``--window`` analysis frames; a file labelled animation or cgi
  is rendered, every other file is camera footage except slides and test patterns, which the
  filter's rules already decide and which are left out of the fit;
- corpus segments of TUNING seeds only (``bench/curate_quality.TUNING_SEEDS``), generated into
  ``--corpus``: segments the rules call physical, clean and defect footage alike (the corpus's
  own animation is flat fills that the rules already catch).

Model: logistic regression on a few of the filter's scene scores (``FEATURES``), standardised,
classes weighted equally, a little L2, fitted by Newton steps in numpy. Decision: the rules'
type, else "animation" when the model's probability reaches --threshold (0.9).

Printed: leave-one-video-out accuracy on the real files (each file's windows left out in turn
and the model refitted on the rest; a file is called by the majority of its windows), for the
rules alone and for rules plus model; how many tuning-corpus physical segments the model calls
rendered; with ``--heldout DIR`` the same on held-out corpus seeds (never fitted on). ``--write``
stores the model fitted on everything, with these figures, in
``tasks/curate/video_type_model.json``.

    .venv/bin/python bench/fit_video_type.py --corpus /tmp/vt-corpus --heldout /tmp/wl-corpus --write
    (the tuning seeds, 4 min each, are generated into --corpus unless already there)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from curate_quality import HELD_OUT_SEEDS, TUNING_SEEDS, corpus  # noqa: E402
from curate_real import SHARED, VIDEOS_LABELS  # noqa: E402

from tasks.curate import video_type as vt  # noqa: E402
from tasks.curate.config import load_config  # noqa: E402
from tasks.curate.decode import analysis_frames  # noqa: E402

FEATURES = ["smooth", "bflat", "edge_kurtosis"]
LOG = ["edge_kurtosis"]
NONPHYSICAL = {"nonphysical_animation": "animation", "nonphysical_slides": "slides",
               "nonphysical_test_pattern": "test_pattern"}


def real_class(labels: list[str]) -> str:
    for label, kind in (("test_pattern", "test_pattern"), ("slides", "slides"), ("animation", "animation"),
                        ("cgi", "animation")):
        if label in labels:
            return kind
    return "physical"


def decode(path: Path, config) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    frames, times, index = [], [], []
    for f in analysis_frames(path, config.analysis):
        frames.append(f.image)
        times.append(f.time)
        index.append(f.index)
    return np.stack(frames), np.asarray(times), np.asarray(index)


def scene_row(frames, times) -> dict:
    verdict = vt.judge(frames, times, vt.VideoTypeConfig(measure_rendered=True))
    row = {k[len("type_"):]: v for k, v in verdict.scores.items()}
    row["kind"] = verdict.tags[0][len("type:"):]
    return row


def real_rows(window: int, config) -> list[dict]:
    sets = [(SHARED / "videos-dev", json.loads((SHARED / "videos-dev" / "labels.json").read_text())),
            (SHARED / "videos", VIDEOS_LABELS)]
    rows = []
    for folder, labels in sets:
        for name, truth in sorted(labels.items()):
            if not (folder / name).is_file():
                continue
            frames, times, index = decode(folder / name, config)
            bounds = [0] + [int(np.searchsorted(index, c)) for c in truth.get("hard_cuts", [])] + [len(frames)]
            if len(frames) <= 8:  # a few frames in all (slides.avi): one window
                bounds = [0, len(frames)]
            for s, e in zip(bounds[:-1], bounds[1:]):
                for a in range(s, e, window):
                    b = min(e, a + window)
                    if b - a < 2 or (b - a < 8 and len(frames) > 8):
                        continue
                    row = scene_row(frames[a:b], times[a:b])
                    row.update(src=name, cls=real_class(truth["labels"]), uncertain=bool(truth.get("uncertain")))
                    rows.append(row)
    return rows


def corpus_rows(root: Path, seeds, minutes: float, config, generate: bool = True) -> list[dict]:
    rows = []
    for seed in seeds:
        if generate:
            truths = corpus(root, seed, minutes, 320, 180)
        else:
            truths = sorted((root / "corpus" / f"seed_{seed:06d}").glob("raw_*.truth.json"))
        for truth_path in truths:
            truth = json.loads(Path(truth_path).read_text())
            frames, times, index = decode(Path(truth_path).with_name(truth["video"]), config)
            for seg in truth["segments"]:
                a, b = np.searchsorted(index, seg["start"]), np.searchsorted(index, seg["end"])
                if b - a < 2:
                    continue
                row = scene_row(frames[a:b], times[a:b])
                row.update(src=f"seed {seed}", cls=NONPHYSICAL.get(seg["label"], "physical"), label=seg["label"])
                rows.append(row)
    return rows


def matrix(rows) -> np.ndarray:
    return np.array([vt.model_inputs(r, FEATURES, LOG) for r in rows], np.float64)


def fit(X: np.ndarray, y: np.ndarray, lam: float = 1.0, steps: int = 50) -> dict:
    """Class-balanced L2 logistic regression by Newton steps; returns the model as stored."""
    mean, scale = X.mean(0), X.std(0) + 1e-9
    Z = np.hstack([(X - mean) / scale, np.ones((len(X), 1))])
    w = np.where(y == 1, len(y) / (2 * max(y.sum(), 1)), len(y) / (2 * max((1 - y).sum(), 1)))
    b = np.zeros(Z.shape[1])
    reg = np.r_[np.full(len(b) - 1, lam), 1e-6] / len(y)
    for _ in range(steps):
        p = 1 / (1 + np.exp(-Z @ b))
        g = Z.T @ ((p - y) * w) / len(y) + reg * b
        H = (Z * (p * (1 - p) * w)[:, None]).T @ Z / len(y) + np.diag(reg)
        b -= np.linalg.solve(H, g)
    return {"features": FEATURES, "log": LOG, "mean": mean.tolist(), "scale": scale.tolist(),
            "coef": b[:-1].tolist(), "intercept": float(b[-1])}


def probabilities(model: dict, rows) -> np.ndarray:
    return np.array([vt.rendered_probability(r, model) for r in rows])


def training_set(real, corp):
    """Rows the model learns from: footage the rules call physical (rendered = 1)."""
    rows = [r for r in real + corp if r["kind"] == "physical" and r["cls"] in ("physical", "animation")]
    return rows, np.array([r["cls"] == "animation" for r in rows], float)


def decide(row, p: float, threshold: float) -> str:
    return "animation" if row["kind"] == "physical" and p >= threshold else row["kind"]


def lovo(real, corp, threshold: float) -> tuple[list[str], dict]:
    lines, hits = [], {"rules": 0, "model": 0, "rules_type": 0, "model_type": 0}
    files = sorted({r["src"] for r in real})
    for name in files:
        held = [r for r in real if r["src"] == name]
        rows, y = training_set([r for r in real if r["src"] != name], corp)
        model = fit(matrix(rows), y)
        p = probabilities(model, held)
        truth = held[0]["cls"]
        by_rules = [r["kind"] for r in held]
        by_model = [decide(r, pi, threshold) for r, pi in zip(held, p)]
        outcome = {}
        for key, kinds in (("rules", by_rules), ("model", by_model)):
            # a tie goes to physical, as in the physical-or-not count (set order is not stable)
            majority = max(sorted(set(kinds)), key=lambda k: (kinds.count(k), k == "physical"))
            hits[key + "_type"] += majority == truth
            nonphysical = sum(k != "physical" for k in kinds) * 2 > len(kinds)
            hits[key] += nonphysical == (truth != "physical")
            outcome[key] = majority
        lines.append(f"  {name:28s} truth {truth:12s} rules {outcome['rules']:12s} rules+model {outcome['model']:12s}"
                     f" p median {np.median(p):.2f}")
    n = len(files)
    return lines, {k: v / n for k, v in hits.items()} | {"files": n}


def corpus_effect(model: dict, rows, threshold: float) -> dict:
    phys = [r for r in rows if r["cls"] == "physical" and r["kind"] == "physical"]
    p = probabilities(model, phys)
    return {"physical_segments": len(phys), "called_rendered": int((p >= threshold).sum()),
            "sources": sorted({r["src"] for r in rows})}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", type=Path, required=True, help="folder for the tuning-seed corpus")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--minutes", type=float, default=4.0)
    ap.add_argument("--heldout", type=Path, default=None, help="a curate_quality --corpus folder of held-out seeds")
    ap.add_argument("--window", type=int, default=48)
    ap.add_argument("--threshold", type=float, default=0.9)
    ap.add_argument("--write", action="store_true", help="store the model in tasks/curate/video_type_model.json")
    args = ap.parse_args()
    if set(args.seeds) - set(TUNING_SEEDS):
        sys.exit(f"train on TUNING_SEEDS only ({TUNING_SEEDS}); {sorted(set(args.seeds) - set(TUNING_SEEDS))} are not")
    if not (SHARED / "videos-dev" / "labels.json").is_file():
        sys.exit(f"{SHARED}: the real videos are absent; nothing to fit")
    t0 = time.perf_counter()
    config = load_config(None)
    real = real_rows(args.window, config)
    corp = corpus_rows(args.corpus, args.seeds, args.minutes, config)
    print(f"{len(real)} real windows from {len({r['src'] for r in real})} files, "
          f"{len(corp)} corpus segments from tuning seeds {args.seeds} ({time.perf_counter() - t0:.0f} s)")
    lines, scores = lovo(real, corp, args.threshold)
    print("leave-one-video-out (each real file left out, model refitted on the rest):")
    print("\n".join(lines))
    print(f"LOVO accuracy, physical vs not: rules {scores['rules']:.3f}, rules+model {scores['model']:.3f}; "
          f"exact type: rules {scores['rules_type']:.3f}, rules+model {scores['model_type']:.3f} "
          f"({scores['files']} files)")
    rows, y = training_set(real, corp)
    model = fit(matrix(rows), y)
    tuning = corpus_effect(model, corp, args.threshold)
    print(f"tuning corpus (fitted on): {tuning['called_rendered']} of {tuning['physical_segments']} physical segments "
          f"called rendered")
    evaluation = {"lovo": scores, "tuning_corpus": tuning, "threshold": args.threshold,
                  "training": {"real_windows": len(real), "corpus_segments": len(corp), "tuning_seeds": args.seeds}}
    if args.heldout:
        seeds = sorted(int(p.name.split("_")[1]) for p in (args.heldout / "corpus").glob("seed_*"))
        seeds = [s for s in seeds if s in HELD_OUT_SEEDS]
        held = corpus_rows(args.heldout, seeds, 0, config, generate=False)
        effect = corpus_effect(model, held, args.threshold)
        nonphys = [r for r in held if r["cls"] != "physical"]
        caught = sum(r["kind"] != "physical" for r in nonphys)
        print(f"held-out corpus seeds {seeds}: {effect['called_rendered']} of {effect['physical_segments']} physical "
              f"segments called rendered; rules catch {caught} of {len(nonphys)} non-physical segments")
        evaluation["heldout_corpus"] = effect | {"nonphysical_caught_by_rules": caught, "nonphysical": len(nonphys)}
    if args.write:
        model["evaluation"] = evaluation
        vt.MODEL_PATH.write_text(json.dumps(model, indent=1) + "\n")
        print(f"wrote {vt.MODEL_PATH}")
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()

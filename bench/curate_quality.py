"""Curation quality against the labelled corpus: cut F1, each filter's precision and recall on
its own defect class, and dedup pair precision and recall, on seeds the thresholds were NOT
tuned on.

Targets (issue 4): cut F1 >= 0.95 (hit within 2 frames); each filter P and R >= 0.90 on its own
defect classes; dedup pair recall >= 0.95 at precision >= 0.98. Filters and dedup are scored on
the truth segments (so a scene-split error does not count twice); cuts on the scene splitter's
output, one decode per video. Cut F1 is strict: predicted hard cuts against true hard cuts, so a
fade or dissolve reported as a cut is a false positive and a missed cut is not excused by a
transition nearby; transitions are scored on their own line.

The thresholds were tuned by looking at TUNING_SEEDS only. Evaluating on one of them is refused
unless ``--tuning`` is given, and then every figure is printed under a TUNING banner.

    .venv/bin/python bench/curate_quality.py                       # held-out seeds 415-417
    .venv/bin/python bench/curate_quality.py --tuning --seeds 1 2 3
    options: --minutes 6 --size 320x180 --corpus DIR (reuse generated footage) --dump FILE.json
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from schemas import paths  # noqa: E402
from tasks.corpus.config import DEFECT_LABELS, FILTER_GROUPS, CorpusConfig  # noqa: E402
from tasks.corpus.generate import VIDEO_MINUTES, generate_corpus  # noqa: E402
from tasks.curate import analyse, dedup  # noqa: E402
from tasks.curate.config import ConfigError, CurateConfig, load_config  # noqa: E402
from tasks.curate.decode import analysis_frames  # noqa: E402
from tasks.curate.dedup_pairs import footage_distance, hash_distance  # noqa: E402
from tasks.curate.filters import precision_recall, run_filters  # noqa: E402
from tasks.curate.scenes import SceneSplitter, boundaries, cut_f1  # noqa: E402
from tasks.video import probe  # noqa: E402

# Every threshold was chosen looking at these seeds only. 100 and 101 were this bench's default
# seeds while the filters were first written, so they count as seen too; 200-202 and 300-302
# were the held-out seeds until their errors were studied to tune the overlay-text and
# video-type filters, 400-405 until theirs were studied to fix the slide, dedup and corpus
# errors they showed, and 406-408 until their one dedup error (two takes of a task on repeat,
# alike at most sampled moments) was studied. 409-411 were held out for the figures of
# 2026-11-23 and never tuned on. Leaving unreferenced frames undecoded was tuned on 400-405
# (the cut detector's gap power) and 412-414 (whose false fades and dissolves led to filling in
# rows for the frames left out); 415-417 are held out for it.
TUNING_SEEDS = (1, 2, 3, 100, 101, 200, 201, 202, 300, 301, 302, 400, 401, 402, 403, 404, 405, 406, 407, 408,
                412, 413, 414)
HELD_OUT_SEEDS = (415, 416, 417)
# The default corpus copies 16 % of clean segments; twice that gives enough duplicate pairs per
# seed to measure dedup recall (every other setting is the corpus default).
BENCH_CORPUS = CorpusConfig(duplicate_fraction=0.32)


def judge_video(path: Path, truth: dict, config: CurateConfig):
    """One decode: scene spans, and per truth segment every filter's verdict and a signature."""
    info = probe(path)
    splitter = SceneSplitter(info.fps, config.scenes, keep_frames=False)
    spans, rows = [], []
    segments = iter(truth["segments"])
    seg = next(segments, None)
    frames, times, indices = [], [], []
    for frame in analysis_frames(path, config.analysis, info=info):
        spans.extend(splitter.push(frame))
        while seg is not None and frame.index >= seg["end"]:
            rows.append(_judge(path, seg, frames, times, indices, config))
            frames, times, indices, seg = [], [], [], next(segments, None)
        if seg is not None and frame.index >= seg["start"]:
            frames.append(frame.image)
            times.append(frame.time)
            indices.append(frame.index)
    spans.extend(splitter.finish())
    if seg is not None:
        rows.append(_judge(path, seg, frames, times, indices, config))
    return spans, rows


def _judge(path, seg, frames, times, indices, config):
    stack = np.stack(frames)
    merged, per_filter = run_filters(stack, np.asarray(times), config.filters())
    verdicts = {v.stage: (None if v.keep else v.reason) for v in per_filter}
    signature = None
    if seg["label"] is None:
        signature = dedup.signature(stack, config.dedup, positions=np.asarray(indices) - seg["start"],
                                    length=seg["end"] - seg["start"])
    return {"segment": seg, "verdicts": verdicts, "scores": merged.scores, "signature": signature,
            "span": (path, seg["start"], seg["end"]), "sharpness": merged.scores.get("sharpness", 0.0)}


def corpus(root: Path, seed: int, minutes: float, width: int, height: int, fps: float = 30.0) -> list[Path]:
    """Truth files of one seed's corpus under root, generated unless an identical one is there."""
    n_videos = max(1, math.ceil(minutes / VIDEO_MINUTES))
    truths = [paths.resolve(root, paths.CORPUS_TRUTH, seed=seed, index=i) for i in range(n_videos)]
    recipe = {"minutes": minutes, "width": width, "height": height, "fps": fps,
              "config": BENCH_CORPUS.model_dump(mode="json")}
    marker = truths[0].parent / "bench_recipe.json"
    if not (marker.exists() and json.loads(marker.read_text()) == recipe and all(t.exists() for t in truths)):
        generate_corpus(root, seed=seed, minutes=minutes, width=width, height=height, fps=fps, config=BENCH_CORPUS)
        marker.write_text(json.dumps(recipe))
    return truths


def _cuts(spans, truth) -> tuple[dict, dict, dict]:
    """(strict hard-cut score, transition score, any-boundary score) of one video."""
    predicted = boundaries(spans)
    cuts = [p for p in predicted if not isinstance(p, tuple)]
    gradual = [p for p in predicted if isinstance(p, tuple)]
    trans = [(t["start"], t["end"]) for t in truth["transitions"]]
    return (cut_f1(cuts, truth["cuts"], []), cut_f1(gradual, [], trans), cut_f1(predicted, truth["cuts"], trans))


def _prf(scores: list[dict]) -> tuple[float, float, float, int, int, int]:
    hits, pred, true = (sum(s[k] for s in scores) for k in ("hits", "predicted", "truth"))
    p, r = hits / max(pred, 1), hits / max(true, 1)
    return p, r, 2 * p * r / max(p + r, 1e-9), hits, pred, true


def dedup_pairs(rows: list[dict], config: CurateConfig) -> tuple[int, int, int, int, list[str]]:
    """(tp, fp, fn, n_clean, errors) over all pairs of clean segments of one seed's corpus;
    errors name each false or missed pair with its signature distance."""
    clean = [row for row in rows if row["signature"] is not None]
    if not clean:
        return 0, 0, 0, 0, []
    signatures = {row["key"]: row["signature"] for row in clean}
    exact = analyse.exact_for({row["key"]: row["span"] for row in clean}, config)  # as the flow's
    result = dedup.group(signatures, {row["key"]: (0, row["sharpness"]) for row in clean}, config.dedup, exact)
    group_of = {m: k for k, members in result.groups.items() for m in members}
    content = {row["key"]: row["segment"]["content_id"] for row in clean}
    tp = fp = fn = 0
    errors = []
    for a, b in itertools.combinations(sorted(content), 2):
        same, merged = content[a] == content[b], group_of[a] == group_of[b]
        tp += same and merged
        fp += merged and not same
        fn += same and not merged
        if same != merged:
            sa, sb = (exact([k]).get(k, signatures[k]) if not signatures[k].exact else signatures[k] for k in (a, b))
            errors.append(f"{'false' if merged else 'missed'} pair {a} ~ {b}: "
                          + _pair_distances(sa, sb, config.dedup))
    return tp, fp, fn, len(clean), errors


def _pair_distances(sa, sb, config) -> str:
    """The two numbers dedup.group decides a pair on: hash distance and pixel residual."""
    hashes = np.stack([sa.hashes, sb.hashes])
    dist, hyp, clear = hash_distance(hashes, np.array([[0, 1]]))
    residual = footage_distance(sa, sb, int(hyp[0]), bool(clear[0]), config)
    return (f"hash {dist[0]:.3f} (max {config.hash_max}), crop {int(hyp[0])}, "
            f"residual {residual:.2f} (max {config.residual_max})")


def report(title: str, rows: list[dict], cuts: list[tuple], pairs: tuple[int, int, int, int]) -> None:
    print(f"\n=== {title}: {len(rows)} segments ===")
    for name, k, target in (("cuts (hard cuts only)", 0, "  target F1 >= 0.95"), ("transitions", 1, ""),
                            ("any boundary", 2, "")):
        p, r, f, hits, pred, true = _prf([c[k] for c in cuts])
        print(f"{name:22s} P {p:.3f} R {r:.3f} F1 {f:.3f}  ({hits} hits, {pred} predicted, {true} true){target}")
    labels = [row["segment"]["label"] for row in rows]
    support = Counter(label or "clean" for label in labels)
    print("support: " + ", ".join(f"{k} {support.get(k, 0)}" for k in ("clean",) + DEFECT_LABELS))
    print(f"{'filter':14s} {'P':>6s} {'R':>6s} {'tp':>4s} {'fp':>4s} {'fn':>4s}  (targets P, R >= 0.90)")
    for stage, classes in FILTER_GROUPS.items():
        predicted = [row["verdicts"].get(stage) for row in rows]
        pr = precision_recall(predicted, labels, set(classes))
        flag = "" if pr.precision >= 0.9 and pr.recall >= 0.9 else "  SHORT"
        print(f"{stage:14s} {pr.precision:6.3f} {pr.recall:6.3f} {pr.tp:4d} {pr.fp:4d} {pr.fn:4d}{flag}")
    print("confusion (truth label -> every rejecting filter's reason, or keep):")
    table = defaultdict(Counter)
    for row, label in zip(rows, labels):
        reasons = [v for v in row["verdicts"].values() if v] or ["keep"]
        table[label or "clean"].update(["+".join(reasons)])
    for label in ("clean",) + DEFECT_LABELS:
        if label in table:
            print(f"  {label:26s} " + ", ".join(f"{k}: {v}" for k, v in table[label].most_common()))
    tp, fp, fn, n, errors = pairs
    print(f"dedup over {n} clean segments: pairs P {tp / max(tp + fp, 1):.3f} R {tp / max(tp + fn, 1):.3f} "
          f"(tp {tp}, fp {fp}, fn {fn}; targets R >= 0.95 at P >= 0.98)")
    for line in errors:
        print(f"  {line}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=list(HELD_OUT_SEEDS))
    ap.add_argument("--tuning", action="store_true", help="allow tuning seeds (figures are then not held-out)")
    ap.add_argument("--minutes", type=float, default=6.0)
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--corpus", type=Path, default=None, help="folder to keep and reuse generated footage")
    ap.add_argument("--dump", type=Path, default=None, help="write every segment's scores and verdicts as JSON")
    ap.add_argument("--config", type=Path, default=None, help="YAML of CurateConfig overrides (as `worldline curate`)")
    args = ap.parse_args()
    tuned = sorted(set(args.seeds) & set(TUNING_SEEDS))
    if tuned and not args.tuning:
        sys.exit(f"seeds {tuned} are tuning seeds (TUNING_SEEDS = {TUNING_SEEDS}): their figures say nothing about "
                 "unseen footage. Use held-out seeds, or pass --tuning to look at them anyway.")
    banner = "TUNING SEEDS (thresholds were chosen on these; NOT a held-out result)" if tuned else "held-out seeds"
    width, height = map(int, args.size.split("x"))
    try:
        config = load_config(args.config)
    except ConfigError as exc:
        sys.exit(str(exc))
    root = args.corpus or Path(__import__("tempfile").mkdtemp(prefix="wl-quality-"))
    t0 = time.perf_counter()
    print(f"{banner}: {args.seeds}, {args.minutes} min each at {width}x{height} 30 fps "
          f"(analysis long side {config.analysis.long_side} px), footage in {root}")
    all_rows, all_cuts, all_pairs, dump = [], [], [0, 0, 0, 0, []], []
    for seed in args.seeds:
        rows, cuts = [], []
        for truth_path in corpus(root, seed, args.minutes, width, height):
            truth = json.loads(truth_path.read_text())
            spans, judged = judge_video(truth_path.with_name(truth["video"]), truth, config)
            cuts.append(_cuts(spans, truth))
            for row in judged:
                row["key"] = f"{seed}/{truth['video']}/{row['segment']['start']}"
            rows.extend(judged)
        pairs = dedup_pairs(rows, config)
        report(f"seed {seed}{' (TUNING)' if seed in TUNING_SEEDS else ''}", rows, cuts, pairs)
        all_rows += rows
        all_cuts += cuts
        all_pairs = [a + b for a, b in zip(all_pairs, pairs)]
        dump += [{"key": r["key"], "label": r["segment"]["label"], "verdicts": r["verdicts"], "scores": r["scores"]}
                 for r in rows]
    report(f"POOLED over {banner} {args.seeds}", all_rows, all_cuts, tuple(all_pairs))
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    if args.dump:
        args.dump.write_text(json.dumps(dump, indent=0, default=float))


if __name__ == "__main__":
    main()

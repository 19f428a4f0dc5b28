"""Curation on real footage: cuts, verdicts and per-label filter figures on videos nobody here made.

Runs the curate analysis (``tasks.curate.analyse.analyse_video``, the default config unless
``--config`` is given) on every file of ``../shared/data/videos-dev`` (hand-checked labels in its
``labels.json``) and of ``../shared/data/videos`` (labels below, from that folder's README), and
prints:

- cut precision, recall and F1, a hit within 2 frames (``scenes.cut_f1``);
- verdict accuracy: each file's verdict is the outcome covering most of its frames, where a
  clip is ``reject`` when a filter rejected it, ``tag_text`` when kept with ``overlay:text``,
  ``keep`` otherwise;
- precision and recall per label of the tag or rejection that should answer it (``LABELS``: a
  file says a label when clips covering most of its judged frames say it; a freeze, when any
  clip is rejected as frozen), and of decode-reported corruption against ``corrupted_frames``;
- one line per error naming the file, the frames and the program's reason.

Entries marked ``uncertain`` in the labels are scored on their own line, not in the headline
figures (the labels' README: "not scored strictly"). Issue 27 targets, development set,
default config: cut F1 >= 0.97, verdict accuracy >= 0.9, no clip rejected as overlay text that
shows none.

    .venv/bin/python bench/curate_real.py
    options: --dev DIR --videos DIR --config FILE.yaml --only NAME ... --json OUT.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tasks.curate.analyse import analyse_video  # noqa: E402
from tasks.curate.config import load_config  # noqa: E402
from tasks.curate.decode import analysis_frames  # noqa: E402
from tasks.curate.filters import run_filters  # noqa: E402
from tasks.curate.quality import QualityConfig  # noqa: E402
from tasks.curate.scenes import cut_f1  # noqa: E402
from tasks.video import DecodeError  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"

# ../shared/data/videos: labels from its README ("what it is good for"); the verdict of a file
# the README does not settle is marked uncertain.
VIDEOS_LABELS = {
    "bikes.mp4": {"hard_cuts": [30, 76, 137, 187, 242], "verdict": "keep", "labels": ["faces", "outdoor"]},
    "carphone_pristine.mp4": {"hard_cuts": [], "verdict": "keep", "labels": ["faces"]},
    "carphone_distorted.mp4": {"hard_cuts": [], "verdict": "reject", "labels": ["faces", "compression_artifacts"],
                               "uncertain": True, "uncertain_why": "heavy compression: reject only if a quality filter calls it"},
    "chaplin.mp4": {"hard_cuts": [], "verdict": "keep", "labels": ["black_and_white", "letterbox"],
                    "uncertain": True, "uncertain_why": "an old film: physical footage; the README does not list its cuts"},
    "fire2.mp4": {"hard_cuts": [], "verdict": "reject", "labels": ["handheld", "shaky", "motion_blur"]},
    "smpte-2997.mp4": {"hard_cuts": [], "verdict": "reject", "labels": ["test_pattern", "text_timestamp"]},
    "aloha_sim_transfer_cube.mp4": {"hard_cuts": [], "verdict": "keep", "labels": ["simulation"], "uncertain": True,
                                    "uncertain_why": "a simulator render: the embodiment footage the platform trains on"},
}


def _overlay(c) -> bool:
    return "overlay:text" in c.tags or c.reject_reason == "overlay_text"


def _type(*kinds):
    return lambda c: any(f"type:{k}" in c.tags or c.reject_reason == f"non_physical:{k}" for k in kinds)


def _reason(*reasons):
    return lambda c: c.reject_reason in reasons


def _frozen(c) -> bool:
    """Quality's frozen test on the clip's scores: another filter may have rejected it first."""
    q = QualityConfig()
    return c.reject_reason == "frozen" or (c.scores.get("frozen_s", 0.0) >= q.frozen_min_s
                                           and c.scores.get("frozen_motion", 0.0) >= q.frozen_motion)


# name -> (the labels it answers, what answers it on one clip, what the answer is called)
LABELS = {
    "animation": ({"animation", "cgi"}, _type("animation"), "type:animation"),
    "slides": ({"slides"}, _type("slides", "screen"), "type:slides"),
    "test_pattern": ({"test_pattern"}, _type("test_pattern"), "type:test_pattern"),
    "shaky": ({"shaky"}, _reason("shake"), "rejected as shake"),
    "static": ({"static"}, _reason("static"), "rejected as static"),
    "burned-in text": ({"text_timestamp", "text_caption"}, _overlay, "overlay:text"),
    "overexposed": ({"overexposed"}, _reason("overexposed"), "rejected as overexposed"),
    "frozen": ({"frozen_frames"}, _frozen, "frozen (quality's frozen_s and frozen_motion)"),
}
FILE_LABELS = {"corrupted_frames": "decode reported corrupt, missing or concealment-smeared frames"}


def judged(clips):
    """The clips a filter judged: a span shorter than ``min_scene_s`` is a length policy, not a
    verdict on the footage, so it does not vote."""
    return [c for c in clips if c.reject_reason != "too_short"]


def file_verdict(clips) -> tuple[str, dict[str, int]]:
    """The outcome covering most judged frames, and the frames of each outcome."""
    frames: Counter = Counter()
    for c in judged(clips):
        outcome = "reject" if not c.kept else ("tag_text" if "overlay:text" in c.tags else "keep")
        frames[outcome] += c.end_frame - c.start_frame
    return (frames.most_common(1)[0][0] if frames else "reject"), dict(frames)


def majority(clips, predicate) -> bool:
    clips = judged(clips)
    total = sum(c.end_frame - c.start_frame for c in clips)
    hit = sum(c.end_frame - c.start_frame for c in clips if predicate(c))
    return total > 0 and hit * 2 > total


def why(clips) -> str:
    parts = []
    for c in clips:
        what = "kept" if c.kept else f"{c.reject_stage}:{c.reject_reason}"
        tags = ",".join(t for t in c.tags if t.startswith(("type:", "overlay:", "camera:shake")))
        parts.append(f"{c.start_frame}-{c.end_frame} {what}" + (f" [{tags}]" if tags else ""))
    return "; ".join(parts)


def whole_file(path: Path, analysis, config) -> list:
    """The file judged by the filters as one scene (a file shorter than ``min_scene_s``)."""
    frames = list(analysis_frames(path, config.analysis))
    if len(frames) < 2:
        return list(analysis.clips)
    images = np.stack([f.image for f in frames])
    times = np.asarray([f.time for f in frames])
    verdict, _ = run_filters(images, times, config.filters())
    first = analysis.clips[0]
    return [first.model_copy(update={"start_frame": frames[0].index, "end_frame": frames[-1].index + 1,
                                     "kept": verdict.keep, "reject_stage": verdict.stage,
                                     "reject_reason": verdict.reason, "tags": verdict.tags,
                                     "scores": {k: v for k, v in verdict.scores.items() if np.isfinite(v)}})]


def score_file(name: str, path: Path, truth: dict, config) -> dict:
    t0 = time.perf_counter()
    sha = hashlib.sha256(path.read_bytes()).hexdigest()
    try:
        analysis = analyse_video(path, sha, config)
    except DecodeError as exc:
        return {"file": name, "error": str(exc), "verdict": "reject", "seconds": time.perf_counter() - t0,
                "clips": [], "cuts": [], "transitions": [], "corrupt": True}
    spans = list(analysis.clips)
    whole = False
    if not judged(spans):  # the whole file is shorter than a scene: judge it as one, as labelled
        spans, whole = whole_file(path, analysis, config), True
    starts = sorted(c.start_frame for c in spans)
    # A cut is every clip start after the first that the splitter did not make by splitting a
    # long shot; transitions are not clips, so a clip starting after one is not a cut either.
    from tasks.curate.scenes import scenes_of  # the spans, with their causes, from one more pass
    scenes = list(scenes_of(path, config.scenes, config.analysis))
    cuts = [s.start_frame for s in scenes if s.kind != "transition" and s.cause == "cut"]
    transitions = [(s.start_frame, s.end_frame) for s in scenes if s.kind == "transition"]
    verdict, frames = file_verdict(spans)
    d = analysis.decode
    return {"file": name, "verdict": verdict, "verdict_frames": frames, "clips": spans, "cuts": cuts,
            "transitions": transitions, "starts": starts, "why": ("whole file judged: " if whole else "") + why(spans),
            "corrupt": bool(d.get("corrupt") or d.get("missing") or d.get("decode_errors") or d.get("smeared")),
            "seconds": time.perf_counter() - t0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dev", type=Path, default=SHARED / "videos-dev")
    ap.add_argument("--videos", type=Path, default=SHARED / "videos")
    ap.add_argument("--config", type=Path, default=None)
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if not (args.dev / "labels.json").is_file():
        print(f"{args.dev}: no labels.json; nothing to score (the real videos live in ../shared/data)")
        return 0
    config = load_config(args.config)
    sets = {"dev": (args.dev, json.loads((args.dev / "labels.json").read_text()))}
    if args.videos.is_dir():
        sets["videos"] = (args.videos, {k: v for k, v in VIDEOS_LABELS.items() if (args.videos / k).is_file()})
    t0 = time.perf_counter()
    summary = {}
    for set_name, (folder, labels) in sets.items():
        results, errors = [], []
        for name, truth in sorted(labels.items()):
            if args.only and name not in args.only:
                continue
            r = score_file(name, folder / name, truth, config)
            r["truth"] = truth
            results.append(r)
        summary[set_name] = report(set_name, results)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(summary, indent=1, sort_keys=True, default=str))
    return 0


def report(set_name: str, results: list[dict]) -> dict:
    print(f"\n=== {set_name}: {len(results)} files")
    out = {}
    lines = []
    for tag in ("certain", "uncertain", "all"):
        group = [r for r in results if tag == "all" or bool(r["truth"].get("uncertain")) == (tag == "uncertain")]
        if not group:
            continue
        pred_cuts = hits = truth_cuts = 0
        for r in group:
            t = r["truth"]
            f = cut_f1(r["cuts"] + [tuple(x) for x in r["transitions"]], t.get("hard_cuts", []),
                       [tuple(x) for x in t.get("transitions", [])])
            pred_cuts += f["predicted"]
            hits += f["hits"]
            truth_cuts += f["truth"]
        p = hits / pred_cuts if pred_cuts else 1.0
        rc = hits / truth_cuts if truth_cuts else 1.0
        f1 = 2 * p * rc / (p + rc) if p + rc else 0.0
        acc = sum(r["verdict"] == r["truth"]["verdict"] for r in group) / len(group)
        print(f"[{tag}, {len(group)} files] cuts: precision {p:.3f} recall {rc:.3f} F1 {f1:.3f} "
              f"({hits} hits, {pred_cuts} predicted, {truth_cuts} true); verdict accuracy {acc:.3f}")
        out[tag] = {"cut_precision": p, "cut_recall": rc, "cut_f1": f1, "verdict_accuracy": acc, "files": len(group)}
    # per label, every file (uncertain ones too: their labels are certain, their verdicts not)
    counts = defaultdict(Counter)
    for r in results:
        have = set(r["truth"].get("labels", []))
        for label, (wanted, predicate, answer) in LABELS.items():
            # A freeze is a stretch of a file, not most of it: any clip rejected as frozen answers it.
            said = majority(r["clips"], predicate) if label != "frozen" else any(predicate(c) for c in r["clips"])
            labelled = bool(wanted & have)
            key = "tp" if (said and labelled) else "fp" if said else "fn" if labelled else "tn"
            counts[label][key] += 1
            if key == "fp":
                lines.append(f"{r['file']}: {answer} but not labelled {'/'.join(sorted(wanted))} ({r.get('why', '')})")
            elif key == "fn":
                lines.append(f"{r['file']}: labelled {'/'.join(sorted(wanted & have))}, program did not say {answer} "
                             f"({r.get('why', '')})")
        said = r["corrupt"]
        have_c = "corrupted_frames" in have
        counts["corrupted_frames"]["tp" if said and have_c else "fp" if said else "fn" if have_c else "tn"] += 1
        if said != have_c:
            lines.append(f"{r['file']}: corrupted_frames labelled {have_c}, decode reported {said}")
    print("label             P      R    (tp fp fn)")
    for label, c in counts.items():
        if c["tp"] + c["fn"] + c["fp"] == 0:
            continue
        p = c["tp"] / (c["tp"] + c["fp"]) if c["tp"] + c["fp"] else float("nan")
        rc = c["tp"] / (c["tp"] + c["fn"]) if c["tp"] + c["fn"] else float("nan")
        print(f"{label:16s} {p:5.2f}  {rc:5.2f}   ({c['tp']} {c['fp']} {c['fn']})")
        out.setdefault("labels", {})[label] = {"precision": p, "recall": rc, **c}
    # overlay-text rejections of clips that show none
    wrong_text = [(r["file"], c) for r in results for c in r["clips"]
                  if c.reject_reason == "overlay_text" and not ({"text_timestamp", "text_caption", "slides", "test_pattern"}
                                                                  & set(r["truth"].get("labels", [])))]
    print(f"clips rejected as overlay text that show none: {len(wrong_text)}")
    out["text_false_rejects"] = len(wrong_text)
    for name, c in wrong_text:
        lines.append(f"{name}: frames {c.start_frame}-{c.end_frame} rejected as overlay text "
                     f"(text_area {c.scores.get('text_area', float('nan')):.4f}), none labelled")
    for r in results:
        t = r["truth"]
        u = " (uncertain)" if t.get("uncertain") else ""
        if r.get("error"):
            lines.append(f"{r['file']}: quarantined: {r['error']}")
        if r["verdict"] != t["verdict"]:
            lines.append(f"{r['file']}{u}: verdict {r['verdict']}, labelled {t['verdict']} ({r.get('why', '')})")
        truth_cuts = list(t.get("hard_cuts", []))
        for c in r["cuts"]:
            if not any(abs(c - x) <= 2 for x in truth_cuts):
                lines.append(f"{r['file']}{u}: false cut at frame {c}")
        for a, b in r["transitions"]:
            if not any(a - 2 <= x <= b + 1 for x in truth_cuts):
                lines.append(f"{r['file']}{u}: false transition at frames {a}-{b}")
        for x in truth_cuts:
            if not any(abs(c - x) <= 2 for c in r["cuts"]) and not any(a - 2 <= x <= b + 1 for a, b in r["transitions"]):
                lines.append(f"{r['file']}{u}: missed cut at frame {x}")
    print(f"errors ({len(lines)}):")
    for line in lines:
        print("  " + line)
    print("per file: " + ", ".join(f"{r['file']} {r['seconds']:.1f}s" for r in results))
    return out


if __name__ == "__main__":
    raise SystemExit(main())

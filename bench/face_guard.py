"""Face guard on real footage: recall of hand-labelled faces, false boxes on face-free footage,
and cost per 720p frame on one core, CenterFace (default) side by side with the Haar cascades.

    .venv/bin/python bench/face_guard.py [--detect-every N] [--free-every K] [--detectors centerface haar]

Labels: tests/tasks/guard/face_boxes.json (boxes drawn by hand on sampled frames; see its notes).
Videos: ../shared/data/videos and ../shared/data/videos-dev.

- Recall: for each labelled frame f the guard runs as over the whole video with ``detect_every``
  N (curation's value by default), on frames a - 3N .. b = min(a + N, last), a = f - f % N,
  detecting on every Nth and carrying boxes to f: three detections back is what the guard
  remembers of a face held after a miss (found one detection before it, its speed from the one
  before that). A labelled face of at least 20 px (its shorter side) counts as hidden when, on the guarded frame, the mean absolute Laplacian inside
  its box fell to at most HIDDEN of the original's (the blur removes the detail; a box blurred
  only in part keeps most of it). Frames are turned upright first (``rotate``), as the guard
  sees them in curation.
- False boxes: detections (not carried boxes) per 100 searched frames on face-free footage,
  every K-th frame searched.
- Cost: detect_faces on one 1280 x 720 frame (a real frame of group.mp4 scaled up), one thread.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tasks.curate.config import CurateConfig  # noqa: E402
from tasks.guard.config import GuardConfig  # noqa: E402
from tasks.guard.faces import detect_faces, guard_stream  # noqa: E402
from tasks.video import stored_frames  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
LABELS = ROOT / "tests" / "tasks" / "guard" / "face_boxes.json"
MIN_SIDE = 20
HIDDEN = 0.5


def decode(path: Path) -> list[np.ndarray]:
    return list(stored_frames(path))


def rotate_box(box, shape, turns: int):
    """A box of an H x W frame, in the frame np.rot90(frame, turns) (counter-clockwise turns)."""
    x, y, w, h = box
    height, width = shape[:2]
    for _ in range(turns % 4):
        x, y, w, h = y, width - x - w, h, w
        height, width = width, height
    return x, y, w, h


def detail(frame: np.ndarray, box) -> float:
    x, y, w, h = box
    grey = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2GRAY).astype(np.float32)
    lap = np.abs(cv2.Laplacian(grey, cv2.CV_32F))
    return float(lap[max(0, y):y + h, max(0, x):x + w].mean())


def guarded_at(frames: list[np.ndarray], f: int, config: GuardConfig) -> np.ndarray:
    every = config.detect_every
    a = f - f % every
    b = min(a + every, len(frames) - 1)
    # Three detections back: a face held after a miss was found the detection before, its speed from the one before that.
    start = max(0, a - 3 * every)
    for i, (out, _) in enumerate(guard_stream(frames[start:b + 1], config), start=start):
        if i == f:
            return out
    raise AssertionError(f)


def recall(config: GuardConfig, labels: dict) -> tuple[dict, int, int]:
    per_video, hidden_all, total_all = {}, 0, 0
    for name, entry in labels["videos"].items():
        frames = decode(DATA / entry["dir"] / name)
        turns = entry.get("rotate", 0)
        upright = [np.ascontiguousarray(np.rot90(f, turns)) for f in frames] if turns else frames
        hidden = total = 0
        for key, boxes in entry["frames"].items():
            f = int(key)
            boxes = [rotate_box(b, frames[f].shape, turns) for b in boxes if min(b[2], b[3]) >= MIN_SIDE]
            if not boxes:
                continue
            out = guarded_at(upright, f, config)
            for box in boxes:
                total += 1
                hidden += detail(out, box) <= HIDDEN * max(detail(upright[f], box), 1e-6)
        per_video[name] = (hidden, total)
        hidden_all += hidden
        total_all += total
    return per_video, hidden_all, total_all


def false_boxes(config: GuardConfig, labels: dict, every: int) -> dict:
    out = {}
    for name, folder in labels["face_free"]["videos"].items():
        frames = decode(DATA / folder / name)[::every]
        out[name] = (sum(len(detect_faces(f, config)) for f in frames), len(frames))
    return out


def cost_ms(config: GuardConfig, repeat: int = 5) -> float:
    frame = decode(DATA / "videos-dev" / "group.mp4")[0]
    frame = cv2.resize(frame, (1280, 720), interpolation=cv2.INTER_CUBIC)
    detect_faces(frame, config)  # load the model / cascades
    t0 = time.perf_counter()
    for _ in range(repeat):
        detect_faces(frame, config)
    return (time.perf_counter() - t0) / repeat * 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--detect-every", type=int, default=CurateConfig().guard.detect_every)
    parser.add_argument("--free-every", type=int, default=10, help="search every K-th frame of face-free footage")
    parser.add_argument("--detectors", nargs="+", default=["centerface", "haar"], choices=["centerface", "haar"])
    args = parser.parse_args()
    cv2.setNumThreads(1)  # one core, as curation runs one video per worker
    labels = json.loads(LABELS.read_text())
    base = CurateConfig().guard.model_copy(update={"detect_every": args.detect_every})
    results = {}
    for detector in args.detectors:
        config = base.model_copy(update={"detector": detector})
        t0 = time.perf_counter()
        per_video, hidden, total = recall(config, labels)
        found = false_boxes(config, labels, args.free_every)
        ms = cost_ms(config)
        results[detector] = per_video, hidden, total, found, ms
        print(f"({detector}: {time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    names = list(results)
    print(f"detect_every={base.detect_every} min_face={base.min_face} pad={base.pad} score={base.score} (centerface)")
    print(f"{'':36s}" + "".join(f"{n:>14s}" for n in names))
    rows = results[names[0]][0]
    for video in rows:
        cells = "".join(f"{f'{h}/{n} {h / n:.2f}':>14s}" for h, n in (results[d][0][video] for d in names))
        print(f"  recall {video:28s}{cells}")
    cells = "".join(f"{f'{r[1]}/{r[2]} {r[1] / r[2]:.3f}':>14s}" for r in results.values())
    print(f"  {f'recall, faces >= {MIN_SIDE} px':34s}{cells}")
    for video in results[names[0]][3]:
        cells = "".join(f"{f'{results[d][3][video][0]} in {results[d][3][video][1]}':>14s}" for d in names)
        print(f"  false boxes {video:23s}{cells}")
    per_100 = []
    for r in results.values():
        boxes, frames = sum(b for b, _ in r[3].values()), sum(n for _, n in r[3].values())
        per_100.append(f"{100 * boxes / frames:.1f}")
    print(f"  {'false boxes per 100 face-free frames':34s}" + "".join(f"{c:>14s}" for c in per_100))
    print(f"  {'ms per 1280x720 frame, one core':34s}" + "".join(f"{r[4]:14.0f}" for r in results.values()))
    print(f"  {f'ms per frame at detect_every={base.detect_every}':34s}"
          + "".join(f"{r[4] / base.detect_every:14.0f}" for r in results.values()) + "   (hiding not counted)")


if __name__ == "__main__":
    main()

"""How exactly the camera-control estimator reads a camera's motion from true frames (issue 33).

Renders held-out episodes of `manifests/camera_control_aisle.yaml` (the camera's pose at every
frame), and from windows every 6 frames re-estimates the motion over 4, 8, 12 and 16 frames
three ways: the general essential matrix on the pair of frames, the planar (ground-rig) fit on
the pair, and the planar fit frame to frame, composed (`trajectory_errors`, what `worldline
evaluate camera` uses). Prints per horizon the mean true rotation, each way's mean rotation
error and median translation-direction error (degrees) and its failures (pairs with too few
matches, scored as no motion).

With ``--tokenizer CKPT ...`` it also reads the motion frame to frame from each tokenizer's
reconstruction of the same frames (what `evaluate camera` calls the ceiling: no world model can
score better than the frames its decoder gives back) and prints each one's PSNR on them, so a
tokenizer can be judged for camera control before a world model is trained on it.

    .venv/bin/python bench/camera_motion.py [--seeds 10000 10001] [--camera front] [--tokenizer CKPT ...]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from tasks.manifests import load
from tasks.tokenize.data import square
from tasks.tokenize.tokens import load_checkpoint
from tasks.world.camera_control import render_heldout
from tasks.world.heldout import decode, encode
from tasks.world.camera_motion import motion_errors, motion_table, trajectory_errors

MANIFEST = Path(__file__).resolve().parent.parent / "manifests" / "camera_control_aisle.yaml"
HORIZONS = (4, 8, 12, 16)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[10000, 10001])
    parser.add_argument("--camera", default="front")
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--every", type=int, default=6, help="frames between window starts")
    parser.add_argument("--tokenizer", nargs="*", default=[],
                        help="tokenizer checkpoint folders whose reconstruction is read too")
    args = parser.parse_args()
    manifest = load(MANIFEST)
    tokenizers = {Path(t).name[:12]: load_checkpoint(Path(t)) for t in args.tokenizer}
    rows, psnr, started = [], {name: [] for name in tokenizers}, time.perf_counter()
    for seed in args.seeds:
        truth, poses = render_heldout(manifest, seed, args.camera)
        frames, cams = square(truth.frames, args.size), [c.square(args.size) for c in poses]
        recons = {}
        for name, tokenizer in tokenizers.items():
            recon = decode(tokenizer, encode(tokenizer, truth.frames, args.size))
            mse = np.mean((recon.astype(np.float64) - frames[:len(recon)]) ** 2)
            psnr[name].append(10 * np.log10(255.0 ** 2 / max(mse, 1e-12)))
            recons[name] = recon
        frames = frames[:min([len(frames), *map(len, recons.values())])]
        true_steps: dict = {}  # windows overlap: each step of the true frames is estimated once
        for last in range(8, len(frames) - max(HORIZONS) - 1, args.every):
            for h in HORIZONS:
                for name, planar in (("general, pair", False), ("planar, pair", True)):
                    rows.append({"horizon": h, "source": name,
                                 **motion_errors(frames[last], frames[last + h], cams[last], cams[last + h],
                                                 planar=planar)})
            chained = trajectory_errors(frames[last:last + max(HORIZONS) + 1], cams[last:last + max(HORIZONS) + 1],
                                        steps=true_steps, keys=list(range(last, last + max(HORIZONS) + 1)))
            rows += [{"horizon": h, "source": "planar, frame to frame", **chained[h - 1]} for h in HORIZONS]
            for name, recon in recons.items():
                chained = trajectory_errors(recon[last:last + max(HORIZONS) + 1], cams[last:last + max(HORIZONS) + 1])
                rows += [{"horizon": h, "source": f"reconstruction {name}", **chained[h - 1]} for h in HORIZONS]
    table = motion_table(rows)
    print(f"# camera_motion ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}): {MANIFEST.name}, camera "
          f"{args.camera} at {args.size} px, seeds {args.seeds}, windows every {args.every} frames; "
          f"{time.perf_counter() - started:.0f} s")
    for name, values in psnr.items():
        print(f"tokenizer {name}: PSNR {min(values):.2f}-{max(values):.2f} dB on these episodes")
    print("| horizon (frames) | true rotation | way | rotation error, mean | direction error, median | failed |")
    print("|---|---|---|---|---|---|")
    for r in table:
        direction = "-" if r["direction_median_deg"] is None else f"{r['direction_median_deg']:.1f}"
        print(f"| {r['horizon']} | {r['true_rotation_mean_deg']:.2f} | {r['source']} | {r['rotation_mean_deg']:.2f} | "
              f"{direction} | {r['failures']} of {r['pairs']} |")
    assert np.isfinite([r["rotation_mean_deg"] for r in table]).all()


if __name__ == "__main__":
    main()

"""A smoke run of the transfer model (docs/transfer.md): simulator pairs of a manifest, a short
training of a preset, free-running PSNR per look on a held-out seed (for a preset with
reference conditioning, such as small-ref, also given a reference clip). Prints JSON lines.

    .venv/bin/python bench/transfer_smoke.py --seconds 100 --out /tmp/transfer-smoke
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tasks.manifests import load  # noqa: E402
from tasks.tokenize.train import psnr  # noqa: E402
from tasks.transfer.pairs import make_pairs  # noqa: E402
from tasks.transfer.train import TrainConfig, evaluate, new_model, save_transfer, train_transfer  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--manifest", default="manifests/push_closeup.yaml")
    parser.add_argument("--seeds", type=int, nargs="+", default=[21, 22, 23, 24])
    parser.add_argument("--held-out", type=int, default=25)
    parser.add_argument("--preset", default="small")
    parser.add_argument("--seconds", type=float, default=90.0)
    parser.add_argument("--horizon", type=float, default=None, help="seconds of each episode (default: the manifest's)")
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--frames", type=int, default=3, help="frames per training window")
    parser.add_argument("--eval-frames", type=int, default=8, help="frames of each clip generated for the PSNR")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (2 on the loaded 2-core machine ran 3 to 30 times slower)")
    parser.add_argument("--temporal", type=float, default=TrainConfig().temporal,
                        help="weight of the temporal loss (TrainConfig.temporal)")
    parser.add_argument("--self-feed", type=float, default=TrainConfig().self_feed,
                        help="chance a window's previous frames are the model's own (TrainConfig.self_feed)")
    parser.add_argument("--out", type=Path, default=None, help="checkpoint folder")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    started = time.perf_counter()
    manifest = load(args.manifest)
    pairs = make_pairs(manifest, args.seeds, horizon_s=args.horizon)
    held = make_pairs(manifest, [args.held_out], horizon_s=args.horizon)
    print(json.dumps({"pairs": len(pairs), "frames": int(pairs[0].frames.shape[0]),
                      "simulate_s": round(time.perf_counter() - started, 1)}), flush=True)
    # Baseline: the source look's frames as the answer for every look (what no transfer scores).
    source = {p.seed: p.frames for p in held if p.prompt == "nominal"}
    as_is = lambda f: torch.from_numpy(f[:args.eval_frames]).float().div(127.5).sub(1).movedim(-1, 0)[None]  # noqa: E731
    print(json.dumps({"held_out_psnr_source_as_is": {p.prompt: float(np.mean(psnr(as_is(p.frames), as_is(source[p.seed])).item()))
                                                     for p in held}}), flush=True)
    config = TrainConfig(preset=args.preset, steps=100_000, seconds=args.seconds, batch_size=args.batch,
                         clip_frames=args.frames, threads=args.threads, log_every=20, temporal=args.temporal,
                         self_feed=args.self_feed)
    model = new_model(config)
    print(json.dumps({"held_out_psnr_before": evaluate(model, held, frames=args.eval_frames)}), flush=True)
    history = train_transfer(model, pairs, config, on_log=lambda r: print(json.dumps(r), flush=True))
    print(json.dumps({"held_out_psnr_after": evaluate(model, held, frames=args.eval_frames),
                      "train_psnr_after": evaluate(model, pairs, frames=args.eval_frames)}), flush=True)
    if model.config.reference:
        # The look from a reference clip: the held-out seed's own stressed render (its colours
        # exactly) and a training seed's render of the same look (another draw of that look);
        # each with its segmentation, which gives a palette model the clip's class colours.
        own = {(p.seed, p.prompt): p for p in held}
        other = {p.prompt: p for p in pairs if p.seed == args.seeds[0]}
        print(json.dumps({
            "held_out_psnr_reference_own": evaluate(model, held, args.eval_frames, lambda p: own[p.seed, p.prompt]),
            "held_out_psnr_reference_other_seed": evaluate(model, held, args.eval_frames, lambda p: other[p.prompt]),
        }), flush=True)
    if args.out:
        save_transfer(model, args.out, config, history)


if __name__ == "__main__":
    main()

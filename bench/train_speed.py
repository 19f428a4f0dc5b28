"""Training speed of the tokenizer and world-model presets on a device: steps/s and samples/s.

Each preset trains through the project's own loops (``train_tokenizer``, ``train_world_model``)
on generated data of the shapes the benches use (tokenizer: windows of 1 + 2 x temporal
compression frames at 64 x 64; world model: windows of 8 x 8 x 8 codes), first ``--warmup``
steps (compilation and allocator warm-up, not counted), then ``--steps`` timed steps.
``--device`` (auto, cpu, cuda), ``--precision bf16`` and ``--compile`` as the CLI takes them
(``tasks.device.Runtime``); every row names the device it ran on. With ``--against cpu`` the
same presets also run on the CPU in the same run and the ratio is printed (a figure that
holds on a shared, noisy machine).

    .venv/bin/python bench/train_speed.py [--device auto] [--steps 20] [--warmup 3]
        [--tokenizers small-dv4x8x8] [--world-models small-wm] [--compile] [--precision bf16]
        [--against cpu]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from models.tokenizer import VideoTokenizer  # noqa: E402
from models.tokenizer import preset as tokenizer_preset  # noqa: E402
from models.world_model import WorldModel  # noqa: E402
from models.world_model import preset as world_preset  # noqa: E402
from tasks.device import Runtime  # noqa: E402
from tasks.tokenize.train import TrainConfig, train_tokenizer  # noqa: E402
from tasks.world.data import CodeSequence  # noqa: E402
from tasks.world.train import WorldTrainConfig, train_world_model  # noqa: E402


def device_name(runtime: Runtime) -> str:
    device = runtime.torch_device()
    return torch.cuda.get_device_name(device) if device.type == "cuda" else f"CPU ({torch.get_num_threads()} threads)"


def clips(frames: int, size: int = 72, n: int = 6) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (size + 32, size + 32, 3), dtype=np.uint8)
    return [np.stack([np.roll(base, 2 * j + k, axis=1)[:size, :size] for j in range(frames + 8)]) for k in range(n)]


def sequences(codebook: int, n: int = 6, frames: int = 12, grid: int = 8) -> list[CodeSequence]:
    rng = np.random.default_rng(1)
    return [CodeSequence(key=f"s{k}", codes=rng.integers(0, codebook, (frames, grid, grid)).astype(np.int64),
                         text="push the package") for k in range(n)]


def timed(run_steps) -> float:
    """Seconds for the timed steps: the loop's own per-step record, after the warm-up run."""
    history = run_steps()
    return history[-1]["seconds"]


def tokenizer_speed(name: str, runtime: Runtime, steps: int, warmup: int, batch: int) -> tuple[float, float]:
    config = tokenizer_preset(name)
    frames = 1 + 2 * config.temporal_compression
    data = clips(frames)
    torch.manual_seed(0)
    model = VideoTokenizer(config)
    base = dict(preset=name, batch_size=batch, clip_frames=frames, size=64, log_every=10 ** 6, warmup_steps=0)
    train_tokenizer(model, data, TrainConfig(steps=warmup, **base), runtime=runtime)
    seconds = timed(lambda: train_tokenizer(model, data, TrainConfig(steps=steps, **base), runtime=runtime))
    return steps / seconds, steps * batch / seconds


def world_speed(name: str, runtime: Runtime, steps: int, warmup: int, batch: int) -> tuple[float, float]:
    config = world_preset(name)
    data = sequences(config.codebook_size)
    torch.manual_seed(0)
    model = WorldModel(config)
    base = dict(preset=name, batch_size=batch, log_every=10 ** 6, warmup_steps=0)
    train_world_model(model, data, WorldTrainConfig(steps=warmup, **base), runtime=runtime)
    seconds = timed(lambda: train_world_model(model, data, WorldTrainConfig(steps=steps, **base), runtime=runtime))
    return steps / seconds, steps * batch / seconds


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="auto")
    ap.add_argument("--precision", default="fp32", choices=["fp32", "bf16"])
    ap.add_argument("--compile", action="store_true")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--tokenizers", nargs="*", default=["small-dv4x8x8"])
    ap.add_argument("--world-models", nargs="*", default=["small-wm"])
    ap.add_argument("--tokenizer-batch", type=int, default=4)
    ap.add_argument("--world-batch", type=int, default=8)
    ap.add_argument("--threads", type=int, default=2, help="CPU threads (torch.set_num_threads)")
    ap.add_argument("--against", default=None, help="a second device to run the same presets on, e.g. cpu")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    runtimes = [Runtime(device=args.device, precision=args.precision, compile=args.compile)]
    if args.against:
        runtimes.append(Runtime(device=args.against))
    results: dict[tuple[str, str], dict[int, float]] = {}
    for k, runtime in enumerate(runtimes):
        where = device_name(runtime)
        print(f"device {runtime.device} -> {where}; precision {runtime.precision}; compile {runtime.compile}; "
              f"torch {torch.__version__}", flush=True)
        for name in args.tokenizers:
            rate, samples = tokenizer_speed(name, runtime, args.steps, args.warmup, args.tokenizer_batch)
            results.setdefault(("tokenizer", name), {})[k] = rate
            print(f"  tokenizer {name:16s} {rate:8.2f} steps/s {samples:9.1f} samples/s  [{where}]", flush=True)
        for name in args.world_models:
            rate, samples = world_speed(name, runtime, args.steps, args.warmup, args.world_batch)
            results.setdefault(("world model", name), {})[k] = rate
            print(f"  world model {name:14s} {rate:8.2f} steps/s {samples:9.1f} samples/s  [{where}]", flush=True)
    if args.against:
        for (kind, name), rates in results.items():
            print(f"ratio {kind} {name}: {rates[0] / rates[1]:.2f}x {args.device} over {args.against}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Simulation + rendering throughput of scenario episodes, in frames per second per core.

Usage: .venv/bin/python bench/simulate.py [--seconds 4] [--robots-root ../shared/data/robots]

Each row rolls out the bin-pick manifest (no stressors) with one world camera at the given
size and 30 fps: physics at 500 Hz, control at 50 Hz, one rendered frame per 1/30 s.
fps/core = frames / CPU seconds of this process (all its threads, so EGL/llvmpipe work
counts), scene build excluded (shown on its own); wall fps is shown beside it. Thread pools are pinned to one thread (numpy/BLAS via
the environment, torch if installed, llvmpipe via LP_NUM_THREADS) so the figures are per core.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "LP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MUJOCO_GL", "egl")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from schemas.manifest import Camera  # noqa: E402
from tasks.manifests import load  # noqa: E402
from tasks.sim.episode import rollout  # noqa: E402
from tasks.sim.scene import SimConfig, build_scene  # noqa: E402

UR5E = "universal_robots_ur5e/ur5e.xml"


def _threads() -> str:
    try:
        import torch
    except ImportError:
        return "numpy/BLAS/llvmpipe threads = 1 (torch not installed)"
    torch.set_num_threads(1)
    return f"numpy/BLAS/llvmpipe threads = 1, torch.set_num_threads(1) -> {torch.get_num_threads()}"


def measure(manifest, side: int, seconds: float, config: SimConfig) -> tuple[int, float, float, float, bool]:
    """(frames, build cpu s, rollout wall s, rollout cpu s, lifted); rollout times exclude the build."""
    cam = Camera(name="bench", position=(1.1, 0.55, 0.75), look_at=(0.45, 0.0, 0.1), resolution=(side, side), fps=30)
    m = manifest.model_copy(update={"cameras": (cam,), "stressors": (), "horizon_s": seconds})
    build = time.process_time()
    build_scene(m, 0, config)
    build = time.process_time() - build
    wall, cpu = time.perf_counter(), time.process_time()
    episode = rollout(m, 0, config)
    wall, cpu = time.perf_counter() - wall - build, time.process_time() - cpu - build
    return episode.frames["bench"].shape[0], build, wall, cpu, episode.success


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=4.0, help="simulated seconds per row")
    parser.add_argument("--robots-root", type=Path, default=ROOT / "../shared/data/robots")
    args = parser.parse_args()
    print(_threads())
    base = load(ROOT / "manifests/bin_pick_dim_forklift.yaml")
    config = SimConfig(robots_root=args.robots_root)
    rows = [("builtin_arm", base)]
    if (args.robots_root / UR5E).is_file():
        rows.append(("ur5e+2f85", base.model_copy(update={"embodiment": base.embodiment.model_copy(
            update={"robot": "ur5e", "mjcf": UR5E})})))
    else:
        print(f"skipping UR5e: {args.robots_root / UR5E} not found (../shared/data is absent)")
    print(f"{'robot':<12} {'size':>8} {'build s':>8} {'frames':>7} {'cpu s':>7} {'fps/core':>9} {'wall fps':>9} {'lifted':>7}")
    for name, manifest in rows:
        for side in (128, 256):
            frames, build, wall, cpu, ok = measure(manifest, side, args.seconds, config)
            print(f"{name:<12} {side:>4}x{side:<3} {build:>8.2f} {frames:>7} {cpu:>7.2f} {frames / cpu:>9.1f} "
                  f"{frames / wall:>9.1f} {str(ok):>7}")


if __name__ == "__main__":
    main()

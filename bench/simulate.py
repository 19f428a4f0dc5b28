"""Simulation plus rendering throughput, frames per second per core.

Runs `rollout` (physics, scripted control, every camera rendered) single-threaded for the
built-in primitive arm and for the Menagerie UR5e (when ../shared/data is present), at
128x128 and 256x256, one camera, and prints rendered frames per second of wall time.

    .venv/bin/python bench/simulate.py [--seconds 4]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_NUM_THREADS", "1")
REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from schemas.manifest import Embodiment  # noqa: E402
from tasks.manifests import load  # noqa: E402
from tasks.sim.episode import rollout  # noqa: E402
from tasks.sim.scene import SimConfig  # noqa: E402

ROBOTS = REPO.parent / "shared" / "data" / "robots"


def manifest_for(robot: str, side: int, seconds: float):
    base = load(REPO / "manifests" / "conveyor_push.yaml")
    camera = base.cameras[0].model_copy(update={"resolution": (side, side)})
    update = {"horizon_s": seconds, "cameras": (camera,), "stressors": ()}
    if robot == "ur5e":
        update["embodiment"] = Embodiment(kind="arm", robot="ur5e", mjcf="universal_robots_ur5e/ur5e.xml")
    return base.model_copy(update=update)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=4.0, help="simulated seconds per run (30 fps camera)")
    args = ap.parse_args()
    robots = ["builtin_arm"] + (["ur5e"] if (ROBOTS / "universal_robots_ur5e").is_dir() else [])
    if len(robots) == 1:
        print("UR5e skipped: ../shared/data/robots is absent")
    config = SimConfig(robots_root=ROBOTS)
    print(f"{'robot':12s} {'size':>8s} {'frames':>7s} {'seconds':>8s} {'fps/core':>9s}")
    for robot in robots:
        for side in (128, 256):
            m = manifest_for(robot, side, args.seconds)
            rollout(m, 0, config)  # warm-up: compile, EGL context
            t0 = time.perf_counter()
            ep = rollout(m, 1, config)
            dt = time.perf_counter() - t0
            frames = sum(f.shape[0] for f in ep.frames.values())
            print(f"{robot:12s} {side:>4d}x{side:<3d} {frames:7d} {dt:8.2f} {frames / dt:9.1f}")


if __name__ == "__main__":
    main()

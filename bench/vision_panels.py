"""Stressors that bite: a vision policy and a state policy, both trained on nominal
demonstrations, evaluated cell by cell on one matched panel per task family (issue 28, point 2).

For each family (a push and a pick) it trains, from the same scripted demonstrations of the
manifest as it is (the nominal cell), the state policy (simulator state in, tasks/policy/bc.py)
and the vision policy (cameras and proprioception in, plus DAgger rounds, tasks/policy/vision.py),
then rolls both out on every cell of the panel: nominal, dim, occluder, distractors, jitter,
appearance, forklift (the default grid's cells plus a strong appearance change), on seeds no
training run used. It prints per cell the simulator's success of each policy with a Wilson
95% interval, the spread across cells, the frame detector's balanced agreement with the
simulator over every episode rendered, policy inference frames per second and training steps
per second on one thread.

``--tokenizer FAMILY=FOLDER`` (issue 28, point 1's second option) adds, for that family, vision
policies that see through that tokenizer checkpoint's encoder (frozen; ``--layers``: its
latents, its last hidden features, or both), trained on the same demonstrations with the same
steps and DAgger rounds, side by side with the CNN on the same panel.

    .venv/bin/python bench/vision_panels.py [--families push,pick] [--episodes 20] [--per-cell 10]
        [--steps 3000] [--dagger 0] [--tokenizer push=CHECKPOINT_FOLDER] [--layers latent,hidden]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from schemas.manifest import Appearance  # noqa: E402
from schemas.panel import StressorCell, StressorGrid  # noqa: E402
from tasks import manifests  # noqa: E402
from tasks.panels.grid import default_grid, expand, primary_camera  # noqa: E402
from tasks.policy import bc, vision, vision_train  # noqa: E402
from tasks.policy.evaluate import agreement, run_episode  # noqa: E402
from tasks.policy.vision_obs import ObservationSpec  # noqa: E402
from tasks.tokenize.tokens import load_checkpoint as load_tokenizer  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
FAMILIES = {"push": ("manifests/push_closeup.yaml", ("side",)),
            "pick": ("manifests/bin_pick.yaml", ("front", "wrist"))}
ORDER = ("nominal", "dim", "occluder", "distractors", "jitter", "appearance", "forklift")
TRAIN, DAGGER, PANEL = 1000, 1500, 10300  # seed offsets: demonstrations, DAgger rounds, the panel's seeds


def wilson(k: int, n: int) -> tuple[float, float]:
    if n == 0:
        return (float("nan"), float("nan"))
    z, p = 1.96, k / n
    centre, half = (p + z * z / (2 * n)) / (1 + z * z / n), z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def bench_grid(parent, per_cell: int, offset: int = PANEL) -> StressorGrid:
    """The default grid's cells in ORDER, plus a strong appearance change, on panel seeds."""
    cells = {c.name: c for c in default_grid(parent).cells}
    cells["appearance"] = StressorCell(name="appearance", stressors=(Appearance(colour_jitter=0.9, texture=True),))
    return StressorGrid(name="vision-bench", description="nominal, then one stressor at a time",
                        cells=tuple(cells[name] for name in ORDER), episodes=per_cell, seed=parent.seed + offset)


def panel(parent, per_cell: int, offset: int = PANEL):
    return expand(parent, bench_grid(parent, per_cell, offset))


def train_all(parent, cameras, episodes: int, steps: int, rounds: int, tokenizer: Path | None = None,
              layers: tuple[str, ...] = ()) -> tuple[dict, dict]:
    """The state policy, the CNN vision policy and, with ``tokenizer``, one vision policy per
    tokenizer layer, all from the same demonstrations (and the same DAgger seeds)."""
    seeds = list(range(parent.seed + TRAIN, parent.seed + TRAIN + episodes))
    timing = {}
    t = time.perf_counter()
    state_demos = bc.collect(parent, seeds)
    state, _ = bc.train_bc(state_demos, bc.TrainConfig(steps=steps))
    timing["state policy: collect + train s"] = time.perf_counter() - t
    spec = ObservationSpec(cameras=cameras, image_size=64)
    t = time.perf_counter()
    demos = vision.collect(parent, seeds, spec)
    timing["vision: collect s"] = time.perf_counter() - t
    config = bc.TrainConfig(steps=steps, batch_size=64)
    per_round = max(4, episodes // 2)
    dagger_seeds = [list(range(parent.seed + DAGGER + k * per_round, parent.seed + DAGGER + (k + 1) * per_round))
                    for k in range(rounds)]
    policies = {"state": bc.BCPolicy(state)}
    arms = [("vision", None, "latent")]
    if tokenizer is not None:
        tok = load_tokenizer(tokenizer)
        arms += [(f"vision-tok-{layer}", tok, layer) for layer in layers]
    for key, tok, layer in arms:
        t = time.perf_counter()
        model, history = vision_train.train_vision(demos, spec, config, tokenizer=tok, layer=layer)
        timing[f"{key}: train steps/s (1 thread, encoder cached)" if tok else f"{key}: train steps/s (1 thread)"] = \
            steps / (time.perf_counter() - t)
        timing[f"{key}: final smoothed loss"] = history[-1]["smoothed_loss"]
        t = time.perf_counter()
        model, _, more = vision_train.dagger(parent, spec, demos, model, dagger_seeds, config, offset=steps)
        if rounds:
            timing[f"{key}: DAgger s"] = time.perf_counter() - t
            timing[f"{key}: learner success per DAgger round"] = [
                round(r, 2) for _, r in sorted({(row["round"], row["learner_success"]) for row in more})]
        policies[key] = vision.VisionPolicy(model, spec)
    return policies, timing


def inference_fps(policy: vision.VisionPolicy, frames: int = 200) -> float:
    model, spec = policy.model, policy.spec
    x = torch.zeros((1, len(spec.cameras), 3, spec.image_size, spec.image_size), dtype=torch.uint8)
    p = torch.zeros((1, model.config.proprio_size))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with torch.inference_mode():
            model(x, p)
            t = time.perf_counter()
            for _ in range(frames):
                model(x, p)
        return frames / (time.perf_counter() - t)
    finally:
        torch.set_num_threads(threads)


def family(name: str, args) -> None:
    path, cameras = FAMILIES[name]
    parent = manifests.load(REPO / path)
    started = time.perf_counter()
    tokenizer = dict(item.split("=", 1) for item in args.tokenizer).get(name)
    policies, timing = train_all(parent, cameras, args.episodes, args.steps, args.dagger,
                                 Path(tokenizer) if tokenizer else None, tuple(args.layers.split(",")))
    spec, variants = panel(parent, args.per_cell, args.panel_offset)
    camera = primary_camera(parent, None)
    outcomes = {k: [] for k in policies}
    for pv, variant in zip(spec.variants, variants):
        for seed in pv.seeds:
            for key, policy in policies.items():
                outcomes[key].append(run_episode(variant, pv.cell, seed, policy, camera).outcome)
    print(f"\n## {name}: {parent.name}, vision policy on {', '.join(cameras)} at 64 px; "
          f"{args.episodes} demonstrations, {args.steps} steps, {args.dagger} DAgger rounds; "
          f"{args.per_cell} seeds per cell from {parent.seed + args.panel_offset}")
    print("| cell | " + " | ".join(f"{key} policy" for key in policies) + " |\n|" + "---|" * (len(policies) + 1))
    rates = {k: [] for k in policies}
    for cell in ORDER:
        row = [cell]
        for key in policies:
            mine = [o for o in outcomes[key] if o.cell == cell]
            k = sum(o.success for o in mine)
            lo, hi = wilson(k, len(mine))
            rates[key].append(k / len(mine))
            row.append(f"{k / len(mine):.2f} [{lo:.2f}, {hi:.2f}]")
        print("| " + " | ".join(row) + " |")
    for key, values in rates.items():
        print(f"{key} policy: spread across cells {max(values) - min(values):.2f} (max {max(values):.2f}, "
              f"min {min(values):.2f} in {ORDER[int(np.argmin(values))]})")
    judged = agreement([o.as_dict() for key in policies for o in outcomes[key]], "detector")
    balanced = "-" if judged["balanced"] is None else f"{judged['balanced']:.3f}"
    print(f"frame detector on {camera}: balanced agreement {balanced} ({judged['agree']}/{judged['decided']} decided, "
          f"{judged['successes']} successes, {judged['failures']} failures)")
    for key in policies:  # one line per disagreement, to find out what the detector misreads
        for o in outcomes[key]:
            if o.detector is not None and o.detector != o.success:
                print(f"disagree: {key} {o.cell} seed {o.seed}: simulator {'success' if o.success else 'failure'} "
                      f"({o.reason}); detector {o.detector_reason}")
    for key, value in timing.items():
        print(f"{key}: {value if isinstance(value, list) else round(value, 1)}")
    for key, policy in policies.items():
        if key != "state":
            print(f"{key}: inference {inference_fps(policy):.0f} frames/s (1 thread)")
    print(f"family wall time {time.perf_counter() - started:.0f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--families", default="push,pick")
    parser.add_argument("--episodes", type=int, default=20, help="nominal demonstrations per family")
    parser.add_argument("--per-cell", type=int, default=10, help="panel seeds per cell")
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--dagger", type=int, default=0, help="DAgger rounds after behaviour cloning")
    parser.add_argument("--tokenizer", action="append", default=[], metavar="FAMILY=FOLDER",
                        help="also vision policies seeing through this tokenizer checkpoint's encoder")
    parser.add_argument("--panel-offset", type=int, default=PANEL,
                        help="the panel's first seed past the manifest's (other seeds, the same cells)")
    parser.add_argument("--layers", default="latent,hidden", help="the tokenizer's layers to try: latent, hidden")
    args = parser.parse_args()
    started = time.perf_counter()
    print(f"# vision_panels ({time.strftime('%Y-%m-%d')})")
    for name in args.families.split(","):
        family(name, args)
    print(f"\nbench wall time {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()

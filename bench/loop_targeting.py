"""The loop against its controls (issue 28, point 3): does targeting the failed cells beat
spending the same budget of new demonstrations elsewhere?

From one starting vision policy (behaviour cloning on nominal demonstrations of the manifest),
three arms each get the same number of new scripted demonstrations, seen through the policy's
own cameras, and post-train the starting policy on them (``tasks/policy/posttrain.py``, the
loop's own step):
- **targeted**: the loop: manifests derived from the ``--worst`` lowest cells of the starting
  policy's panel, the budget shared by failure rate (``tasks/loop.py``);
- **nominal**: the budget on the manifest as it is;
- **uniform**: the budget spread evenly over every cell of the panel.
Each arm runs ``--repeats`` times with independent demonstration and training seeds. Every
policy is evaluated on the same held-out panel seeds (which no demonstration used). It prints
each repeat's success on the cells that failed as it goes, then per cell success before and after for each arm (pooled over repeats) with a bootstrap 95%
interval over episodes, the gain on the cells that failed against the better control, and
the wall time. With several ``--budget`` values it runs every arm at each (an arm's
demonstrations at a smaller budget are the first ones of its larger budget: derived manifests
draw seeds in order) and prints the smallest budget at which each arm reaches 0.9 on the cells
that failed, pooled over repeats.

    .venv/bin/python bench/loop_targeting.py [--family push] [--start-episodes 40] [--steps 3000]
        [--budget 12 [24 ...]] [--worst 2] [--repeats 3] [--per-cell 12] [--post-steps 800] [--start-seed 0]

The defaults are the configuration docs/evaluation.md reports (about 22 minutes at one budget).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.vision_panels import FAMILIES, ORDER, bench_grid, panel  # noqa: E402
from tasks import loop as steps  # noqa: E402
from tasks import manifests  # noqa: E402
from tasks.policy import bc, posttrain, vision, vision_train  # noqa: E402
from tasks.policy.evaluate import run_episode  # noqa: E402
from tasks.policy.vision_obs import ObservationSpec  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
TRAIN, PANEL, NEW = 1000, 10300, 20000  # seed offsets: start demonstrations, panel, each arm's new demonstrations


def evaluate(spec, variants, policy) -> dict[str, list[bool]]:
    out: dict[str, list[bool]] = {}
    for pv, variant in zip(spec.variants, variants):
        out[pv.cell] = [run_episode(variant, pv.cell, seed, policy, None).outcome.success for seed in pv.seeds]
    return out


def bootstrap(values: list[bool], rng: np.random.Generator, n: int = 2000) -> tuple[float, float]:
    x = np.asarray(values, float)
    means = x[rng.integers(0, len(x), (n, len(x)))].mean(1)
    return float(np.quantile(means, 0.025)), float(np.quantile(means, 0.975))


def arm_manifests(arm: str, parent, grid, before: dict[str, list[bool]], budget: int, worst: int, offset: int):
    """(manifests, counts) of one arm's new demonstrations, on seeds parent.seed + offset.."""
    if arm == "nominal":
        return steps.derive_manifests(parent, grid, ["nominal"], offset), [budget]
    if arm == "uniform":
        cells = list(ORDER)
        counts = [budget // len(cells) + (1 if i < budget % len(cells) else 0) for i in range(len(cells))]
        picked = [(c, n) for c, n in zip(cells, counts) if n]
        return steps.derive_manifests(parent, grid, [c for c, _ in picked], offset), [n for _, n in picked]
    table = [{"cell": c, "sim": float(np.mean(v))} for c, v in before.items()]
    chosen = steps.worst_cells(table, worst)
    return (steps.derive_manifests(parent, grid, [c for c, _ in chosen], offset),
            steps.episode_counts([r for _, r in chosen], budget))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--family", default="push", choices=sorted(FAMILIES))
    parser.add_argument("--start-episodes", type=int, default=40,
                        help="the start's demonstrations: 40 (with 3000 steps) solve every nominal panel seed; 20 fail "
                             "hard layouts in every cell, which new data of any kind mends (docs/evaluation.md)")
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--budget", type=int, nargs="+", default=[12],
                        help="new demonstrations per arm; several: each arm at each, and the budget to reach 0.9")
    parser.add_argument("--worst", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--per-cell", type=int, default=12)
    parser.add_argument("--post-steps", type=int, default=800)
    parser.add_argument("--start-seed", type=int, default=0, help="training seed of the starting policy")
    parser.add_argument("--shift", type=int, default=0,
                        help="random-shift augmentation in pixels, for the start and every post-training (0: none)")
    args = parser.parse_args()
    started = time.perf_counter()
    path, cameras = FAMILIES[args.family]
    parent = manifests.load(REPO / path)
    spec_obs = ObservationSpec(cameras=cameras, image_size=64)
    seeds = list(range(parent.seed + TRAIN, parent.seed + TRAIN + args.start_episodes))
    demos = vision.collect(parent, seeds, spec_obs)
    config = bc.TrainConfig(steps=args.steps, batch_size=64, seed=args.start_seed, shift=args.shift)
    model, _ = vision_train.train_vision(demos, spec_obs, config)
    start = vision.VisionPolicy(model, spec_obs, {"manifest_hash": parent.sha256, "train_seeds": seeds})
    spec, variants = panel(parent, args.per_cell)
    grid = bench_grid(parent, args.per_cell)
    before = evaluate(spec, variants, start)
    print(f"# loop_targeting ({time.strftime('%Y-%m-%d')}): {parent.name}, vision policy on {', '.join(cameras)}; "
          f"start: {args.start_episodes} demonstrations, {args.steps} steps (seed {args.start_seed}); "
          f"budget {args.budget} per arm, "
          f"{args.repeats} repeats, post-training {args.post_steps} steps; {args.per_cell} panel seeds per cell"
          + (f"; random shift {args.shift} px" if args.shift else ""))
    failed = [c for c in ORDER if np.mean(before[c]) < 0.9]
    reached: dict[str, int | None] = {arm: None for arm in ("targeted", "nominal", "uniform")}
    for budget in sorted(args.budget):
        after = run_arms(args, parent, start, spec, variants, grid, before, budget)
        if failed:
            for arm, cells in after.items():
                share = float(np.mean(sum((cells[c] for c in failed), [])))
                if reached[arm] is None and share >= 0.9:
                    reached[arm] = budget
    if failed and len(args.budget) > 1:
        print(f"\nbudget to reach 0.9 on the cells that failed ({', '.join(failed)}): "
              + ", ".join(f"{arm} {b if b is not None else f'not by {max(args.budget)}'}" for arm, b in reached.items()))
    print(f"bench wall time {time.perf_counter() - started:.0f} s")


def run_arms(args, parent, start, spec, variants, grid, before, budget: int) -> dict[str, dict[str, list[bool]]]:
    """Every arm at one budget, ``--repeats`` times: per arm and cell the outcomes after, pooled;
    prints the table and the gain on the cells that failed."""
    after: dict[str, dict[str, list[bool]]] = {arm: {c: [] for c in ORDER} for arm in ("targeted", "nominal", "uniform")}
    targeted_cells: list[str] = []
    scratch = tempfile.mkdtemp(prefix="loop_targeting_")
    failed = [c for c in ORDER if np.mean(before[c]) < 0.9]
    for r in range(args.repeats):
        for k, arm in enumerate(after):
            made, counts = arm_manifests(arm, parent, grid, before, budget, args.worst, NEW + 1000 * (3 * r + k))
            if arm == "targeted":
                targeted_cells = [m.name.rsplit("--", 1)[1] for m in made]
            new = posttrain.demonstrations(parent, start, made, counts, note=lambda line: print(f"  {line}"))
            folder = Path(scratch) / f"{arm}_{r}"
            posttrain.post_train(start, new, bc.TrainConfig(steps=args.post_steps, batch_size=64, seed=r, shift=args.shift),
                                 folder,
                                 parent, {})
            outcomes = evaluate(spec, variants, vision.VisionPolicy.from_checkpoint(folder))
            for cell in outcomes:
                after[arm][cell] += outcomes[cell]
            print(f"  budget {budget}, repeat {r}, {arm}: {sum(counts)} new demonstrations in "
                  f"{', '.join(m.name for m in made)}{repeat_summary(outcomes, failed)}", flush=True)
    shutil.rmtree(scratch, ignore_errors=True)
    rng = np.random.default_rng(0)
    print(f"\nbudget {budget} new demonstrations per arm")
    print("\n| cell | before | targeted | nominal | uniform |\n|---|---|---|---|---|")
    for cell in ORDER:
        row = [cell + (" (targeted)" if cell in targeted_cells else "")]
        for values in (before[cell], *(after[arm][cell] for arm in after)):
            lo, hi = bootstrap(values, rng)
            row.append(f"{np.mean(values):.2f} [{lo:.2f}, {hi:.2f}]")
        print("| " + " | ".join(row) + " |")
    if failed:
        print("\n" + "\n".join(failed_summary(before, after, failed, rng)))
    return after


def repeat_summary(outcomes: dict[str, list[bool]], failed: list[str]) -> str:
    """One repeat's success on the cells that failed, and elsewhere at its lowest: how much of an
    arm's pooled figure one post-training run carries."""
    if not failed:
        return ""
    rest = [c for c in outcomes if c not in failed]
    low = min(rest, key=lambda c: np.mean(outcomes[c])) if rest else None
    parts = [f"{c} {np.mean(outcomes[c]):.2f}" for c in failed]
    if low is not None:
        parts.append(f"lowest elsewhere {low} {np.mean(outcomes[low]):.2f}")
    return "; after: " + ", ".join(parts)


def failed_summary(before, after, failed: list[str], rng: np.random.Generator) -> list[str]:
    """Lines on the cells that failed: each arm's gain there, targeted minus the better control,
    each arm's pooled success there after with a bootstrap 95% interval, and the most any arm
    could have led the better control by (one at 1.00 on every failed cell): where the better
    control already reaches 0.8 there, no targeting can meet a +0.2 lead."""
    def pooled(cells):
        return sum((cells[c] for c in failed), [])

    gains = {arm: np.mean(pooled(cells)) - np.mean(pooled(before)) for arm, cells in after.items()}
    better = max(("nominal", "uniform"), key=lambda arm: gains[arm])
    spans = {arm: bootstrap(pooled(cells), rng) for arm, cells in after.items()}
    apart = "apart" if spans["targeted"][0] > spans[better][1] else "overlap"
    return [f"cells that failed (before < 0.9): {', '.join(failed)}; gain there: "
            + ", ".join(f"{arm} {g:+.2f}" for arm, g in gains.items())
            + f"; targeted minus the better control ({better}) {gains['targeted'] - gains[better]:+.2f}",
            "success there after, pooled: "
            + ", ".join(f"{arm} {np.mean(pooled(cells)):.2f} [{spans[arm][0]:.2f}, {spans[arm][1]:.2f}]"
                        for arm, cells in after.items())
            + f"; the intervals of targeted and {better} {apart}",
            f"the most any arm could lead {better} by there (1.00 on every failed cell): "
            f"{1.0 - np.mean(pooled(after[better])):+.2f}"]


if __name__ == "__main__":
    main()

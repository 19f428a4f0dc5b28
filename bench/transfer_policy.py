"""Does transferred data help a policy? (issue 32 point 6)

A vision policy trained on N nominal scripted demonstrations plus their transferred variants
(the same steps, the camera frames made by a transfer model in each look: dim, very dim, colour
shift, textures; `tasks/transfer/variants.py`) against one trained on the same N nominal
demonstrations alone, and (``--control``) one trained on as many nominal demonstrations as the
transfer arm has episodes. Every arm: the same TrainConfig and steps, behaviour cloning,
``--seeds`` training seeds. Each policy runs on the same held-out seeds of the vision-panel
bench's cells (`bench/vision_panels.py`: its grid and panel seeds; the loop bench's
`evaluate`, physics only, the policy seeing its cameras at the rate it was trained at). It
prints per cell the success of each arm pooled over training seeds with a bootstrap 95%
interval over episodes, each seed's own rate, the gain of the transfer arm over the others on
the appearance, dim and distractor cells with a bootstrap interval of the difference, and the
wall time of each phase.

    .venv/bin/python bench/transfer_policy.py --model /work/runs/transfer-small-45m [--episodes 10]
        [--steps 1000] [--seeds 3] [--per-cell 10] [--control] [--no-rendered]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.loop_targeting import bootstrap, evaluate  # noqa: E402
from bench.vision_panels import FAMILIES, ORDER, TRAIN, panel  # noqa: E402
from models.transfer import ALL_CONTROLS  # noqa: E402
from tasks import manifests  # noqa: E402
from tasks.policy import bc, vision, vision_train  # noqa: E402
from tasks.policy.vision_obs import ObservationSpec  # noqa: E402
from tasks.transfer import variants  # noqa: E402
from tasks.transfer.apply import model_info  # noqa: E402
from tasks.transfer.train import load_transfer  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
LOOKS = ("dim", "very dim", "colour shift", "textures")
REFERENCE = 5000  # --reference other: a reference clip's seed is the episode's plus this
STRESSED = ("dim", "appearance", "distractors")  # the cells the gain is judged on


def diff_interval(a: list[bool], b: list[bool], rng: np.random.Generator, n: int = 2000) -> tuple[float, float]:
    """Bootstrap 95% interval of mean(a) - mean(b), each resampled over its own episodes."""
    x, y = np.asarray(a, float), np.asarray(b, float)
    d = x[rng.integers(0, len(x), (n, len(x)))].mean(1) - y[rng.integers(0, len(y), (n, len(y)))].mean(1)
    return float(np.quantile(d, 0.025)), float(np.quantile(d, 0.975))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, help="transfer checkpoint folder (bench/transfer_smoke.py --out, or worldline train-transfer)")
    parser.add_argument("--episodes", type=int, default=10, help="nominal demonstrations N")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--seeds", type=int, default=3, help="training seeds per arm")
    parser.add_argument("--per-cell", type=int, default=10, help="held-out panel seeds per cell")
    parser.add_argument("--cells", default="nominal,dim,distractors,appearance")
    parser.add_argument("--control", action="store_true", help="also the arm of as many nominal episodes as arm (b)")
    parser.add_argument("--reference", choices=("none", "other"), default="none",
                        help="a model trained with reference clips (small-ref): each episode's look is given by the "
                             "true render in that look of another seed (the episode's seed + 5000)")
    parser.add_argument("--no-rendered", action="store_true",
                        help="no depth and segmentation controls: weight 0 (the transfer model saw that in training)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    started = time.perf_counter()
    timing: dict[str, float] = {}
    path, cameras = FAMILIES["push"]
    parent = manifests.load(REPO / path)
    spec = ObservationSpec(cameras=cameras, image_size=64)
    _, info = model_info(args.model)
    camera = info.get("camera") or cameras[0]
    weights = dict.fromkeys(ALL_CONTROLS, 1.0)  # a model reads the ones it takes
    if args.no_rendered:
        weights.update(depth=0.0, segmentation=0.0)

    t = time.perf_counter()
    seeds = list(range(parent.seed + TRAIN, parent.seed + TRAIN + args.episodes))
    nominal = vision.collect(parent, seeds, spec)
    timing["collect N nominal"] = time.perf_counter() - t
    t = time.perf_counter()
    clips = variants.episode_clips(parent, nominal, spec, camera, info["size"], rendered=not args.no_rendered)
    timing["controls (rollouts with recorder)"] = time.perf_counter() - t
    t = time.perf_counter()
    model = load_transfer(Path(args.model))
    references = None
    if args.reference == "other":
        if not model.config.reference:
            parser.error(f"--reference other: {args.model} was not trained with reference clips")
        references = variants.look_references(parent, [c.clip.seed + REFERENCE for c in clips], camera, info["size"],
                                              LOOKS, model.config)
        timing["reference renders"] = time.perf_counter() - t
        t = time.perf_counter()
    mixed = variants.with_variants(nominal, spec, clips, model, LOOKS, weights, references)
    timing["transfer (generation)"] = time.perf_counter() - t
    data = {"a: nominal N": nominal, "b: N + transferred": mixed}
    if args.control:
        t = time.perf_counter()
        total = len(clips) * (1 + len(LOOKS))
        extra = vision.collect(parent, list(range(seeds[-1] + 1, seeds[-1] + 1 + total - len(clips))), spec)
        data[f"c: nominal {total}"] = nominal + extra
        timing["collect control's extra nominal"] = time.perf_counter() - t

    cells = [c for c in ORDER if c in args.cells.split(",")]
    full, made = panel(parent, args.per_cell)
    keep = [(pv, v) for pv, v in zip(full.variants, made) if pv.cell in cells]
    held = SimpleNamespace(variants=[pv for pv, _ in keep])
    variants_ = [v for _, v in keep]
    results: dict[str, dict[str, list[bool]]] = {}
    per_seed: dict[str, list[dict[str, float]]] = {}
    for arm, demos in data.items():
        results[arm], per_seed[arm] = {c: [] for c in cells}, []
        train_s = eval_s = 0.0
        for s in range(args.seeds):
            t = time.perf_counter()
            net, _ = vision_train.train_vision(demos, spec, bc.TrainConfig(steps=args.steps, batch_size=64, seed=s))
            train_s += time.perf_counter() - t
            t = time.perf_counter()
            out = evaluate(held, variants_, vision.VisionPolicy(net, spec))
            eval_s += time.perf_counter() - t
            per_seed[arm].append({c: float(np.mean(v)) for c, v in out.items()})
            for c, v in out.items():
                results[arm][c] += v
            print(f"  {arm}, seed {s}: " + ", ".join(f"{c} {np.mean(v):.2f}" for c, v in out.items()), flush=True)
        timing[f"train {arm} ({args.seeds} seeds)"] = train_s
        timing[f"evaluate {arm}"] = eval_s

    rng = np.random.default_rng(0)
    arms = list(data)
    episodes = {arm: len(np.unique(d.episode)) for arm, d in data.items()}
    stamp = time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())
    rendered = "weight 0" if args.no_rendered else "recorded"
    print(f"\n# transfer_policy ({stamp}): {parent.name}, vision policy on "
          f"{', '.join(cameras)} at 64 px (seen at the camera's fps, as collected); transfer model {args.model} "
          f"(depth and segmentation {rendered}; reference {args.reference}), looks {', '.join(LOOKS)}; "
          f"N = {len(clips)} demonstrations (seeds {seeds[0]}-{seeds[-1]}); {args.steps} BC steps, batch 64, "
          f"{args.seeds} training seeds per arm; {args.per_cell} held-out panel seeds per cell")
    print("episodes (steps) per arm: " + ", ".join(f"{a} {episodes[a]} ({len(d.act)})" for a, d in data.items()))
    print("frames the policy saw vs the recorded rollout: mean |difference| "
          f"{variants.mean_mismatch(clips):.3f} grey levels")
    print("\n| cell | " + " | ".join(arms) + " |\n|---|" + "---|" * len(arms))
    for c in cells:
        row = [c]
        for arm in arms:
            lo, hi = bootstrap(results[arm][c], rng)
            seeds_txt = "/".join(f"{p[c]:.1f}" for p in per_seed[arm])
            row.append(f"{np.mean(results[arm][c]):.2f} [{lo:.2f}, {hi:.2f}] ({seeds_txt})")
        print("| " + " | ".join(row) + " |")
    judged = [c for c in STRESSED if c in cells]
    b = arms[1]
    print(f"\n| gain of {b} | " + " | ".join(f"over {a}" for a in arms if a != b) + " |\n|---|"
          + "---|" * (len(arms) - 1))
    for c in [*judged, "pooled: " + ", ".join(judged)]:
        pick = judged if c.startswith("pooled") else [c]
        row = [c]
        for a in arms:
            if a == b:
                continue
            x = sum((results[b][k] for k in pick), [])
            y = sum((results[a][k] for k in pick), [])
            lo, hi = diff_interval(x, y, rng)
            row.append(f"{np.mean(x) - np.mean(y):+.2f} [{lo:+.2f}, {hi:+.2f}]")
        print("| " + " | ".join(row) + " |")
    print()
    for key, value in timing.items():
        print(f"wall time, {key}: {value:.0f} s")
    print(f"bench wall time {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()

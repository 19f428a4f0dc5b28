"""The physics evaluation's steps as plain functions (flows/physics.py makes tasks of the
rollouts): held-out truth from the simulator, the world model's predictions on it, the episodes
a checkpoint trained on, the Sampson rows between cameras and the window counts."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from tasks.tokenize import tokens
from tasks.world import data, heldout, physics
from tasks.world.family import is_diffusion, load_world_model
from tasks.world.data import CodeSequence, read_meta
from tasks.world.geometry import PinholeCamera, sampson_table
from tasks.world.report import fmt
from tasks.world.train import teacher_forced, window_length


def trained_folders(config: dict, root: Path) -> list[Path]:
    """The episode folders a post-trained checkpoint saw (its config lists them) that are still here."""
    folders = [Path(uri) if Path(uri).is_absolute() else root / uri for uri in config.get("episodes", [])]
    return [folder for folder in folders if (folder / "meta.json").is_file()]


def trained_seeds(config: dict, root: Path) -> set[int]:
    """Seeds of the episodes a post-trained checkpoint saw."""
    return {int(read_meta(folder)["seed"]) for folder in trained_folders(config, root)}


def render_heldout(scenario, seed: int, camera: str, others: list[str]) -> dict[str, heldout.Truth]:
    """The primary camera's truth (with the package's masks) and the other cameras' frames,
    all checked against the rollout's own renders."""
    from tasks.sim.episode import rollout

    ep = rollout(scenario, seed)
    truth = heldout.render_truth(scenario, seed, camera)
    if not np.array_equal(truth.frames, ep.frames[camera]):
        raise RuntimeError(f"seed {seed}: the segmentation replay renders other frames than the rollout")
    return {camera: truth, **{c: replace(truth, camera=c, frames=ep.frames[c], masks=None) for c in others}}


def predict_heldout(wm_folder: Path, tok_folder: Path, per_camera: dict[str, list[tuple[int, heldout.Truth]]],
                    cameras: dict[str, PinholeCamera], size: int, text: str, context: int, horizon: int, stride: int,
                    move_m: float, shuffle_seed: int, trained: list[Path], tokenizer_id: str, root: Path,
                    sampler_steps: int = 8) -> tuple[dict[str, list[physics.Window]], dict, float | None]:
    """Windows per camera: encode, fit colours (primary camera), roll out with true and shuffled
    actions. And teacher-forced next-frame scores on the primary camera's held-out episodes
    beside as many of the episodes the model trained on (``trained``, that camera): an
    autoregressive model's only (next-code accuracy has no diffusion counterpart here; a
    diffusion model samples with ``sampler_steps`` Euler steps). And the primary camera's rollout
    time per generated video frame (decoding included)."""
    import torch

    torch.set_num_threads(min(2, torch.get_num_threads()))
    model, tokenizer = load_world_model(wm_folder), tokens.load_checkpoint(tok_folder)
    diffusion = is_diffusion(model)
    if tokenizer.config.variant != ("continuous" if diffusion else "discrete"):
        raise ValueError(f"{tok_folder}: a {tokenizer.config.variant} tokenizer; the "
                         f"{'diffusion' if diffusion else 'autoregressive'} world model at {wm_folder} reads "
                         f"{'a continuous' if diffusion else 'a discrete'} one's {'latents' if diffusion else 'codes'}")
    if not model.config.action_conditioned:
        raise ValueError(f"{wm_folder}: not post-trained with actions; give a post-trained world model")
    out, memorising, per_frame = {}, {}, None
    for name, truths in per_camera.items():
        prepared = [heldout.prepare(f"seed{seed}", t, cameras[name], tokenizer, size, model.config.action_dim, text,
                                    totals=model.config.action_totals)
                    for seed, t in truths]
        started = time.perf_counter()
        out[name] = heldout.predict(model, tokenizer, prepared, context, horizon, stride, move_m, shuffle_seed,
                                    sampler_steps=sampler_steps)
        if per_frame is None:  # per generated video frame, decoding included: true and shuffled actions
            t = tokenizer.config.temporal_compression
            per_frame = (time.perf_counter() - started) / max(1, 2 * len(out[name]) * t * horizon)
        if not memorising and not diffusion:  # the primary camera comes first
            held = [CodeSequence(p.key, p.codes, p.text, p.actions) for p in prepared]
            window = window_length(held, model.config.max_frames)
            memorising["held_out"] = teacher_forced(model, held, window, stride)
            seen = data.load_episodes(trained[:len(prepared)], tokenizer, size, [name], model.config.action_dim,
                                      text, tokenizer_id, root, model.config.action_totals)
            if any(s.frames >= window for s in seen):
                memorising["trained"] = teacher_forced(model, seen, window, stride)
    return out, memorising, per_frame


def two_view_rows(windows: dict[str, list[physics.Window]], primary: str, cameras: dict[str, PinholeCamera],
                  horizons: list[int]) -> list[dict]:
    """Sampson error between the primary camera and each other one: simulator, ceiling, model."""
    main, rows = windows[primary], []
    for name, other in windows.items():
        if name == primary:
            continue
        views = {source: [(a.true, b.true) if source == "simulator" else (a.outputs[source], b.outputs[source])
                          for a, b in zip(main, other)] for source in ("simulator", "ceiling", "model")}
        rows += [{"pair": f"{primary}-{name}", **r}
                 for r in sampson_table(views, cameras[primary], cameras[name], horizons)]
    return rows


def window_counts(main: list[physics.Window], seeds: list[int]) -> dict:
    untracked = sorted({f"{w.info['episode']} (colour fit IoU: "
                        + ", ".join(f"{k} {fmt(v)}" for k, v in w.info["fit_iou"].items()) + ")"
                        for w in main if w.true_colour is None or w.decoded_colour is None})
    return {"episodes": len(seeds), "seeds": f"{seeds[0]}..{seeds[-1]}", "windows": len(main),
            "moving": sum(w.moved for w in main), "tracked": sum(w.tracked for w in main),
            "untracked": ", ".join(untracked)}

"""Train a vision policy by behaviour cloning plus DAgger, and save / load its checkpoint.

``train_vision`` fits the network to demonstrations (MSE on standardised actions; the first
call sets the normalisation statistics, later calls, post-training and DAgger rounds, keep
them). ``dagger`` alternates: roll out the learner on fresh seeds, have the expert label
every visited state, aggregate, train on. Checkpoints are safetensors plus config JSON as for
every model (``{"vision": VisionConfig, "observe": ObservationSpec, "train": ..., ...}``).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch

from models.tokenizer import VideoTokenizer
from models.vision_policy import VisionConfig, VisionPolicyNet, preset
from schemas.manifest import ScenarioManifest
from schemas.panel import contract_hash, panel_contract
from tasks.checkpoint_files import (WEIGHTS_FILE, CheckpointError, load_weights, model_config,  # noqa: F401
                                     read_config, write_checkpoint)
from tasks.policy.bc import TrainConfig
from tasks.policy.fit import fit
from tasks.policy.vision import VisionDemonstrations, VisionPolicy, collect
from tasks.policy.vision_obs import PROPRIO_VERSION, ObservationSpec

KEY = "vision"
# DAgger's gate, in the demonstrations' spreads of a move value: the expert takes over (and
# labels) a step only where the learner's move is further off its own (tasks/policy/vision.py).
# One spread: on push_closeup plain DAgger took held-out success from 1.00 to 0.25 and 0.00 in
# two rounds, gated at 1.0 it stayed at 1.00; from weaker starts gated rounds stay below
# behaviour cloning retrained with the same seeds (docs/evaluation.md).
DAGGER_GATE = 1.0


def frozen_features(model: VisionPolicyNet, frames: torch.Tensor, chunk: int = 256) -> torch.Tensor:
    """``model.frozen`` of every frame, in chunks, without gradient; a tokenizer encoder's as
    float16 (its latents, FSQ levels, are exact there; its hidden features, up to about 10, were
    within 0.0034 on the push tokenizer), so the encoder runs once per frame, not once per step
    that samples it."""
    with torch.no_grad():
        out = [model.frozen(frames[i:i + chunk]) for i in range(0, len(frames), chunk)]
    return torch.cat(out).half()


def train_vision(demos: VisionDemonstrations, spec: ObservationSpec, config: TrainConfig = TrainConfig(),
                 start: VisionPolicyNet | None = None, log: Callable[[dict], None] | None = None,
                 device: str | torch.device = "cpu", tokenizer: VideoTokenizer | None = None,
                 layer: str = "latent") -> tuple[VisionPolicyNet, list[dict]]:
    """Seeded: the same demonstrations and config give the same weights. History rows every
    1/20 of the run: step, loss, smoothed loss, seconds. ``device``: where it trains (the
    demonstrations move there whole; minibatch indices are drawn on the CPU, so the same
    samples on any device); the model is returned there (``tasks.device``). ``tokenizer``: a
    fresh policy sees through that tokenizer's encoder (frozen; ``layer`` latent or hidden)
    instead of its own convolutions."""
    torch.manual_seed(config.seed)
    threads = torch.get_num_threads()
    torch.set_num_threads(config.threads)
    try:
        frames, state, act = (torch.from_numpy(demos.frames), torch.from_numpy(demos.proprio),
                              torch.from_numpy(demos.act))
        if start is not None:
            model = copy.deepcopy(start)
        else:
            model = VisionPolicyNet(preset(config.preset, len(spec.cameras), spec.image_size, state.shape[1],
                                           tokenizer.config if tokenizer else None, layer))
            if tokenizer is not None:
                model.load_tokenizer(tokenizer)
            sample = torch.randperm(len(frames), generator=torch.Generator().manual_seed(config.seed))[:2000]
            model.set_statistics(frames[sample], state, act)
        model.to(device)
        frames, state = frames.to(device), state.to(device)
        target = ((act.to(device) - model.act_mean) / model.act_std)
        cached = frozen_features(model, frames) if model.config.encoder == "tokenizer" else None
        if config.shift and cached is not None:
            raise ValueError("shift augmentation needs the policy's own convolutions: a tokenizer encoder's "
                             "features are computed once per frame")
        shifts = torch.Generator().manual_seed(config.seed + 7919)  # its own stream: minibatches stay as without

        def loss(b: torch.Tensor) -> torch.Tensor:
            b = b.to(device)
            seen = random_shift(frames[b], config.shift, shifts) if config.shift else frames[b]
            frozen = None if cached is None else cached[b]
            return torch.nn.functional.mse_loss(model.forward_normalised(seen, state[b], frozen), target[b])

        history = fit(model, loss, len(frames), config, log)
        return model.eval(), history
    finally:
        torch.set_num_threads(threads)


def random_shift(frames: torch.Tensor, pad: int, generator: torch.Generator) -> torch.Tensor:
    """``frames`` (B x cameras x 3 x H x W) each moved by a whole number of pixels, up to ``pad``
    either way in x and y (drawn per sample and camera on the CPU), the picture's edge rows and
    columns repeated where it moved away from the border: a pad-and-crop with replicated edges."""
    b, c, _, h, w = frames.shape
    dy, dx = (torch.randint(-pad, pad + 1, (2, b, c), generator=generator)).to(frames.device)
    rows = (torch.arange(h, device=frames.device) + dy[..., None]).clamp(0, h - 1)  # B x C x H
    cols = (torch.arange(w, device=frames.device) + dx[..., None]).clamp(0, w - 1)  # B x C x W
    index = rows[:, :, None, :, None] * w + cols[:, :, None, None, :]  # B x C x 1 x H x W
    flat = frames.reshape(b, c, frames.shape[2], h * w)
    return flat.gather(3, index.expand(-1, -1, frames.shape[2], -1, -1).reshape(b, c, frames.shape[2], h * w)
                       ).reshape(frames.shape)


def dagger(manifest: ScenarioManifest, spec: ObservationSpec, demos: VisionDemonstrations, model: VisionPolicyNet,
           rounds: Sequence[Sequence[int]], config: TrainConfig, offset: int = 0,
           log: Callable[[dict], None] | None = None, device: str | torch.device = "cpu",
           gate: float | None = DAGGER_GATE, loss: float | None = None
           ) -> tuple[VisionPolicyNet, VisionDemonstrations, list[dict]]:
    """One DAgger round per seed list in ``rounds``: the learner's episodes, expert-labelled,
    added to ``demos``; then, as in DAgger, a policy trained afresh on the aggregate, its
    normalisation statistics recomputed. (Continuing from the current weights kept the
    demonstrations' statistics: the expert's corrections, much larger than the noisy
    demonstrations' yaw moves, then dominated the loss, and on push_closeup held-out success
    fell from 0.9 to 0.0 in two rounds.) ``gate``: the expert labels, and takes over, only the
    steps where the learner's move is off its own by more than ``gate`` times the
    demonstrations' spread (HG-DAgger; ``tasks/policy/vision.py``); None labels every step
    (plain DAgger). A round where the expert never took over adds nothing and trains nothing:
    its history row carries the model's last training loss (``loss`` before the first round).
    History rows gain ``round``, the learner's success in it (``learner_success``; with a gate,
    helped where the expert took over) and the share of its steps the expert took
    (``interventions``); their steps count on from ``offset`` (the steps trained before)."""
    history = []
    for k, seeds in enumerate(rounds, start=1):
        counts: dict[str, int] = {}
        visited = collect(manifest, seeds, spec, learner=VisionPolicy(model, spec), round_=k, gate=gate, counts=counts)
        rate = sum(visited.successes) / max(1, len(visited.successes))
        share = counts.get("interventions", 0) / max(1, counts.get("steps", 0)) if gate is not None else 1.0
        if len(visited.act):
            demos = demos + visited
            model, rows = train_vision(demos, spec, config.model_copy(update={"seed": config.seed + k}), device=device,
                                       tokenizer=tokenizer_of(model), layer=model.config.tokenizer_layer)
        else:
            rows = [{"step": config.steps, "loss": history[-1]["loss"] if history else
                     (float("nan") if loss is None else loss)}]
        history += [{**row, "step": offset + (k - 1) * config.steps + row["step"], "round": k, "learner_success": rate,
                     "interventions": share} for row in rows]
        if log:
            log({"round": k, "learner_success": rate, "interventions": share, "samples": len(demos.act),
                 "loss": rows[-1]["loss"]})
    return model, demos, history


def tokenizer_of(model: VisionPolicyNet) -> VideoTokenizer | None:
    """The tokenizer whose encoder ``model`` sees through (its encoder's weights; the decoder,
    which a policy never runs, left as built), or None for a CNN policy: what a policy trained
    afresh on the same footing needs (DAgger)."""
    if model.config.tokenizer is None:
        return None
    tokenizer = VideoTokenizer(model.config.tokenizer)
    tokenizer.encoder.load_state_dict(model.encoders[0].encoder.state_dict())
    return tokenizer.to(next(model.parameters()).device)


def save_checkpoint(model: VisionPolicyNet, spec: ObservationSpec, folder: Path, manifest: ScenarioManifest,
                    train: TrainConfig, extra: dict | None = None) -> tuple[Path, Path]:
    """Weights (safetensors) and config JSON, each written atomically."""
    contract = panel_contract(manifest)
    return write_checkpoint(model, folder, KEY, {
        "observe": spec.model_dump(mode="json"), "train": train.model_dump(mode="json"),
        "manifest_hash": manifest.sha256, "contract": contract.model_dump(mode="json"),
        "contract_hash": contract_hash(contract), **(extra or {})})


def load_checkpoint(folder: Path) -> tuple[VisionPolicyNet, ObservationSpec, dict[str, Any]]:
    meta = read_config(folder, KEY, "vision-policy checkpoint")
    try:
        spec = ObservationSpec.model_validate(meta.get("observe"))
    except ValueError as exc:
        raise CheckpointError(f"{folder}: no usable observation spec ({str(exc).splitlines()[0]})") from None
    if spec.proprio_version != PROPRIO_VERSION:
        raise CheckpointError(f"{folder}: proprioception version {spec.proprio_version} is not {PROPRIO_VERSION}")
    model = load_weights(VisionPolicyNet(model_config(VisionConfig, meta, KEY, folder)), folder)
    return model, spec, meta


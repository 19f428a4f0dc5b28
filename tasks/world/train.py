"""Train the world model: pre-training on token sequences with text, post-training on episodes with actions.

Pure: ``CodeSequence``s in, a trained model and its history out; no files, no Prefect. Random
windows of ``max_frames`` latent frames, next-frame cross-entropy, AdamW, linear warm-up then
a cosine on progress = max(step / steps, training seconds / budget) (as tasks/tokenize/train.py
does, so a wall-clock budget and a step count both end the cosine at its floor).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from models.world_model import WorldModel, action_scale, next_frame_loss, post_trainable, text_ids
from tasks.device import Runtime, autocast, model_device, prepare
from tasks.world.data import CodeSequence


class WorldTrainConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    preset: str = "tiny-wm"
    steps: int = Field(200, ge=1)
    seconds: float | None = Field(None, gt=0, description="training-time budget; stops at steps or this")
    batch_size: int = Field(8, ge=1)
    lr: float = Field(1e-3, gt=0)
    warmup_steps: int = Field(20, ge=0)
    min_lr_ratio: float = Field(0.1, ge=0, le=1)
    weight_decay: float = Field(0.01, ge=0)
    text_dropout: float = Field(0.1, ge=0, le=1, description="share of windows trained without their text")
    change_weight: float = Field(0.0, ge=0, description="extra loss weight on codes that change from the frame before")
    self_condition: float = Field(0.0, ge=0, le=1, description="share of windows whose input frames after the first "
                                  "are the model's own predictions (see ``own_inputs``)")
    action_totals: int = Field(0, ge=0, le=8, description="post-training: leading action values also given as running "
                               "totals (``tasks.world.data.align_actions``; the episodes must be loaded with them)")
    seed: int = 0
    threads: int = Field(2, ge=1)
    log_every: int = Field(10, ge=1)


def window_length(sequences: Sequence[CodeSequence], max_frames: int) -> int:
    """Frames per training window: ``max_frames``, or the longest sequence when all are shorter."""
    longest = max((s.frames for s in sequences), default=0)
    if longest < 2:
        raise ValueError("no sequence has 2 latent frames: nothing to predict")
    return min(max_frames, longest)


def pick_windows(sequences: Sequence, frames: int, batch: int, gen: torch.Generator, with_actions: bool,
                 text_dropout: float, values: Callable) -> tuple[list[np.ndarray], list[str], torch.Tensor | None]:
    """``batch`` random windows of ``frames`` latent frames of ``values(sequence)`` (an array whose
    first axis is the latent frame: codes, or a diffusion model's latents), with their texts (dropped
    to "" with probability ``text_dropout``) and actions ``B x (frames - 1) x F`` float32 (the rows
    between the window's frames) or None. Both world-model families draw their windows here."""
    usable = [s for s in sequences if s.frames >= frames]
    if not usable:
        raise ValueError(f"no sequence has {frames} latent frames")
    grids = {values(s).shape[1:] for s in usable}
    if len(grids) > 1:
        raise ValueError(f"sequences have different latent grids {sorted(grids)}; train on one tokenizer size")
    windows, texts, actions = [], [], []
    for _ in range(batch):
        seq = usable[int(torch.randint(len(usable), (1,), generator=gen))]
        t0 = int(torch.randint(seq.frames - frames + 1, (1,), generator=gen))
        windows.append(values(seq)[t0:t0 + frames])
        drop = text_dropout > 0 and float(torch.rand((), generator=gen)) < text_dropout
        texts.append("" if drop else seq.text)
        if with_actions:
            if seq.actions is None:
                raise ValueError(f"{seq.key}: no actions to condition on")
            actions.append(seq.actions[t0:t0 + frames - 1])
    acts = torch.from_numpy(np.stack(actions).astype(np.float32)) if with_actions else None
    return windows, texts, acts


def sample_windows(sequences: Sequence[CodeSequence], frames: int, batch: int, gen: torch.Generator,
                   with_actions: bool = False, text_dropout: float = 0.0
                   ) -> tuple[torch.Tensor, list[str], torch.Tensor | None]:
    """``batch`` random windows of ``frames`` latent frames (from sequences at least that long):
    codes ``B x frames x H' x W'`` int64, texts and actions as ``pick_windows`` gives them."""
    codes, texts, acts = pick_windows(sequences, frames, batch, gen, with_actions, text_dropout, lambda s: s.codes)
    return torch.from_numpy(np.stack(codes)).long(), texts, acts


@torch.no_grad()
def teacher_forced(model: WorldModel, sequences: Sequence[CodeSequence], frames: int, stride: int = 2) -> dict:
    """Next-frame scores on every window of ``frames`` latent frames (``stride`` apart) of
    ``sequences``, fed the true frames and, to an action-conditioned model, their actions:
    windows, loss (mean nats per code), accuracy, and changed_accuracy, the share right of the
    codes that differ from the frame before (what copying the last frame never gets).

    On held-out episodes beside training ones it shows memorising: a model that has learnt
    its episodes by heart scores far better on them than on new ones."""
    was_training = model.training
    model.eval()
    device = model_device(model)
    losses, right, moved, moved_right, total = [], 0, 0, 0, 0
    for seq in sequences:
        for t0 in range(0, seq.frames - frames + 1, stride):
            codes = torch.from_numpy(seq.codes[t0:t0 + frames]).long()[None].to(device)
            actions = None
            if model.config.action_conditioned:
                if seq.actions is None:
                    raise ValueError(f"{seq.key}: no actions for an action-conditioned model")
                actions = torch.from_numpy(np.asarray(seq.actions[t0:t0 + frames - 1], np.float32))[None].to(device)
            logits = model(codes, [seq.text], actions)
            losses.append(next_frame_loss(logits, codes).item())
            hit = logits[:, :-1].argmax(-1) == codes[:, 1:]
            change = codes[:, 1:] != codes[:, :-1]
            right, total = right + int(hit.sum()), total + hit.numel()
            moved, moved_right = moved + int(change.sum()), moved_right + int((hit & change).sum())
    model.train(was_training)
    if not losses:
        raise ValueError(f"no sequence has {frames} latent frames")
    return {"windows": len(losses), "loss": float(np.mean(losses)), "accuracy": right / total,
            "changed_accuracy": moved_right / moved if moved else float("nan")}


def own_inputs(model: WorldModel, codes: torch.Tensor, texts: list[str], actions: torch.Tensor | None,
               share: float, gen: torch.Generator) -> torch.Tensor:
    """Inputs for windows that read the model's own frames instead of the true ones.

    Open-loop rollouts feed a model its own predictions, which drift from anything it saw in
    training; trained only on true frames it never learns to recover from them. For a share
    of the windows (drawn with ``gen``), the input frames after the first are replaced by what
    the model itself predicts, unrolled (without gradients) as a rollout would: frame j + 1
    is predicted from frames 0..j of the previous pass, T' - 1 passes in all. Targets stay
    the true frames, so the model learns to pull a drifted frame back to the truth
    (scheduled sampling, Bengio et al. 2015, unrolled over the window)."""
    picked = (torch.rand(codes.shape[0], generator=gen) < share).to(codes.device)
    if not picked.any():
        return codes
    sub, acts = codes[picked], None if actions is None else actions[picked]
    kept = [t for t, p in zip(texts, picked.tolist(), strict=True) if p]
    was_training = model.training
    model.eval()
    with torch.no_grad():
        inputs = sub
        for _ in range(sub.shape[1] - 1):
            predicted = model(inputs, kept, acts).argmax(-1)
            inputs = torch.cat([sub[:, :1], predicted[:, :-1]], dim=1)
    model.train(was_training)
    out = codes.clone()
    out[picked] = inputs
    return out


def lr_at(config: WorldTrainConfig, step: int, progress: float) -> float:
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    floor = config.lr * config.min_lr_ratio
    return floor + (config.lr - floor) * 0.5 * (1 + math.cos(math.pi * min(progress, 1.0)))


def optimizer(model: torch.nn.Module, config) -> torch.optim.Optimizer:
    """AdamW on the trainable parameters, weight decay on matrices only, not on biases, norms or
    the learned position vectors (nanoGPT)."""
    params = [p for p in model.parameters() if p.requires_grad]
    decay = [p for p in params if p.dim() >= 2]
    rest = [p for p in params if p.dim() < 2]
    return torch.optim.AdamW([{"params": decay, "weight_decay": config.weight_decay},
                              {"params": rest, "weight_decay": 0.0}], lr=config.lr, betas=(0.9, 0.95))


def optimise(model: torch.nn.Module, config, batch_loss: Callable[[], tuple[torch.Tensor, dict[str, float]]],
             on_log: Callable[[dict], None] | None = None) -> list[dict]:
    """The training loop both world-model families share, in place: ``config.steps`` steps (or
    ``config.seconds`` of training), the learning rate of `lr_at` set each step, one
    ``batch_loss()`` (a window batch's loss and the step's other figures), gradients clipped to
    norm 1, and one record per ``log_every`` steps and the last: step, seconds, loss, the other
    figures (means over those steps) and lr; ``on_log`` sees each record with the model in eval mode."""
    opt = optimizer(model, config)
    history: list[dict] = []
    trained, pending = 0.0, []
    model.train()
    for step in range(config.steps):
        if config.seconds and trained >= config.seconds:
            break
        started = time.perf_counter()
        progress = max(step / config.steps, trained / config.seconds if config.seconds else 0.0)
        for group in opt.param_groups:
            group["lr"] = lr_at(config, step, progress)
        loss, figures = batch_loss()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        pending.append({"loss": loss.item(), **figures})
        trained += time.perf_counter() - started
        last = step + 1 == config.steps or bool(config.seconds and trained >= config.seconds)
        if (step + 1) % config.log_every == 0 or last:
            record = {"step": step + 1, "seconds": round(trained, 2),
                      **{k: float(np.mean([p[k] for p in pending])) for k in pending[0]},
                      "lr": opt.param_groups[0]["lr"]}
            pending = []
            history.append(record)
            if on_log:
                model.eval()
                on_log(record)
                model.train()
    model.eval()
    return history


def train_world_model(model: WorldModel, sequences: Sequence[CodeSequence], config: WorldTrainConfig,
                      on_log: Callable[[dict], None] | None = None, runtime: Runtime | None = None) -> list[dict]:
    """Train in place; one record per ``log_every`` steps (and the last): step, seconds, loss
    (nats per token), accuracy (argmax next-frame tokens right), copy_accuracy (what repeating
    the current frame would score), lr. An action-conditioned model trains on the sequences'
    actions. Same seed, sequences and config: same weights (single-threaded). ``runtime`` says
    where (``tasks.device``): windows are sampled on the CPU and moved there; the model stays."""
    torch.set_num_threads(config.threads)
    runtime = runtime or Runtime(device="cpu")
    call, device = prepare(model, runtime)
    gen = torch.Generator().manual_seed(config.seed)
    frames = window_length(sequences, model.config.max_frames)
    with_actions = model.config.action_conditioned

    def batch_loss() -> tuple[torch.Tensor, dict[str, float]]:
        codes, texts, actions = sample_windows(sequences, frames, config.batch_size, gen, with_actions,
                                               config.text_dropout)
        codes = codes.to(device, non_blocking=True)
        actions = actions.to(device, non_blocking=True) if actions is not None else None
        inputs = own_inputs(model, codes, texts, actions, config.self_condition, gen) if config.self_condition else codes
        # Word ids, not strings, go into the (maybe compiled) model: a compiled model guards on a
        # string's value and would recompile for every caption it meets.
        ids = text_ids(texts, model.config).to(device, non_blocking=True)
        with autocast(runtime, device):
            logits = call(inputs, ids, actions)
        with torch.no_grad():
            target = codes[:, 1:]
            accuracy = (logits[:, :-1].argmax(-1) == target).float().mean().item()
            copy = (codes[:, :-1] == target).float().mean().item()
        return next_frame_loss(logits.float(), codes, config.change_weight), {"accuracy": accuracy,
                                                                             "copy_accuracy": copy}

    return optimise(model, config, batch_loss, on_log)


def posttrain(pretrained: WorldModel, episodes: Sequence[CodeSequence], config: WorldTrainConfig,
              on_log: Callable[[dict], None] | None = None,
              runtime: Runtime | None = None) -> tuple[WorldModel, list[dict]]:
    """A copy of the pre-trained model with a zero-initialised action encoder (so it starts out
    computing exactly what the pre-trained model does), trained on episodes with their actions,
    each action value divided by its root mean square over these episodes (``action_scale``)."""
    torch.manual_seed(config.seed)
    c = pretrained.config
    scale = action_scale([e.actions for e in episodes], c.action_dim, c.temporal_compression)
    model = post_trainable(pretrained, scale, config.action_totals)
    return model, train_world_model(model, episodes, config, on_log, runtime)

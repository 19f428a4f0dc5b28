"""Diffusion world model over a continuous video tokenizer's latents, sized for a CPU.

A flow-matching (rectified flow) transformer beside the autoregressive ``models/world_model.py``:
Video2World after the Cosmos diffusion world models (NVIDIA, arXiv:2501.03575): context latent
frames go in clean, marked by a per-frame flag channel, and every future frame of the window
is denoised jointly with full attention over the window. Blocks are DiT blocks (Peebles and
Xie, arXiv:2212.09748) with adaptive layer norm, zero-initialised (AdaLN-Zero), conditioned on
the flow time, the pooled text and, once post-trained, the action leading into each frame.

Flow (rectified flow, Liu et al. arXiv:2209.03003; the SD3 convention, arXiv:2403.03206): at
time s in [0, 1] a future frame is ``x_s = (1 - s) x + s e`` with e ~ N(0, 1), so s = 0 is the
data and s = 1 pure noise; the model predicts the velocity ``e - x``, and ``sample`` integrates
it with Euler steps from s = 1 down to 0 (the step count is a parameter).

Layouts (``C = latent_channels``, ``t = temporal_compression``):

- latents ``B x C x T' x H' x W'`` float, about [-1, 1]: ``VideoTokenizer.encode`` of the
  continuous variant (channels before time); latent frame 0 is the first video frame alone,
  latent frame j >= 1 covers video frames ``t (j - 1) + 1 .. t j``.
- context: an int c (the first c frames of every row are context) or ``B x T'`` bool flags.
- text: a list of B strings, or ``B x text_tokens`` int64 word ids from
  ``models.world_model.text_ids`` (the autoregressive model's word hashing; 0 is padding),
  mean-pooled into the conditioning vector (a learned vector when a text has no words).
- actions ``B x S x action_features``, ``action_features = t x action_dim``, the layout of the
  autoregressive model (``tasks/world/data.align_actions``): row j leads from latent frame j to
  j + 1, so frame j + 1 is conditioned on row j and frame 0 on nothing; S >= T' - 1 (rows past
  the window are ignored).
- velocity ``B x C x T' x H' x W'``: meaningful on the future frames only.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field, model_validator
from torch import nn

from models.world_model import text_ids

DIFFUSION_WORLD_SCHEMA_VERSION = 1


class DiffusionWorldConfig(BaseModel):
    """Architecture of one diffusion world model; its JSON is saved beside every checkpoint."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    schema_version: int = DIFFUSION_WORLD_SCHEMA_VERSION
    name: str = "custom"
    latent_channels: int = Field(16, ge=1, description="C: the continuous tokenizer's latent channels")
    temporal_compression: int = Field(4, ge=1, description="video frames per latent frame: action slots per step")
    max_frames: int = Field(8, ge=2, description="latent frames in the window (context and future together)")
    max_height: int = Field(8, ge=1, description="largest latent grid height H'")
    max_width: int = Field(8, ge=1, description="largest latent grid width W'")
    patch: int = Field(2, ge=1, description="each token holds a patch x patch block of latent positions")
    temporal_patch: int = Field(1, ge=1, description="... of this many latent frames (windows are padded to it)")
    width: int = Field(64, ge=8, description="model dimension")
    layers: int = Field(2, ge=1)
    heads: int = Field(4, ge=1)
    mlp_ratio: int = Field(4, ge=1)
    text_vocab: int = Field(2048, ge=2, description="hash buckets for words; id 0 is padding")
    text_tokens: int = Field(32, ge=1, description="words kept per text (distinct, in order of appearance)")
    action_dim: int = Field(8, ge=1, description="actions are zero-padded to this many values per control step")
    action_conditioned: bool = Field(False, description="has the action encoder (post-trained)")
    action_scale: tuple[float, ...] | None = Field(
        None, description="action_dim divisors applied before the action encoder; None: 1")
    action_totals: int = Field(0, ge=0, description="leading action values also given as running totals "
                                                    "(tasks/world/data.align_actions)")

    @model_validator(mode="after")
    def _consistent(self) -> "DiffusionWorldConfig":
        if self.width % self.heads:
            raise ValueError(f"width {self.width} is not a multiple of heads {self.heads}")
        if self.max_height % self.patch or self.max_width % self.patch:
            raise ValueError(f"grid {self.max_height} x {self.max_width} is not a multiple of patch {self.patch}")
        if self.max_frames % self.temporal_patch:
            raise ValueError(f"max_frames {self.max_frames} is not a multiple of temporal_patch {self.temporal_patch}")
        if self.action_scale is not None and (len(self.action_scale) != self.action_dim
                                              or not all(v > 0 and math.isfinite(v) for v in self.action_scale)):
            raise ValueError(f"action_scale needs {self.action_dim} positive finite values, got {self.action_scale}")
        return self

    @property
    def action_features(self) -> int:
        return self.temporal_compression * self.action_dim


def time_features(s: torch.Tensor, dim: int) -> torch.Tensor:
    """Sinusoidal features ``B x dim`` of flow times ``B`` in [0, 1] (scaled by 1000, as DiT's steps)."""
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, device=s.device, dtype=torch.float32) / half)
    angles = 1000.0 * s.float()[:, None] * freqs[None]
    return torch.cat([angles.cos(), angles.sin()], dim=-1)


def _modulate(x: torch.Tensor, shift: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    return x * (1 + scale) + shift


class DiTBlock(nn.Module):
    """Full self-attention and MLP, each under adaptive layer norm with a zero-initialised gate,
    so a fresh block is the identity. ``cond`` is ``B x N x width`` (one vector per token)."""

    def __init__(self, c: DiffusionWorldConfig):
        super().__init__()
        self.heads = c.heads
        self.norm1 = nn.LayerNorm(c.width, elementwise_affine=False)
        self.norm2 = nn.LayerNorm(c.width, elementwise_affine=False)
        self.qkv, self.proj = nn.Linear(c.width, 3 * c.width), nn.Linear(c.width, c.width)
        self.mlp = nn.Sequential(nn.Linear(c.width, c.mlp_ratio * c.width), nn.GELU(approximate="tanh"),
                                 nn.Linear(c.mlp_ratio * c.width, c.width))
        self.ada = nn.Linear(c.width, 6 * c.width)

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        b, n, d = x.shape
        shift1, scale1, gate1, shift2, scale2, gate2 = self.ada(F.silu(cond)).chunk(6, dim=-1)
        h = _modulate(self.norm1(x), shift1, scale1)
        q, k, v = self.qkv(h).view(b, n, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        y = F.scaled_dot_product_attention(q, k, v).transpose(1, 2).reshape(b, n, d)
        x = x + gate1 * self.proj(y)
        return x + gate2 * self.mlp(_modulate(self.norm2(x), shift2, scale2))


class ActionEncoder(nn.Module):
    """Per-token-frame actions ``B x T'' x (temporal_patch x action_features)`` -> ``B x T'' x
    width``, added to the conditioning vector. Its last layer starts at zero, so a model that
    gains it computes exactly what it computed without it (as the autoregressive model's)."""

    def __init__(self, c: DiffusionWorldConfig):
        super().__init__()
        scale = torch.tensor(c.action_scale or (1.0,) * c.action_dim, dtype=torch.float32)
        self.register_buffer("scale", scale.repeat(c.temporal_compression * c.temporal_patch), persistent=False)
        features = c.temporal_patch * c.action_features
        self.net = nn.Sequential(nn.Linear(features, c.width), nn.SiLU(), nn.Linear(c.width, c.width))
        nn.init.normal_(self.net[0].weight, std=0.02)
        nn.init.zeros_(self.net[0].bias)
        nn.init.zeros_(self.net[2].weight)
        nn.init.zeros_(self.net[2].bias)

    def forward(self, actions: torch.Tensor) -> torch.Tensor:
        return self.net(actions / self.scale)


class DiffusionWorldModel(nn.Module):
    """Velocity of the future latent frames of a window, given its clean context frames.

    ``forward(latents, time, context, text, actions)`` -> velocity ``B x C x T' x H' x W'``;
    ``sample`` generates the future frames of one window, ``rollout`` any number of frames.
    """

    def __init__(self, config: DiffusionWorldConfig):
        super().__init__()
        c = self.config = config
        w = c.width
        self.patch_in = (c.latent_channels + 1) * c.temporal_patch * c.patch * c.patch  # + the context flag
        self.embed = nn.Linear(self.patch_in, w)
        self.frame_embed = nn.Parameter(torch.zeros(c.max_frames // c.temporal_patch, w))
        self.row_embed = nn.Parameter(torch.zeros(c.max_height // c.patch, w))
        self.col_embed = nn.Parameter(torch.zeros(c.max_width // c.patch, w))
        self.time_mlp = nn.Sequential(nn.Linear(w, w), nn.SiLU(), nn.Linear(w, w))
        self.text_embed = nn.Embedding(c.text_vocab, w)
        self.no_text = nn.Parameter(torch.zeros(w))
        self.blocks = nn.ModuleList(DiTBlock(c) for _ in range(c.layers))
        self.norm = nn.LayerNorm(w, elementwise_affine=False)
        self.final_ada = nn.Linear(w, 2 * w)
        self.head = nn.Linear(w, c.latent_channels * c.temporal_patch * c.patch * c.patch)
        self.apply(self._init)
        for p in (self.frame_embed, self.row_embed, self.col_embed, self.no_text):
            nn.init.normal_(p, std=0.02)
        for layer in [b.ada for b in self.blocks] + [self.final_ada, self.head]:  # AdaLN-Zero: blocks start as identity
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)
        self.action_encoder = ActionEncoder(c) if c.action_conditioned else None

    @staticmethod
    def _init(module: nn.Module) -> None:
        if isinstance(module, nn.Linear):
            nn.init.xavier_uniform_(module.weight)
            nn.init.zeros_(module.bias)
        elif isinstance(module, nn.Embedding):
            nn.init.normal_(module.weight, std=0.02)

    def add_action_conditioning(self, action_scale: Sequence[float] | None = None,
                                action_totals: int = 0) -> "DiffusionWorldModel":
        """Add a zero-initialised action encoder in place (post-training); outputs are unchanged
        until it trains. The config becomes ``action_conditioned=True`` with ``action_scale`` and
        ``action_totals`` (as ``WorldModel.add_action_conditioning``)."""
        if self.action_encoder is None:
            scale = None if action_scale is None else tuple(float(v) for v in action_scale)
            self.config = DiffusionWorldConfig.model_validate(
                {**self.config.model_dump(), "action_conditioned": True, "action_scale": scale,
                 "action_totals": action_totals})
            device = next(self.parameters()).device
            self.action_encoder = ActionEncoder(self.config).to(device)
        return self

    def _text(self, text, batch: int, device) -> torch.Tensor:
        """Mean word embedding ``B x width``, or the learned no-text vector for a text without words."""
        if text is None:
            return self.no_text.expand(batch, -1)
        ids = (text if isinstance(text, torch.Tensor) else text_ids(list(text), self.config)).to(device)
        if ids.shape[0] != batch:
            raise ValueError(f"text has {ids.shape[0]} rows for a batch of {batch}")
        real = (ids != 0).to(self.no_text.dtype)[..., None]
        count = real.sum(1)
        pooled = (self.text_embed(ids) * real).sum(1) / count.clamp(min=1)
        return torch.where(count > 0, pooled, self.no_text.expand(batch, -1))

    def _actions(self, actions: torch.Tensor, b: int, t: int) -> torch.Tensor:
        """Rows ``B x S x F`` -> per token-frame ``B x T'' x (temporal_patch F)``: frame j + 1 gets row j."""
        c = self.config
        if self.action_encoder is None:
            raise ValueError("actions given to a model without action conditioning (add_action_conditioning)")
        if actions.shape[0] != b or actions.shape[1] < t - 1 or actions.shape[2] != c.action_features:
            raise ValueError(f"actions {tuple(actions.shape)}: need {b} x (>= {t - 1}) x {c.action_features}")
        per_frame = F.pad(actions[:, :t - 1], (0, 0, 1, 0))  # frame 0 has no action leading into it
        return per_frame.reshape(b, t // c.temporal_patch, c.temporal_patch * c.action_features)

    def forward(self, latents: torch.Tensor, time: torch.Tensor | float, context: int | torch.Tensor,
                text: torch.Tensor | Sequence[str] | None = None, actions: torch.Tensor | None = None) -> torch.Tensor:
        """latents ``B x C x T' x H' x W'`` (context frames clean, future frames at flow time
        ``time``, a float or ``B``) -> velocity ``B x C x T' x H' x W'``. ``context``: the number of
        leading context frames or ``B x T'`` bool flags. ``actions`` only for an action-conditioned
        model; without them it computes what the model it was post-trained from would."""
        c = self.config
        b, ch, t, h, w = latents.shape
        qt, q = c.temporal_patch, c.patch
        if ch != c.latent_channels or t > c.max_frames or h > c.max_height or w > c.max_width:
            raise ValueError(f"latents {tuple(latents.shape)} exceed {c.latent_channels} channels x max_frames "
                             f"{c.max_frames} x grid {c.max_height} x {c.max_width}")
        if t % qt or h % q or w % q:
            raise ValueError(f"latents {tuple(latents.shape)}: not a multiple of the patch {qt} x {q} x {q}")
        flags = context_flags(context, b, t, latents.device)
        time = torch.as_tensor(time, dtype=torch.float32, device=latents.device).expand(b)
        x = torch.cat([latents, flags[:, None, :, None, None].to(latents.dtype).expand(b, 1, t, h, w)], dim=1)
        gt, gh, gw = t // qt, h // q, w // q
        x = x.view(b, ch + 1, gt, qt, gh, q, gw, q).permute(0, 2, 4, 6, 1, 3, 5, 7).reshape(b, gt, gh, gw, -1)
        x = self.embed(x) + self.frame_embed[:gt, None, None] + self.row_embed[:gh, None] + self.col_embed[None, :gw]
        cond = (self.time_mlp(time_features(time, c.width).to(x.dtype)) + self._text(text, b, latents.device))[:, None]
        if actions is not None:
            cond = cond + self.action_encoder(self._actions(actions.to(x.dtype), b, t))
        cond = cond.expand(b, gt, -1).repeat_interleave(gh * gw, dim=1)  # one vector per token
        seq = x.reshape(b, gt * gh * gw, c.width)
        for block in self.blocks:
            seq = block(seq, cond)
        shift, scale = self.final_ada(F.silu(cond)).chunk(2, dim=-1)
        out = self.head(_modulate(self.norm(seq), shift, scale)).view(b, gt, gh, gw, ch, qt, q, q)
        return out.permute(0, 4, 1, 5, 2, 6, 3, 7).reshape(b, ch, t, h, w)

    @torch.no_grad()
    def sample(self, context: torch.Tensor, n_future: int, text: torch.Tensor | Sequence[str] | None = None,
               actions: torch.Tensor | None = None, steps: int = 8,
               generator: torch.Generator | None = None) -> torch.Tensor:
        """The window ``B x C x (c + n_future) x H' x W'``: the context ``B x C x c x H' x W'`` (c >= 1)
        returned as given, then ``n_future`` frames integrated from noise with ``steps`` Euler
        steps. ``actions`` ``B x (c - 1 + n_future) x action_features``. Noise is drawn with
        ``generator`` on its own device (the CPU by default), so a seed gives the same sample
        wherever the model runs; computed on the model's device, returned on the context's."""
        c, n = context.shape[2], n_future
        if c < 1 or n < 1 or steps < 1:
            raise ValueError(f"sample needs a context frame, a future frame and a step; got {c}, {n}, {steps}")
        pad = -(c + n) % self.config.temporal_patch  # extra future frames to fill the last temporal patch
        if c + n + pad > self.config.max_frames:
            raise ValueError(f"{c} context + {n} future frames exceed max_frames {self.config.max_frames}")
        where, device = context.device, next(self.parameters()).device
        known = context.to(device)
        b, ch, _, h, w = known.shape
        if actions is not None:
            actions = actions.to(device)
            if actions.shape[1] < c - 1 + n:
                raise ValueError(f"{n} frames after {c} need {c - 1 + n} action rows, got {actions.shape[1]}")
            actions = F.pad(actions[:, :c - 1 + n], (0, 0, 0, pad))
        ids = None if text is None else (text if isinstance(text, torch.Tensor) else text_ids(list(text), self.config))
        noise_device = generator.device if generator is not None else torch.device("cpu")
        x = torch.randn(b, ch, n + pad, h, w, generator=generator, device=noise_device).to(device, known.dtype)
        for i in range(steps):
            s, s_next = 1 - i / steps, 1 - (i + 1) / steps
            velocity = self(torch.cat([known, x], dim=2), s, c, ids, actions)[:, :, c:]
            x = x + (s_next - s) * velocity.to(x.dtype)
        return torch.cat([context, x[:, :, :n].to(where)], dim=2)

    @torch.no_grad()
    def rollout(self, context: torch.Tensor, n: int, text: torch.Tensor | Sequence[str] | None = None,
                actions: torch.Tensor | None = None, steps: int = 8, generator: torch.Generator | None = None,
                keep: int | None = None) -> torch.Tensor:
        """Generate ``n`` latent frames after ``context`` ``B x C x c x H' x W'``: ``B x C x n x H' x W'``.

        Chunk by chunk: each ``sample`` takes the latest ``keep`` frames (default: c, at most
        max_frames - 1) as context and fills the rest of a ``max_frames`` window, so past
        ``max_frames`` the window slides as the autoregressive rollout's does. ``actions`` ``B x
        (c - 1 + n) x action_features``: row j leads from frame j to j + 1 (an episode's actions
        sliced as ``[:, :c - 1 + n]``)."""
        c, limit = context.shape[2], self.config.max_frames
        keep = min(keep or c, limit - 1)
        if actions is not None and actions.shape[1] < c - 1 + n:
            raise ValueError(f"rollout of {n} frames after {c} needs {c - 1 + n} action rows, got {actions.shape[1]}")
        frames = context
        while frames.shape[2] < c + n:
            have = frames.shape[2]
            start = max(0, have - keep)
            chunk = min(c + n - have, limit - (have - start))
            rows = None if actions is None else actions[:, start:have - 1 + chunk]
            window = self.sample(frames[:, :, start:], chunk, text, rows, steps, generator)
            frames = torch.cat([frames, window[:, :, have - start:]], dim=2)
        return frames[:, :, c:]


def context_flags(context: int | torch.Tensor, batch: int, frames: int, device) -> torch.Tensor:
    """``B x T'`` bool: True on context frames (the first ``context`` when an int)."""
    if isinstance(context, torch.Tensor):
        if context.shape != (batch, frames):
            raise ValueError(f"context flags {tuple(context.shape)}: need {batch} x {frames}")
        return context.to(device, torch.bool)
    return (torch.arange(frames, device=device) < int(context)).expand(batch, frames)


def post_trainable(model: DiffusionWorldModel, action_scale: Sequence[float] | None = None,
                   action_totals: int = 0) -> DiffusionWorldModel:
    """A copy of a pre-trained model with the zero-initialised action encoder added."""
    return copy.deepcopy(model).add_action_conditioning(action_scale, action_totals)


PRESETS: dict[str, DiffusionWorldConfig] = {
    # Tests and smoke runs.
    "tiny-dwm": DiffusionWorldConfig(name="tiny-dwm", width=64, layers=2, heads=4),
    # About the size of the autoregressive small-wm (1.3M parameters).
    "small-dwm": DiffusionWorldConfig(name="small-dwm", width=128, layers=3, heads=4),
}


def preset(name: str, **overrides) -> DiffusionWorldConfig:
    """A named preset, validated again with ``overrides`` (e.g. the tokenizer's latent channels and grid)."""
    try:
        base = PRESETS[name]
    except KeyError:
        known = ", ".join(sorted(PRESETS))
        raise ValueError(f"unknown diffusion world model preset {name!r}; known: {known}") from None
    return DiffusionWorldConfig.model_validate({**base.model_dump(), **overrides}) if overrides else base

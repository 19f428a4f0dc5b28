"""Autoregressive world model over a discrete video tokenizer's codes, sized for a CPU.

A transformer with frame-level (block) causal attention, after the frame-by-frame next-token
models of the Cosmos world foundation models (NVIDIA, arXiv:2501.03575) and GAIA-1 (Wayve,
arXiv:2309.17080), with every token of the next latent frame predicted in parallel (one
step per frame, so a rollout of n frames costs n forward passes, not n H' W').

Layouts (``K = codebook_size``, ``t = temporal_compression``):

- codes ``B x T' x H' x W'``, int64 in [0, K): ``VideoTokenizer.encode`` of the discrete
  variant; latent frame 0 is the first video frame alone, latent frame j >= 1 covers video
  frames ``t (j - 1) + 1 .. t j``.
- text: a list of B strings, or ``B x text_tokens`` int64 word ids from ``text_ids`` (0 is
  padding). A bag of hashed words (no downloaded weights, no word order), used as prefix
  tokens that every frame attends to.
- actions ``B x S x action_features`` float, ``action_features = t x action_dim``: row j holds
  the actions applied between latent frame j and j + 1, as t slots (one per video frame that
  leads into frame j + 1), each the mean action of the control steps in that slot, zero-padded
  to ``action_dim`` (``tasks/world/data.align_actions`` makes them from an episode).
- logits ``B x T' x H' x W' x K``: position j predicts latent frame j + 1 from frames <= j,
  the text and actions rows <= j; the last position predicts the frame after the input.
"""

from __future__ import annotations

import copy
import hashlib
import math
import re
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field, model_validator
from torch import nn

WORLD_MODEL_SCHEMA_VERSION = 1


class WorldModelConfig(BaseModel):
    """Architecture of one world model; its JSON is saved beside every checkpoint."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    schema_version: int = WORLD_MODEL_SCHEMA_VERSION
    name: str = "custom"
    codebook_size: int = Field(1000, ge=2, description="K: the tokenizer's codebook (FSQ (8, 5, 5, 5) has 1000)")
    temporal_compression: int = Field(4, ge=1, description="video frames per latent frame: action slots per step")
    max_frames: int = Field(8, ge=2, description="latent frames in the context window (frame-index embeddings)")
    max_height: int = Field(8, ge=1, description="largest latent grid height H'")
    max_width: int = Field(8, ge=1, description="largest latent grid width W'")
    patch: int = Field(1, ge=1, description="each transformer token holds a patch x patch block of codes "
                                            "(embeddings summed per slot; one head per slot predicts them)")
    width: int = Field(64, ge=8, description="model dimension")
    layers: int = Field(2, ge=1)
    heads: int = Field(4, ge=1)
    mlp_ratio: int = Field(4, ge=1)
    text_vocab: int = Field(2048, ge=2, description="hash buckets for words; id 0 is padding")
    text_tokens: int = Field(32, ge=1, description="words kept per text (distinct, in order of appearance)")
    action_dim: int = Field(8, ge=1, description="actions are zero-padded to this many values per control step")
    action_conditioned: bool = Field(False, description="has the action encoder (post-trained)")
    action_scale: tuple[float, ...] | None = Field(
        None, description="action_dim divisors applied before the action encoder (post-training sets each to the "
                          "root mean square of that action value over its episodes); None: 1")
    action_totals: int = Field(0, ge=0, description="leading action values also given as running totals since the "
                                                    "episode's start (ee_delta: 3, the commanded tcp's offset); "
                                                    "tasks/world/data.align_actions")
    copy_path: bool = Field(False, description="add a learned gain to the logit of each position's current code "
                                               "(starting at log K: copy-last-frame at even odds)")

    @model_validator(mode="after")
    def _consistent(self) -> "WorldModelConfig":
        if self.width % self.heads:
            raise ValueError(f"width {self.width} is not a multiple of heads {self.heads}")
        if self.max_height % self.patch or self.max_width % self.patch:
            raise ValueError(f"grid {self.max_height} x {self.max_width} is not a multiple of patch {self.patch}")
        if self.action_scale is not None and (len(self.action_scale) != self.action_dim
                                              or not all(v > 0 and math.isfinite(v) for v in self.action_scale)):
            raise ValueError(f"action_scale needs {self.action_dim} positive finite values, got {self.action_scale}")
        return self

    @property
    def action_features(self) -> int:
        return self.temporal_compression * self.action_dim


_WORD = re.compile(r"[a-z0-9]+")


def text_ids(texts: Sequence[str | None], config: WorldModelConfig) -> torch.Tensor:
    """Strings -> ``B x text_tokens`` int64 word ids in [1, text_vocab), 0-padded.

    Words are lower-case alphanumeric runs, kept once each in order of appearance (the
    first ``text_tokens``), hashed with BLAKE2b so ids are the same in every process.
    """
    out = torch.zeros(len(texts), config.text_tokens, dtype=torch.int64)
    for i, text in enumerate(texts):
        words = list(dict.fromkeys(_WORD.findall((text or "").lower())))[:config.text_tokens]
        for j, word in enumerate(words):
            digest = int.from_bytes(hashlib.blake2b(word.encode(), digest_size=8).digest(), "little")
            out[i, j] = 1 + digest % (config.text_vocab - 1)
    return out


class Block(nn.Module):
    """Pre-norm transformer block; ``allowed`` is ``B x 1 x S x S`` bool (True: may attend)."""

    def __init__(self, c: WorldModelConfig):
        super().__init__()
        self.heads = c.heads
        self.norm1, self.norm2 = nn.LayerNorm(c.width), nn.LayerNorm(c.width)
        self.qkv, self.proj = nn.Linear(c.width, 3 * c.width), nn.Linear(c.width, c.width)
        self.mlp = nn.Sequential(nn.Linear(c.width, c.mlp_ratio * c.width), nn.GELU(),
                                 nn.Linear(c.mlp_ratio * c.width, c.width))

    def forward(self, x: torch.Tensor, allowed: torch.Tensor) -> torch.Tensor:
        b, s, d = x.shape
        q, k, v = self.qkv(self.norm1(x)).view(b, s, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        y = F.scaled_dot_product_attention(q, k, v, attn_mask=allowed)
        x = x + self.proj(y.transpose(1, 2).reshape(b, s, d))
        return x + self.mlp(self.norm2(x))


class ActionEncoder(nn.Module):
    """``B x S x action_features`` -> ``B x S x width``; the last layer starts at zero, so a
    model that gains this encoder computes exactly what it computed without it (ControlNet's
    zero initialisation, Zhang et al., arXiv:2302.05543).

    Each action value is first divided by its ``config.action_scale`` (every slot alike), so
    end-effector steps of a few millimetres reach the first layer at unit size rather than
    vanishing under its initial weights. Dividing, not standardising, keeps an empty slot at 0.
    """

    def __init__(self, c: WorldModelConfig):
        super().__init__()
        scale = torch.tensor(c.action_scale or (1.0,) * c.action_dim, dtype=torch.float32)
        self.register_buffer("scale", scale.repeat(c.temporal_compression), persistent=False)
        self.net = nn.Sequential(nn.Linear(c.action_features, c.width), nn.SiLU(), nn.Linear(c.width, c.width))
        nn.init.normal_(self.net[0].weight, std=0.02)
        nn.init.zeros_(self.net[0].bias)
        nn.init.zeros_(self.net[2].weight)
        nn.init.zeros_(self.net[2].bias)

    def forward(self, actions: torch.Tensor) -> torch.Tensor:
        return self.net(actions / self.scale)


class WorldModel(nn.Module):
    """Next-latent-frame prediction over tokenizer codes, conditioned on text and (optionally) actions.

    ``forward(codes, text, actions)``: codes ``B x T' x H' x W'`` int64 in [0, K) (T' <=
    max_frames) -> logits ``B x T' x H' x W' x K``; position j predicts frame j + 1 and sees
    frames <= j only. ``rollout`` generates frames after a context.
    """

    def __init__(self, config: WorldModelConfig):
        super().__init__()
        c = self.config = config
        slots = c.patch * c.patch
        self.code_embed = nn.Embedding(slots * c.codebook_size, c.width)  # code k in slot s: row s K + k
        self.row_embed = nn.Parameter(torch.zeros(c.max_height // c.patch, c.width))
        self.col_embed = nn.Parameter(torch.zeros(c.max_width // c.patch, c.width))
        self.frame_embed = nn.Parameter(torch.zeros(c.max_frames, c.width))
        self.text_embed = nn.Embedding(c.text_vocab, c.width)
        self.prefix = nn.Parameter(torch.zeros(1, 1, c.width))  # always present: no row attends to nothing
        self.blocks = nn.ModuleList(Block(c) for _ in range(c.layers))
        self.norm = nn.LayerNorm(c.width)
        self.head = nn.Linear(c.width, slots * c.codebook_size)
        # Most codes repeat from one latent frame to the next: a copy path lets the transformer
        # spend itself on what changes instead of first learning to echo its input through the head.
        self.copy_gain = nn.Parameter(torch.tensor(math.log(c.codebook_size))) if c.copy_path else None
        self.apply(self._init)
        for p in (self.row_embed, self.col_embed, self.frame_embed, self.prefix):
            nn.init.normal_(p, std=0.02)
        self.action_encoder = ActionEncoder(c) if c.action_conditioned else None

    @staticmethod
    def _init(module: nn.Module) -> None:
        if isinstance(module, (nn.Linear, nn.Embedding)):
            nn.init.normal_(module.weight, std=0.02)
        if isinstance(module, nn.Linear) and module.bias is not None:
            nn.init.zeros_(module.bias)

    def add_action_conditioning(self, action_scale: Sequence[float] | None = None,
                                action_totals: int = 0) -> "WorldModel":
        """Add a zero-initialised action encoder in place (post-training); outputs are unchanged
        until it trains. The config becomes ``action_conditioned=True`` with ``action_scale``
        (``action_dim`` divisors, see ``action_scale``; None: 1) and ``action_totals`` (how its
        actions are laid out: ``tasks/world/data.align_actions``)."""
        if self.action_encoder is None:
            scale = None if action_scale is None else tuple(float(v) for v in action_scale)
            self.config = WorldModelConfig.model_validate(
                {**self.config.model_dump(), "action_conditioned": True, "action_scale": scale,
                 "action_totals": action_totals})
            self.action_encoder = ActionEncoder(self.config)
        return self

    def _text(self, text, batch: int, device) -> tuple[torch.Tensor, torch.Tensor]:
        """Prefix tokens ``B x P x width`` and which of them are real ``B x P`` bool."""
        prefix = self.prefix.expand(batch, 1, -1)
        if text is None:
            return prefix, torch.ones(batch, 1, dtype=torch.bool, device=device)
        ids = text if isinstance(text, torch.Tensor) else text_ids(list(text), self.config)
        ids = ids.to(device)
        if ids.shape[0] != batch:
            raise ValueError(f"text has {ids.shape[0]} rows for a batch of {batch}")
        real = torch.cat([torch.ones(batch, 1, dtype=torch.bool, device=device), ids != 0], dim=1)
        return torch.cat([prefix, self.text_embed(ids)], dim=1), real

    def forward(self, codes: torch.Tensor, text: torch.Tensor | Sequence[str] | None = None,
                actions: torch.Tensor | None = None) -> torch.Tensor:
        """codes ``B x T' x H' x W'`` int64 in [0, K) -> logits ``B x T' x H' x W' x K``.

        Position j predicts latent frame j + 1. ``actions`` is ``B x S x action_features`` with
        S = T' (row j leads from frame j to j + 1) or S = T' - 1 (the last position gets no
        action term); only an ``action_conditioned`` model takes them, and without them it
        computes what the model it was post-trained from would with these weights.
        """
        c = self.config
        b, t, h, w = codes.shape
        if t > c.max_frames or h > c.max_height or w > c.max_width:
            raise ValueError(f"codes {tuple(codes.shape)} exceed max_frames {c.max_frames} x grid "
                             f"{c.max_height} x {c.max_width}")
        q = c.patch
        if h % q or w % q:
            raise ValueError(f"codes {tuple(codes.shape)}: grid is not a multiple of patch {q}")
        gh, gw = h // q, w // q
        slot = torch.arange(q * q, device=codes.device) * c.codebook_size
        x = self.code_embed(_patches(codes, q) + slot).sum(-2)  # B x T' x gh x gw x width
        x = x + self.frame_embed[:t, None, None] + self.row_embed[:gh, None] + self.col_embed[None, :gw]
        if actions is not None:
            if self.action_encoder is None:
                raise ValueError("actions given to a model without action conditioning (add_action_conditioning)")
            if actions.shape[0] != b or actions.shape[1] not in (t, t - 1) or actions.shape[2] != c.action_features:
                raise ValueError(f"actions {tuple(actions.shape)}: need {b} x ({t} or {t - 1}) x {c.action_features}")
            a = self.action_encoder(actions.to(x.dtype))
            x = x + F.pad(a, (0, 0, 0, t - a.shape[1]))[:, :, None, None]
        prefix, real = self._text(text, b, codes.device)
        p, n = prefix.shape[1], t * gh * gw
        frame = torch.arange(t, device=codes.device).repeat_interleave(gh * gw)
        allowed = torch.zeros(b, p + n, p + n, dtype=torch.bool, device=codes.device)
        allowed[:, :, :p] = real[:, None, :]  # everyone reads the real prefix tokens
        allowed[:, p:, p:] = frame[None, :, None] >= frame[None, None, :]  # frames <= own frame
        seq = torch.cat([prefix, x.reshape(b, n, c.width)], dim=1)
        mask = allowed[:, None]
        for block in self.blocks:
            seq = block(seq, mask)
        logits = self.head(self.norm(seq[:, p:])).view(b, t, gh, gw, q, q, c.codebook_size)
        logits = logits.permute(0, 1, 2, 4, 3, 5, 6).reshape(b, t, h, w, c.codebook_size)
        if self.copy_gain is not None:
            logits = logits.scatter_add(-1, codes[..., None], self.copy_gain.expand(b, t, h, w, 1))
        return logits

    @torch.no_grad()
    def rollout(self, context_codes: torch.Tensor, n: int, text: torch.Tensor | Sequence[str] | None = None,
                actions: torch.Tensor | None = None, temperature: float = 0.0,
                generator: torch.Generator | None = None) -> torch.Tensor:
        """Generate ``n`` latent frames after ``context_codes``: ``B x n x H' x W'`` int64 in [0, K).

        context_codes ``B x c x H' x W'`` (c >= 1). ``actions`` ``B x (c - 1 + n) x
        action_features``: row j leads from frame j to j + 1 (an episode's ``actions`` sliced
        as ``[:, :c - 1 + n]``). Argmax when ``temperature`` is 0, else sampling from
        softmax(logits / temperature) with ``generator`` (a generator on the model's device). Past
        ``max_frames``, the window slides and keeps the latest frames. Inputs may be on any
        device: the rollout runs on the model's and returns on the context's.
        """
        c, where = context_codes.shape[1], context_codes.device
        device = next(self.parameters()).device  # computed there, returned on the context's device
        context_codes = context_codes.to(device)
        actions = actions.to(device) if actions is not None else None
        if actions is not None and actions.shape[1] < c - 1 + n:
            raise ValueError(f"rollout of {n} frames after {c} needs {c - 1 + n} action rows, got {actions.shape[1]}")
        ids = None if text is None else (text if isinstance(text, torch.Tensor) else text_ids(list(text), self.config))
        codes = context_codes
        for _ in range(n):
            start = max(0, codes.shape[1] - self.config.max_frames)
            window = codes[:, start:]
            rows = None if actions is None else actions[:, start:codes.shape[1]]
            logits = self(window, ids, rows)[:, -1]
            if temperature > 0:
                probs = torch.softmax(logits.float() / temperature, dim=-1)
                nxt = torch.multinomial(probs.view(-1, probs.shape[-1]), 1, generator=generator).view(logits.shape[:-1])
            else:
                nxt = logits.argmax(dim=-1)
            codes = torch.cat([codes, nxt[:, None]], dim=1)
        return codes[:, c:].to(where)


def _patches(codes: torch.Tensor, q: int) -> torch.Tensor:
    """``B x T' x H' x W'`` -> ``B x T' x H'/q x W'/q x q*q``: each q x q block, row-major."""
    b, t, h, w = codes.shape
    return codes.view(b, t, h // q, q, w // q, q).permute(0, 1, 2, 4, 3, 5).reshape(b, t, h // q, w // q, q * q)


def next_frame_loss(logits: torch.Tensor, codes: torch.Tensor, change_weight: float = 0.0) -> torch.Tensor:
    """Mean cross-entropy (nats) of logits ``B x T' x H' x W' x K`` against codes
    ``B x T' x H' x W'``: position j is scored on frame j + 1, the last position not at all.

    With ``change_weight``, a weighted mean: codes that differ from the same position in the
    frame before count ``1 + change_weight`` times (what moves, rather than what a copy of
    the last frame already gets right)."""
    k = logits.shape[-1]
    losses = F.cross_entropy(logits[:, :-1].reshape(-1, k), codes[:, 1:].reshape(-1), reduction="none")
    if not change_weight:
        return losses.mean()
    weights = 1 + change_weight * (codes[:, 1:] != codes[:, :-1]).reshape(-1).to(losses.dtype)
    return (losses * weights).sum() / weights.sum()


def post_trainable(model: WorldModel, action_scale: Sequence[float] | None = None,
                   action_totals: int = 0) -> WorldModel:
    """A copy of a pre-trained model with the zero-initialised action encoder added."""
    return copy.deepcopy(model).add_action_conditioning(action_scale, action_totals)


def action_scale(actions: Sequence, action_dim: int, temporal_compression: int,
                 floor: float = 1e-6) -> tuple[float, ...]:
    """Per action value, the root mean square over every slot of ``actions`` (arrays or tensors
    ``S x (temporal_compression x action_dim)``, as ``tasks/world/data.align_actions`` makes
    them; None entries are skipped), or 1 for a value that is always 0 (the zero padding).
    LeRobot likewise normalises actions with dataset statistics (mean and standard deviation)
    before a policy sees them; an RMS without centring keeps "no action" at 0."""
    rows = [torch.as_tensor(a, dtype=torch.float64).reshape(-1, temporal_compression, action_dim)
            for a in actions if a is not None and len(a)]
    if not rows:
        return (1.0,) * action_dim
    values = torch.cat(rows).reshape(-1, action_dim)
    rms = values.pow(2).mean(0).sqrt()
    return tuple(float(v) if v > floor else 1.0 for v in rms)


PRESETS: dict[str, WorldModelConfig] = {
    # Tests and smoke runs: 0.36M parameters (a third of them the word-hash table); a step on
    # 8 windows of 8 latent frames of 4 x 4 codes costs about 0.07 CPU-seconds.
    "tiny-wm": WorldModelConfig(name="tiny-wm", width=64, layers=2, heads=4, copy_path=True),
    # The bench's model: 1.3M parameters; about 1 CPU-second a step on 8 windows of 8 x 8 x 8 codes.
    "small-wm": WorldModelConfig(name="small-wm", width=128, layers=4, heads=4, copy_path=True),
}


def preset(name: str, **overrides) -> WorldModelConfig:
    """A named preset, validated again with ``overrides`` (e.g. the tokenizer's codebook and grid)."""
    try:
        base = PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown world model preset {name!r}; known: {', '.join(sorted(PRESETS))}") from None
    return WorldModelConfig.model_validate({**base.model_dump(), **overrides}) if overrides else base

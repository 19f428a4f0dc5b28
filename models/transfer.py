"""Control-conditioned video generator for transfer, after Cosmos-Transfer (NVIDIA, arXiv:2503.14492), sized for a CPU.

A small U-Net applied frame by frame: frame t is made from the controls of frame t (edges,
blur, depth, segmentation), the generator's own frame t - 1 (zeros for the first frame) and a
prompt from a fixed vocabulary of looks, and optionally a reference clip's colour statistics
(``reference_features``: the look of any clip, e.g. from a curated shard, for looks a word
cannot pin down, such as one random colour shift), so frame t depends on controls and
outputs up to t only. Each control's input channels are multiplied by its weight, a scalar per clip or a map
per pixel and frame, as Cosmos-Transfer weights its control branches (a weight of 0 removes
that control exactly); the prompt scales and shifts every normalised feature map (FiLM).

Layouts: controls ``B x control_channels x T x H x W`` float, stacked in ``config.controls``
order (edges 1 channel in {-1, 1}, blur 3 in [-1, 1], depth 1 in [-1, 1], segmentation
``seg_classes`` one-hot in {0, 1}); weights ``B x len(controls)`` or ``B x len(controls) x T
x H x W`` (any broadcastable shape of those), >= 0; prompts ``B`` int64 indices into
``PROMPTS``; frames ``B x 3 x T x H x W`` float in [-1, 1], H and W multiples of
``2 ** (len(channels) - 1)``.
"""

from __future__ import annotations

from typing import Literal

import torch
from pydantic import BaseModel, ConfigDict, Field, model_validator
from torch import nn

TRANSFER_SCHEMA_VERSION = 1

# The looks the simulator renders as stressors (tasks/transfer/pairs.py LOOKS maps each to
# one): training pairs exist for exactly these. "warm light" is not among them: the scene
# scales its lights' intensity only, it cannot tint them.
PROMPTS: tuple[str, ...] = ("nominal", "dim", "very dim", "colour shift", "textures")
CONTROL_KINDS = ("edges", "blur", "depth", "segmentation")  # Cosmos-Transfer's controls, the default
# "frame": the source look's own frame, a blur of sigma 0. Opt-in (preset small-frame): with it
# the model restyles the source's pixels, where the four above make them anew.
ControlKind = Literal["edges", "blur", "depth", "segmentation", "frame"]
ALL_CONTROLS = (*CONTROL_KINDS, "frame")
OBJECT_CLASSES = 8  # tasks.transfer.pairs.OBJECT_CLASSES (a test keeps the two equal)


class TransferConfig(BaseModel):
    """Architecture of one transfer model; its JSON is saved beside every checkpoint."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    schema_version: int = TRANSFER_SCHEMA_VERSION
    name: str = "custom"
    controls: tuple[ControlKind, ...] = Field(CONTROL_KINDS, min_length=1, description="input controls, in stacking order")
    seg_classes: int = Field(6, ge=1, description="one-hot segmentation channels")
    prompts: tuple[str, ...] = Field(PROMPTS, min_length=1)
    prompt_dim: int = Field(32, ge=1)
    channels: tuple[int, ...] = Field((32, 64, 128), min_length=1, description="width per resolution level, finest first")
    groups: int = Field(8, ge=1, description="GroupNorm groups (every width must divide by it)")
    reference: bool = Field(False, description="also conditioned on a reference clip's colour statistics")
    palette: bool = Field(False, description="also given, per segmentation class, the reference clip's mean colour "
                          "(`palette_features`), drawn over the source's segmentation beside the source's own class "
                          "means: a look whose colours differ per object, such as a random colour shift")
    seg_groups: Literal["grouped", "objects"] = Field(
        "grouped", description="what the segmentation channels' classes are: grouped (tasks.transfer.pairs.SEG_GROUPS, "
        "table and floor one class) or objects (OBJECT_GROUPS, one class per object; seg_classes 8)")
    palette_gain: Literal["frame", "clip"] = Field(
        "frame", description="the source class means the palette's gain starts from: each frame's own (frame) or "
        "the whole clip's (clip): a class's mean moves as objects occlude and leave it, and a gain that follows it "
        "flickers")
    head: Literal["direct", "affine"] = Field(
        "direct", description="direct: the net paints the frame; affine: it predicts a per-pixel gain and offset "
        "applied to the (weighted) 'frame' control, so the source's edges pass through unless the net moves them")

    @model_validator(mode="after")
    def _consistent(self) -> "TransferConfig":
        if len(set(self.controls)) != len(self.controls):
            raise ValueError(f"controls repeat: {self.controls}")
        if any(w % self.groups for w in self.channels):
            raise ValueError(f"every width in {self.channels} must divide by groups={self.groups}")
        if self.head == "affine" and "frame" not in self.controls:
            raise ValueError("head 'affine' transforms the source's frame: controls must include 'frame'")
        if self.palette and not (self.reference and {"frame", "segmentation"} <= set(self.controls)):
            raise ValueError("palette needs reference conditioning and the 'frame' and 'segmentation' controls")
        if self.seg_groups == "objects" and self.seg_classes != OBJECT_CLASSES:
            raise ValueError(f"seg_groups 'objects' has {OBJECT_CLASSES} classes, not seg_classes={self.seg_classes}")
        return self

    def channels_of(self, control: str) -> int:
        return {"edges": 1, "blur": 3, "depth": 1, "segmentation": self.seg_classes, "frame": 3}[control]

    @property
    def control_channels(self) -> int:
        return sum(self.channels_of(c) for c in self.controls)

    @property
    def reference_size(self) -> int:
        """Length of a reference row: the global statistics, then (palette) 4 numbers a class."""
        return REFERENCE_FEATURES + (4 * self.seg_classes if self.palette else 0)

    @property
    def multiple(self) -> int:
        """H and W must be multiples of this."""
        return 2 ** (len(self.channels) - 1)

    def prompt_index(self, prompt: str) -> int:
        try:
            return self.prompts.index(prompt)
        except ValueError:
            raise ValueError(f"unknown prompt {prompt!r}; known: {', '.join(self.prompts)}") from None


REFERENCE_BINS = 8  # histogram bins per colour channel
REFERENCE_FEATURES = 3 + 3 + 3 * REFERENCE_BINS


def reference_features(frames: torch.Tensor) -> torch.Tensor:
    """A clip's look as numbers: frames ``B x 3 x T x H x W`` in [-1, 1] -> ``B x
    REFERENCE_FEATURES``: per colour channel the mean, the standard deviation and the share of
    pixels in each of ``REFERENCE_BINS`` equal bins over [-1, 1]. Global over frames and
    pixels, so any clip of any size and content can be a reference."""
    flat = frames.detach().float().flatten(2)  # B x 3 x N
    mean, std = flat.mean(2), flat.std(2, unbiased=False)
    index = ((flat.clamp(-1, 1) + 1) * (REFERENCE_BINS / 2)).long().clamp(max=REFERENCE_BINS - 1)
    counts = torch.zeros(*flat.shape[:2], REFERENCE_BINS, device=flat.device).scatter_add_(
        2, index, torch.ones_like(flat))
    return torch.cat([mean, std, (counts / flat.shape[2]).flatten(1)], 1)


def palette_features(frames: torch.Tensor, seg: torch.Tensor, classes: int) -> torch.Tensor:
    """Per segmentation class, the clip's mean colour and whether the class is in it: frames
    ``B x 3 x T x H x W`` in [-1, 1], seg ``B x T x H x W`` class ids -> ``B x 4 * classes``
    (r, g, b, 1 for each class present; 0, 0, 0, 0 for one absent)."""
    onehot = nn.functional.one_hot(seg.long(), classes).to(frames.dtype)  # B x T x H x W x K
    counts = onehot.sum((1, 2, 3))
    means = torch.einsum("bthwk,bcthw->bkc", onehot, frames.float()) / counts.clamp(min=1)[..., None]
    known = (counts > 0).to(frames.dtype)
    return torch.cat([means * known[..., None], known[..., None]], 2).flatten(1)


class FiLMBlock(nn.Module):
    """Residual block: (GroupNorm, FiLM by the prompt, SiLU, 3x3 conv) twice, plus a skip."""

    def __init__(self, cin: int, cout: int, prompt_dim: int, groups: int):
        super().__init__()
        self.norm1 = nn.GroupNorm(min(groups, cin), cin, affine=False)
        self.conv1 = nn.Conv2d(cin, cout, 3, padding=1)
        self.norm2 = nn.GroupNorm(groups, cout, affine=False)
        self.conv2 = nn.Conv2d(cout, cout, 3, padding=1)
        self.film = nn.Linear(prompt_dim, 2 * (cin + cout))
        self.skip = nn.Conv2d(cin, cout, 1) if cin != cout else nn.Identity()
        self.split = (cin, cin, cout, cout)

    def forward(self, x: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        f = self.film(p)[..., None, None]
        s1, b1, s2, b2 = f.split(self.split, 1)
        h = self.conv1(nn.functional.silu(self.norm1(x) * (1 + s1) + b1))
        h = self.conv2(nn.functional.silu(self.norm2(h) * (1 + s2) + b2))
        return self.skip(x) + h


class TransferNet(nn.Module):
    """U-Net over one frame at a time; ``forward`` makes a clip causally, ``step`` one frame."""

    def __init__(self, config: TransferConfig):
        super().__init__()
        self.config = config
        c = config
        self.prompt = nn.Embedding(len(c.prompts), c.prompt_dim)
        # A reference's statistics move the prompt's embedding; without one it is the prompt's alone.
        self.reference = nn.Sequential(nn.Linear(REFERENCE_FEATURES, c.prompt_dim), nn.SiLU(),
                                       nn.Linear(c.prompt_dim, c.prompt_dim)) if c.reference else None
        # With a palette: the reference's class colours drawn over the segmentation (3), where
        # they are known (1), and the gain from the source's class means to them (3).
        self.conv_in = nn.Conv2d(c.control_channels + 3 + (7 if c.palette else 0), c.channels[0], 3, padding=1)
        self.down = nn.ModuleList()
        self.pool = nn.ModuleList()
        for i, width in enumerate(c.channels):
            self.down.append(FiLMBlock(width, width, c.prompt_dim, c.groups))
            if i + 1 < len(c.channels):
                self.pool.append(nn.Conv2d(width, c.channels[i + 1], 3, stride=2, padding=1))
        self.mid = FiLMBlock(c.channels[-1], c.channels[-1], c.prompt_dim, c.groups)
        self.lift = nn.ModuleList()
        self.up = nn.ModuleList()
        for i in reversed(range(len(c.channels) - 1)):
            self.lift.append(nn.Conv2d(c.channels[i + 1], c.channels[i], 3, padding=1))
            self.up.append(FiLMBlock(2 * c.channels[i], c.channels[i], c.prompt_dim, c.groups))
        self.norm_out = nn.GroupNorm(c.groups, c.channels[0])
        self.conv_out = nn.Conv2d(c.channels[0], 6 if c.head == "affine" else 3, 3, padding=1)
        if c.head == "affine":  # starts as the identity on the frame control (with a palette: its gain), offset 0
            nn.init.zeros_(self.conv_out.weight)
            nn.init.zeros_(self.conv_out.bias)
        if "frame" in c.controls:
            self._frame = self._channels("frame")
        if "segmentation" in c.controls:
            self._seg = self._channels("segmentation")
        # Per-channel index of the control it belongs to, to spread control weights over channels.
        owner = [i for i, name in enumerate(c.controls) for _ in range(c.channels_of(name))]
        self.register_buffer("_owner", torch.tensor(owner, dtype=torch.long), persistent=False)

    def _channels(self, control: str) -> slice:
        before = self.config.controls[:self.config.controls.index(control)]
        start = sum(self.config.channels_of(name) for name in before)
        return slice(start, start + self.config.channels_of(control))

    def source_means(self, weighted: torch.Tensor) -> torch.Tensor:
        """Mean colour of the source's (weighted) frame per segmentation class, in [0, 1] units:
        ``B x C x [T x] H x W`` -> ``B x classes x 3``, over every frame given."""
        seg, frame = weighted[:, self._seg].flatten(2), (weighted[:, self._frame].flatten(2) + 1) / 2
        return torch.einsum("bkn,bcn->bkc", seg, frame) / seg.sum(2).clamp(min=1e-6)[..., None]

    def palette_maps(self, weighted: torch.Tensor, reference: torch.Tensor | None,
                     source: torch.Tensor | None = None) -> torch.Tensor:
        """``B x 7 x H x W``: the reference's class colours over the (weighted) segmentation, where
        they are known, and the gain per colour channel minus 1 that takes the source's class
        mean (``source``, ``B x classes x 3`` from ``source_means``; by default this frame's) to
        the reference's (in [0, 1] units, at most 4; 0 where unknown): what the affine head's
        gain reads. A reference row without a palette (the global statistics only, a clip with
        no segmentation) knows no class."""
        seg = weighted[:, self._seg]
        b, k = seg.shape[:2]
        known_rows = reference is not None and reference.shape[1] == self.config.reference_size
        palette = (torch.nan_to_num(reference[:, REFERENCE_FEATURES:]).to(seg).view(b, k, 4) if known_rows
                   else seg.new_zeros(b, k, 4))
        colours, known = palette[..., :3] * palette[..., 3:], palette[..., 3]
        source = self.source_means(weighted) if source is None else source.to(seg)
        gain = (((colours + 1) / 2) / source.clamp(min=0.02) - 1).clamp(-1, 3) * known[..., None]
        drawn = torch.einsum("bkhw,bkc->bchw", seg, colours)
        where = torch.einsum("bkhw,bk->bhw", seg, known)[:, None]
        return torch.cat([drawn, where, torch.einsum("bkhw,bkc->bchw", seg, gain)], 1)

    def weighted(self, controls: torch.Tensor, weights: torch.Tensor | None) -> torch.Tensor:
        """``controls`` (``B x C x [T x] H x W``) with each control's channels times its weight."""
        if weights is None:
            return controls
        n = len(self.config.controls)
        if weights.dim() < 2 or weights.shape[1] != n:
            raise ValueError(f"weights need {n} entries along dim 1 (one per control), got shape {tuple(weights.shape)}")
        w = weights.to(controls).index_select(1, self._owner)
        w = w.reshape(*w.shape, *([1] * (controls.dim() - w.dim())))
        return controls * w

    def condition(self, prompts: torch.Tensor, reference: torch.Tensor | None = None) -> torch.Tensor:
        """The look's embedding ``B x prompt_dim``: the prompt's, moved by the reference's
        features (``B x REFERENCE_FEATURES``, or ``B x config.reference_size`` with a palette;
        NaN rows mean "no reference" for that clip)."""
        p = self.prompt(prompts)
        if reference is None:
            return p
        if self.reference is None:
            raise ValueError("this transfer model was not trained with reference clips")
        if reference.shape[1] not in (REFERENCE_FEATURES, self.config.reference_size):
            raise ValueError(f"reference rows of {reference.shape[1]} numbers; this model takes {REFERENCE_FEATURES}"
                             + (f" or {self.config.reference_size}" if self.config.palette else ""))
        look = reference[:, :REFERENCE_FEATURES]
        given = ~look.isnan().any(1, keepdim=True)
        return p + self.reference(torch.nan_to_num(look.to(p))) * given

    def step(self, controls: torch.Tensor, previous: torch.Tensor, prompts: torch.Tensor,
             weights: torch.Tensor | None = None, reference: torch.Tensor | None = None,
             source: torch.Tensor | None = None) -> torch.Tensor:
        """One frame: controls ``B x C x H x W``, previous frame ``B x 3 x H x W`` in [-1, 1],
        prompts ``B``, weights ``B x n`` or ``B x n x H x W``, reference rows (see ``condition``)
        or None, and for a palette model the source class means its gain starts from
        (``palette_maps``; by default the frame's own) -> frame ``B x 3 x H x W`` in [-1, 1]."""
        m = self.config.multiple
        if controls.shape[-1] % m or controls.shape[-2] % m:
            raise ValueError(f"frame size {tuple(controls.shape[-2:])}: H and W must be multiples of {m}")
        p = self.condition(prompts, reference)
        weighted = self.weighted(controls, weights)
        maps = self.palette_maps(weighted, reference, source) if self.config.palette else None
        h = self.conv_in(torch.cat([weighted, previous, *([maps] if maps is not None else [])], 1))
        skips = []
        for i, block in enumerate(self.down):
            h = block(h, p)
            if i < len(self.pool):
                skips.append(h)
                h = self.pool[i](h)
        h = self.mid(h, p)
        for lift, block in zip(self.lift, self.up):
            h = lift(nn.functional.interpolate(h, scale_factor=2.0, mode="nearest"))
            h = block(torch.cat([h, skips.pop()], 1), p)
        out = self.conv_out(nn.functional.silu(self.norm_out(h)))
        if self.config.head == "direct":
            return torch.tanh(out)
        gain, offset = out.split(3, 1)
        if maps is not None:  # the palette's gain is where the head starts: the net learns what it misses
            gain = gain + maps[:, 4:]
        # In [0, 1] pixel units: the frame's weight scales the source pixel (0: the offset alone).
        frame01 = (controls[:, self._frame] + 1) / 2
        if weights is not None:
            w = weights.to(frame01)[:, self.config.controls.index("frame")].unsqueeze(1)
            frame01 = frame01 * w.reshape(*w.shape, *([1] * (frame01.dim() - w.dim())))
        out01 = (1 + gain) * frame01 + offset
        if torch.is_grad_enabled():  # the clip's value, the identity's gradient: a pixel pushed out of
            # [0, 1] can come back (a plain clamp's zero gradient left a dark look black for good)
            return (out01 + (out01.clamp(0, 1) - out01).detach()) * 2 - 1
        return out01.clamp(0, 1) * 2 - 1

    def forward(self, controls: torch.Tensor, prompts: torch.Tensor, weights: torch.Tensor | None = None,
                previous: torch.Tensor | None = None, reference: torch.Tensor | None = None) -> torch.Tensor:
        """A clip: controls ``B x C x T x H x W`` -> frames ``B x 3 x T x H x W`` in [-1, 1];
        ``reference``: ``reference_features`` of a clip in the wanted look, or None.

        With ``previous`` (``B x 3 x T x H x W``: frame t is given frame t - 1 of it, zeros for
        the first) all frames are made at once (teacher forcing); without it frame by frame,
        each from the generator's own previous frame, starting from zeros."""
        b, _, t, hh, ww = controls.shape
        if weights is not None and weights.dim() == 5:
            per_frame = weights.movedim(2, 1).reshape(b * t, *weights.shape[1:2], *weights.shape[3:])
        elif weights is not None:
            per_frame = weights.repeat_interleave(t, 0)
        else:
            per_frame = None
        clip_gain = self.config.palette and self.config.palette_gain == "clip"
        if clip_gain:  # per-pixel weights shared by every frame (B x n x H x W) apply along T too
            shared = weights is not None and weights.dim() == 4
            source = self.source_means(self.weighted(controls, weights.unsqueeze(2) if shared else weights))
        else:
            source = None
        if previous is not None:
            shifted = torch.cat([torch.zeros_like(previous[:, :, :1]), previous[:, :, :-1]], 2)
            flat = lambda x: x.movedim(2, 1).reshape(b * t, x.shape[1], hh, ww)  # noqa: E731
            ref = None if reference is None else reference.repeat_interleave(t, 0)
            out = self.step(flat(controls), flat(shifted), prompts.repeat_interleave(t), per_frame, ref,
                            None if source is None else source.repeat_interleave(t, 0))
            return out.reshape(b, t, 3, hh, ww).movedim(1, 2)
        frames, prev = [], controls.new_zeros(b, 3, hh, ww)
        for i in range(t):
            w = None if per_frame is None else per_frame.reshape(b, t, *per_frame.shape[1:])[:, i]
            prev = self.step(controls[:, :, i], prev, prompts, w, reference, source)
            frames.append(prev)
        return torch.stack(frames, 2)


PRESETS: dict[str, TransferConfig] = {
    # Tests: a forward pass on 16 x 16 in milliseconds.
    "tiny": TransferConfig(name="tiny", channels=(8, 16), prompt_dim=8, groups=4),
    # This machine's smoke runs at 64 x 64 (about 0.29M parameters: 26 ms a frame forward and
    # backward on one loaded core; (32, 64, 128), 1.1M, took 4x that).
    "small": TransferConfig(name="small", channels=(16, 32, 64), prompt_dim=32, groups=8),
    # The same, also conditioned on a reference clip's colour statistics (about 2K parameters more).
    "small-ref": TransferConfig(name="small-ref", channels=(16, 32, 64), prompt_dim=32, groups=8, reference=True),
    # small-ref that also sees the source look's own frame (the "frame" control).
    "small-frame": TransferConfig(name="small-frame", controls=ALL_CONTROLS, channels=(16, 32, 64), prompt_dim=32,
                                  groups=8, reference=True),
    # small-frame whose output is a per-pixel gain and offset of the source's frame (head "affine").
    "small-affine": TransferConfig(name="small-affine", controls=ALL_CONTROLS, channels=(16, 32, 64), prompt_dim=32,
                                   groups=8, reference=True, head="affine"),
    # small-affine also given the reference's mean colour per object (`palette`, `seg_groups` objects),
    # its gain taken from the clip's class means (`palette_gain` clip).
    "small-palette": TransferConfig(name="small-palette", controls=ALL_CONTROLS, channels=(16, 32, 64), prompt_dim=32,
                                    groups=8, reference=True, head="affine", palette=True, seg_groups="objects",
                                    seg_classes=OBJECT_CLASSES, palette_gain="clip"),
}


def preset(name: str) -> TransferConfig:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown transfer preset {name!r}; known: {', '.join(sorted(PRESETS))}") from None

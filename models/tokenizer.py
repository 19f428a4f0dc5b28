"""Causal video tokenizer after the Cosmos Tokenizer (NVIDIA, arXiv:2501.03575), sized for a CPU.

Haar wavelet patching, factorised causal 3D convolutions in residual blocks, self-attention
at the lowest resolution, and either a bounded continuous latent (autoencoder) or finite
scalar quantisation (FSQ). ``1 + t k`` input frames give ``1 + k`` latent frames at temporal
compression t, and latent frame j depends on input frames <= t j only, so the first latent
frame is an image code of the first frame alone.

Layouts: video ``B x 3 x T x H x W, float in [-1, 1]`` with ``T = 1 + t k`` and H, W
multiples of the spatial compression; continuous latents ``B x latent_channels x (1 + k) x
H/s x W/s, float in [-1, 1]``; discrete codes ``B x (1 + k) x H/s x W/s, int64 in [0,
codebook_size)``.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
from pydantic import BaseModel, ConfigDict, Field, model_validator
from torch import nn

from models.tokenizer_layers import (
    FSQ, CausalTemporalConv, Downsample, FrameAttention, FrameNorm, ResBlock, SpatialConv, Upsample,
    haar_patch, haar_unpatch,
)

TOKENIZER_SCHEMA_VERSION = 1


class TokenizerConfig(BaseModel):
    """Architecture of one tokenizer; its JSON is saved beside every checkpoint."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    schema_version: int = TOKENIZER_SCHEMA_VERSION
    name: str = "custom"
    variant: Literal["continuous", "discrete"] = "discrete"
    temporal_compression: int = Field(4, description="input frames per latent frame (after the first)")
    spatial_compression: int = Field(8, description="pixels per latent position along H and W")
    haar_temporal_levels: int = Field(2, ge=0, description="temporal Haar levels (each halves T)")
    haar_spatial_levels: int = Field(1, ge=0, description="spatial Haar levels (each halves H and W)")
    channels: tuple[int, ...] = Field((64, 96, 128), description="width per resolution level, finest first")
    res_blocks: int = Field(1, ge=1, description="residual blocks per level")
    attention_heads: int = 1
    latent_channels: int = Field(16, ge=1, description="continuous variant only")
    fsq_levels: tuple[int, ...] = Field((8, 5, 5, 5), description="discrete variant only")

    @model_validator(mode="after")
    def _consistent(self) -> "TokenizerConfig":
        for name, total, haar in (("temporal", self.temporal_compression, self.haar_temporal_levels),
                                  ("spatial", self.spatial_compression, self.haar_spatial_levels)):
            if total < 1 or total & (total - 1) or total < 2 ** haar:
                raise ValueError(f"{name}_compression must be a power of two >= 2^haar_{name}_levels")
        if len(self.channels) != self.spatial_stages + 1 or self.temporal_stages > self.spatial_stages:
            raise ValueError(f"channels needs {self.spatial_stages + 1} entries (one per resolution level), "
                             "and temporal downsampling stages may not outnumber spatial ones")
        return self

    @property
    def spatial_stages(self) -> int:
        return int(math.log2(self.spatial_compression)) - self.haar_spatial_levels

    @property
    def temporal_stages(self) -> int:
        return int(math.log2(self.temporal_compression)) - self.haar_temporal_levels

    @property
    def code_channels(self) -> int:
        return len(self.fsq_levels) if self.variant == "discrete" else self.latent_channels

    @property
    def codebook_size(self) -> int:
        return math.prod(self.fsq_levels)

    def latent_shape(self, frames: int, height: int, width: int) -> tuple[int, int, int]:
        """(T', H', W') of the latent grid for a clip of that size; refuses sizes that do not fit."""
        t, s = self.temporal_compression, self.spatial_compression
        if frames < 1 or (frames - 1) % t or height % s or width % s:
            raise ValueError(f"{frames}x{height}x{width}: need 1 + {t}k frames and sides divisible by {s}")
        return 1 + (frames - 1) // t, height // s, width // s

    def bits_per_pixel(self, frames: int, height: int, width: int, latent_bits: int = 8) -> float:
        """Discrete: log2(codebook) bits per token; continuous: latent_bits per latent value."""
        per_position = math.log2(self.codebook_size) if self.variant == "discrete" else latent_bits * self.latent_channels
        return math.prod(self.latent_shape(frames, height, width)) * per_position / (frames * height * width)


def _temporal_at(config: TokenizerConfig) -> list[bool]:
    """Which spatial stages also halve time: the coarsest ones (cheapest)."""
    n, k = config.spatial_stages, config.temporal_stages
    return [i >= n - k for i in range(n)]


class Encoder(nn.Module):
    """``B x 3 x T x H x W`` in [-1, 1] -> ``B x code_channels x T' x H' x W'`` (unbounded)."""

    def __init__(self, c: TokenizerConfig):
        super().__init__()
        self.c = c
        patched = 3 * 2 ** c.haar_temporal_levels * 4 ** c.haar_spatial_levels
        self.conv_in = SpatialConv(patched, c.channels[0])
        layers: list[nn.Module] = []
        temporal = _temporal_at(c)
        for i, width in enumerate(c.channels):
            layers += [ResBlock(width, width) for _ in range(c.res_blocks)]
            if i < c.spatial_stages:
                layers.append(Downsample(width, c.channels[i + 1], True, temporal[i]))
        self.down = nn.Sequential(*layers)
        top = c.channels[-1]
        self.mid = nn.Sequential(ResBlock(top, top), FrameAttention(top, c.attention_heads), ResBlock(top, top))
        self.norm_out = FrameNorm(top)
        self.conv_out = nn.Sequential(SpatialConv(top, c.code_channels), CausalTemporalConv(c.code_channels, c.code_channels))

    def hidden(self, x: torch.Tensor) -> torch.Tensor:
        """The last features before the projection to codes, ``B x channels[-1] x T' x H' x W'``
        (what a vision policy may read instead of the codes: models/vision_policy.py)."""
        h = haar_patch(x, self.c.haar_temporal_levels, self.c.haar_spatial_levels)
        return nn.functional.silu(self.norm_out(self.mid(self.down(self.conv_in(h)))))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv_out(self.hidden(x))


class Decoder(nn.Module):
    """``B x code_channels x T' x H' x W'`` -> ``B x 3 x T x H x W`` (about [-1, 1]; clamp for pixels)."""

    def __init__(self, c: TokenizerConfig):
        super().__init__()
        self.c = c
        top = c.channels[-1]
        self.conv_in = nn.Sequential(CausalTemporalConv(c.code_channels, c.code_channels), SpatialConv(c.code_channels, top))
        self.mid = nn.Sequential(ResBlock(top, top), FrameAttention(top, c.attention_heads), ResBlock(top, top))
        layers: list[nn.Module] = []
        temporal = _temporal_at(c)
        for i in reversed(range(len(c.channels))):
            width = c.channels[i]
            layers += [ResBlock(width, width) for _ in range(c.res_blocks)]
            if i > 0:
                layers.append(Upsample(width, c.channels[i - 1], True, temporal[i - 1]))
        self.up = nn.Sequential(*layers)
        self.norm_out = FrameNorm(c.channels[0])
        patched = 3 * 2 ** c.haar_temporal_levels * 4 ** c.haar_spatial_levels
        self.conv_out = SpatialConv(c.channels[0], patched)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        h = self.up(self.mid(self.conv_in(z)))
        h = self.conv_out(nn.functional.silu(self.norm_out(h)))
        return haar_unpatch(h, self.c.haar_temporal_levels, self.c.haar_spatial_levels)


class VideoTokenizer(nn.Module):
    """Encoder, bottleneck (tanh-bounded latents or FSQ) and decoder.

    ``encode``: video ``B x 3 x T x H x W`` in [-1, 1] -> continuous latents ``B x C x T' x H'
    x W'`` in [-1, 1], or discrete codes ``B x T' x H' x W'`` int64 in [0, codebook_size).
    ``decode`` inverts it; ``forward`` returns the reconstruction and the bottleneck values.
    """

    def __init__(self, config: TokenizerConfig):
        super().__init__()
        self.config = config
        self.encoder = Encoder(config)
        self.decoder = Decoder(config)
        self.fsq = FSQ(config.fsq_levels) if config.variant == "discrete" else None

    def _bottleneck(self, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        if self.fsq is not None:
            return self.fsq(h)
        return torch.tanh(h), None

    def forward(self, x: torch.Tensor, latent_noise: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
        """Reconstruction ``B x 3 x T x H x W`` and bottleneck values ``B x C x T' x H' x W'`` in [-1, 1].

        ``latent_noise`` adds uniform noise of that half-width to continuous latents (training
        them to survive 8-bit storage: a half-width of 1/255 is one quantisation step).
        """
        z, _ = self._bottleneck(self.encoder(x))
        zin = z + (torch.rand_like(z) * 2 - 1) * latent_noise if latent_noise and self.fsq is None else z
        return self.decoder(zin), z

    def _device(self) -> torch.device:
        return next(self.parameters()).device

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """Codes (discrete) or latents of video ``B x 3 x T x H x W``, on the input's device
        (computed on the model's)."""
        z, codes = self._bottleneck(self.encoder(x.to(self._device())))
        return (codes if codes is not None else z).to(x.device)

    def decode(self, latents: torch.Tensor) -> torch.Tensor:
        """Video from codes or latents, on the input's device (computed on the model's)."""
        where = latents.device
        latents = latents.to(self._device())
        if self.fsq is not None:
            latents = self.fsq.from_codes(latents)
        return self.decoder(latents).to(where)


_BASE = dict(haar_temporal_levels=2, haar_spatial_levels=1)
PRESETS: dict[str, TokenizerConfig] = {
    # Tests and smoke runs: trains for a few steps in seconds.
    "tiny-dv4x8x8": TokenizerConfig(name="tiny-dv4x8x8", variant="discrete", channels=(16, 24, 32), **_BASE),
    "tiny-cv4x8x8": TokenizerConfig(name="tiny-cv4x8x8", variant="continuous", channels=(16, 24, 32), **_BASE),
    "tiny-dv8x8x8": TokenizerConfig(name="tiny-dv8x8x8", variant="discrete", temporal_compression=8,
                                    channels=(16, 24, 32), **_BASE),
    "tiny-cv8x8x8": TokenizerConfig(name="tiny-cv8x8x8", variant="continuous", temporal_compression=8,
                                    channels=(16, 24, 32), **_BASE),
    # The bench's models, sized for a shared 2-core CPU (about 0.9M parameters).
    "small-dv4x8x8": TokenizerConfig(name="small-dv4x8x8", variant="discrete", channels=(32, 48, 64), **_BASE),
    "small-cv4x8x8": TokenizerConfig(name="small-cv4x8x8", variant="continuous", channels=(32, 48, 64), **_BASE),
    "small-dv8x8x8": TokenizerConfig(name="small-dv8x8x8", variant="discrete", temporal_compression=8,
                                     channels=(32, 48, 64), **_BASE),
    "small-cv8x8x8": TokenizerConfig(name="small-cv8x8x8", variant="continuous", temporal_compression=8,
                                     channels=(32, 48, 64), **_BASE),
    # For world models that must see small objects: 4x less spatial compression (a 5 px
    # package at 64 x 64 spans a latent cell or two, where 8x8 blurs it away), 4x the bits.
    "small-dv4x4x4": TokenizerConfig(name="small-dv4x4x4", variant="discrete", spatial_compression=4,
                                     channels=(32, 64), **_BASE),
    # Its continuous twin, for the diffusion world model on the same 4x4 latent grid.
    "small-cv4x4x4": TokenizerConfig(name="small-cv4x4x4", variant="continuous", spatial_compression=4,
                                     channels=(32, 64), **_BASE),
}


def preset(name: str) -> TokenizerConfig:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown tokenizer preset {name!r}; known: {', '.join(sorted(PRESETS))}") from None

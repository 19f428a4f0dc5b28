"""Building blocks of the causal video tokenizer (models/tokenizer.py).

Every block keeps the time axis causal: output frame t depends on input frames <= t only.
Temporal convolutions pad on the left by repeating the first frame and normalisation is per
frame, as in the Cosmos Tokenizer (NVIDIA, 2025, arXiv:2501.03575), whose factorised
residual blocks (a spatial 1x3x3 convolution, then a causal temporal 3x1x1 one) these follow.
Layouts are ``B x C x T x H x W`` throughout.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

_SQRT2 = math.sqrt(2.0)


# --- Haar wavelet patching ---------------------------------------------------------------

def _haar_axis(x: torch.Tensor, dim: int) -> torch.Tensor:
    """One orthonormal Haar level along ``dim`` (even length): halves it, doubles channels.

    (Cosmos rescales to averages instead; on a 50-step overfit of one clip both reached the
    same PSNR, 13.7 dB, so the orthonormal form, which the bench's checkpoints use, stays.)
    """
    even, odd = x.narrow(dim, 0, x.shape[dim] // 2 * 2).unflatten(dim, (-1, 2)).unbind(dim + 1)
    return torch.cat([(even + odd) / _SQRT2, (even - odd) / _SQRT2], dim=1)


def _ihaar_axis(x: torch.Tensor, dim: int) -> torch.Tensor:
    low, high = x.chunk(2, dim=1)
    return torch.stack([(low + high) / _SQRT2, (low - high) / _SQRT2], dim=dim + 1).flatten(dim, dim + 1)


def haar_patch(x: torch.Tensor, temporal_levels: int, spatial_levels: int) -> torch.Tensor:
    """Wavelet-packet Haar transform: ``B x C x (1 + 2^lt k) x H x W`` -> ``B x C 2^lt 4^ls x (1 + k) x H/2^ls x W/2^ls``.

    The first frame is repeated 2^lt - 1 times in front, so the first output frame is made
    of the first input frame alone (Cosmos' causal patcher). Orthonormal, so exactly invertible.
    """
    if temporal_levels:
        x = torch.cat([x[:, :, :1].expand(-1, -1, 2 ** temporal_levels - 1, -1, -1), x], dim=2)
    for _ in range(spatial_levels):
        x = _haar_axis(_haar_axis(x, 3), 4)
    for _ in range(temporal_levels):
        x = _haar_axis(x, 2)
    return x


def haar_unpatch(x: torch.Tensor, temporal_levels: int, spatial_levels: int) -> torch.Tensor:
    """Inverse of ``haar_patch``; drops the repeated copies of the first frame."""
    for _ in range(temporal_levels):
        x = _ihaar_axis(x, 2)
    for _ in range(spatial_levels):
        x = _ihaar_axis(_ihaar_axis(x, 4), 3)
    return x[:, :, 2 ** temporal_levels - 1:] if temporal_levels else x


# --- causal convolutions -----------------------------------------------------------------

class SpatialConv(nn.Module):
    """A 2D convolution applied to every frame (run as Conv2d on ``(B T) x C x H x W``, faster on CPU)."""

    def __init__(self, cin: int, cout: int, kernel: int = 3, stride: int = 1):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, kernel, stride=stride, padding=kernel // 2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, _, t, _, _ = x.shape
        y = self.conv(x.transpose(1, 2).flatten(0, 1))
        return y.unflatten(0, (b, t)).transpose(1, 2)


class CausalTemporalConv(nn.Module):
    """A temporal convolution padded on the left with copies of the first frame.

    With stride 2, ``1 + 2m`` frames give ``1 + m``; output frame j sees input frames <= 2j.
    """

    def __init__(self, cin: int, cout: int, kernel: int = 3, stride: int = 1):
        super().__init__()
        self.pad, self.stride = kernel - 1, stride
        self.conv = nn.Conv3d(cin, cout, (kernel, 1, 1), stride=(stride, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.pad:
            x = torch.cat([x[:, :, :1].expand(-1, -1, self.pad, -1, -1), x], dim=2)
        return self.conv(x)


class FrameNorm(nn.Module):
    """GroupNorm over each frame separately (a norm over time would leak the future)."""

    def __init__(self, channels: int, groups: int = 8):
        super().__init__()
        self.norm = nn.GroupNorm(math.gcd(groups, channels), channels, eps=1e-6)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, _, t, _, _ = x.shape
        return self.norm(x.transpose(1, 2).flatten(0, 1)).unflatten(0, (b, t)).transpose(1, 2)


class ResBlock(nn.Module):
    """Pre-norm residual block of two factorised causal convolutions (3x3 spatial, 3 causal temporal)."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.norm1, self.norm2 = FrameNorm(cin), FrameNorm(cout)
        self.conv1 = nn.Sequential(SpatialConv(cin, cout), CausalTemporalConv(cout, cout))
        self.conv2 = nn.Sequential(SpatialConv(cout, cout), CausalTemporalConv(cout, cout))
        self.skip = SpatialConv(cin, cout, 1) if cin != cout else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.conv1(F.silu(self.norm1(x)))
        h = self.conv2(F.silu(self.norm2(h)))
        return self.skip(x) + h


class FrameAttention(nn.Module):
    """Self-attention over the positions of each frame (causal by construction)."""

    def __init__(self, channels: int, heads: int = 1):
        super().__init__()
        self.heads = heads
        self.norm = FrameNorm(channels)
        self.qkv = nn.Linear(channels, 3 * channels)
        self.proj = nn.Linear(channels, channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, c, t, h, w = x.shape
        seq = self.norm(x).permute(0, 2, 3, 4, 1).reshape(b * t, h * w, c)
        q, k, v = self.qkv(seq).unflatten(-1, (3, self.heads, c // self.heads)).permute(2, 0, 3, 1, 4)
        out = F.scaled_dot_product_attention(q, k, v).transpose(1, 2).reshape(b * t, h * w, c)
        return x + self.proj(out).reshape(b, t, h, w, c).permute(0, 4, 1, 2, 3)


class Downsample(nn.Module):
    """Halve H and W (strided 3x3) and/or T (strided causal conv: 1 + 2m -> 1 + m frames)."""

    def __init__(self, cin: int, cout: int, spatial: bool, temporal: bool):
        super().__init__()
        self.spatial = SpatialConv(cin, cout, 3, stride=2 if spatial else 1)
        self.temporal = CausalTemporalConv(cout, cout, 3, stride=2) if temporal else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.temporal(self.spatial(x))


class Upsample(nn.Module):
    """Double H and W (nearest, then 3x3) and/or T (1 + m -> 1 + 2m: each frame twice, the first once)."""

    def __init__(self, cin: int, cout: int, spatial: bool, temporal: bool):
        super().__init__()
        self.up_spatial, self.up_temporal = spatial, temporal
        self.spatial = SpatialConv(cin, cout, 3)
        self.temporal = CausalTemporalConv(cout, cout, 3) if temporal else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.up_temporal:
            x = x.repeat_interleave(2, dim=2)[:, :, 1:]
        if self.up_spatial:
            x = F.interpolate(x, scale_factor=(1, 2, 2), mode="nearest")
        return self.temporal(self.spatial(x))


# --- finite scalar quantisation ----------------------------------------------------------

class FSQ(nn.Module):
    """Finite scalar quantisation (Mentzer et al. 2023, arXiv:2309.15505).

    Each of the ``len(levels)`` channels is bounded with tanh and rounded to ``levels[i]``
    values (straight-through gradient); the codebook is their product. ``forward`` takes
    ``B x d x ...`` and returns the quantised values in [-1, 1] (same layout) and the integer
    codes ``B x ...`` in [0, prod(levels)).
    """

    def __init__(self, levels: tuple[int, ...], eps: float = 1e-3):
        super().__init__()
        lv = torch.tensor(levels, dtype=torch.float64)
        self.register_buffer("levels", lv.float(), persistent=False)
        self.register_buffer("half_l", ((lv - 1) * (1 + eps) / 2).float(), persistent=False)
        offset = torch.where(lv % 2 == 1, 0.0, 0.5)
        self.register_buffer("offset", offset.float(), persistent=False)
        self.register_buffer("shift", torch.atanh(offset / ((lv - 1) * (1 + eps) / 2)).float(), persistent=False)
        self.register_buffer("half_width", torch.div(lv, 2, rounding_mode="floor").float(), persistent=False)
        basis = torch.cumprod(torch.tensor((1,) + tuple(levels[:-1]), dtype=torch.int64), 0)
        self.register_buffer("basis", basis, persistent=False)
        self.codebook_size = int(math.prod(levels))

    def _view(self, t: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
        return t.view(1, -1, *([1] * (like.dim() - 2)))

    def forward(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        v = lambda t: self._view(t, z)  # noqa: E731
        bounded = torch.tanh(z + v(self.shift)) * v(self.half_l) - v(self.offset)
        rounded = bounded + (torch.round(bounded) - bounded).detach()
        zq = rounded / v(self.half_width)
        return zq, self.codes(zq)

    def codes(self, zq: torch.Tensor) -> torch.Tensor:
        ints = torch.round(zq * self._view(self.half_width, zq) + self._view(self.half_width, zq)).long()
        return (ints * self._view(self.basis, zq)).sum(1)

    def from_codes(self, codes: torch.Tensor) -> torch.Tensor:
        """``B x ...`` int codes -> ``B x d x ...`` values in [-1, 1]."""
        lv = self.levels.long()
        digits = torch.stack([(codes // b) % n for b, n in zip(self.basis.tolist(), lv.tolist())], dim=1)
        return (digits.float() - self._view(self.half_width, digits)) / self._view(self.half_width, digits)

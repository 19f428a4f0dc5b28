"""Tileable fractal textures and material colouring for procedural footage.

Fields are H x W float32 in [0, 1] and wrap at their edges (sampled with BORDER_WRAP, a camera
can travel forever without a seam); textures are H x W x 4 uint8 RGBA.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

# Colour stops (position in [0, 1], RGB) per material; the height field indexes them.
MATERIALS: dict[str, tuple[tuple[float, tuple[int, int, int]], ...]] = {
    "alpine": ((0.0, (46, 74, 40)), (0.45, (86, 112, 60)), (0.7, (118, 112, 100)), (0.9, (160, 158, 152)),
               (1.0, (206, 208, 212))),
    "meadow": ((0.0, (58, 92, 34)), (0.4, (96, 138, 52)), (0.75, (140, 160, 70)), (1.0, (176, 170, 96))),
    "desert": ((0.0, (150, 104, 62)), (0.5, (196, 152, 98)), (0.8, (214, 178, 128)), (1.0, (170, 120, 80))),
    "forest": ((0.0, (22, 50, 26)), (0.5, (40, 82, 38)), (0.8, (70, 104, 48)), (1.0, (98, 112, 70))),
    "coast": ((0.0, (28, 64, 110)), (0.38, (52, 104, 140)), (0.45, (190, 176, 130)), (0.55, (112, 140, 70)),
              (1.0, (60, 96, 48))),
    "autumn": ((0.0, (92, 48, 24)), (0.4, (160, 86, 34)), (0.7, (186, 136, 52)), (1.0, (110, 90, 46))),
    "tundra": ((0.0, (84, 88, 70)), (0.5, (126, 122, 96)), (0.8, (150, 140, 118)), (1.0, (108, 104, 92))),
    "volcanic": ((0.0, (36, 32, 30)), (0.5, (74, 62, 56)), (0.8, (120, 76, 50)), (1.0, (150, 130, 110))),
    "farmland": ((0.0, (90, 120, 48)), (0.35, (150, 150, 70)), (0.6, (120, 92, 56)), (1.0, (176, 160, 90))),
    "oak": ((0.0, (104, 66, 36)), (0.5, (150, 104, 62)), (1.0, (188, 142, 92))),
    "walnut": ((0.0, (58, 36, 22)), (0.5, (96, 62, 38)), (1.0, (138, 96, 60))),
    "slate": ((0.0, (54, 60, 66)), (0.5, (90, 96, 104)), (1.0, (132, 136, 140))),
    "denim": ((0.0, (34, 52, 92)), (0.5, (58, 84, 130)), (1.0, (104, 130, 170))),
    "concrete": ((0.0, (100, 100, 96)), (0.5, (138, 136, 130)), (1.0, (170, 168, 160))),
}
TERRAINS = ("alpine", "meadow", "desert", "forest", "coast", "autumn", "tundra", "volcanic", "farmland")
SURFACES = ("oak", "walnut", "slate", "denim", "concrete")


def cell_size(width: int) -> int:
    """The coarsest noise wavelength for a frame `width` px wide (a power of two, 8..256)."""
    return int(2 ** min(8, max(3, round(math.log2(max(8, width / 5))))))


def round_up(value: float, multiple: int) -> int:
    return int(math.ceil(value / multiple) * multiple)


def _up2(field: np.ndarray) -> np.ndarray:
    # Pad by wrapping before the cubic upsample so the result still tiles.
    padded = np.pad(field, 2, mode="wrap")
    return cv2.resize(padded, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)[4:-4, 4:-4]


def fractal(height: int, width: int, seed: int, coarse: int, persistence: float = 0.5, fine: int = 1) -> np.ndarray:
    """H x W float32 in [0, 1]: octave noise from `coarse` px wavelength down to `fine` px, tileable.

    height and width must be multiples of `coarse`; persistence is the amplitude ratio per octave.
    """
    if height % coarse or width % coarse:
        raise ValueError(f"fractal: size {height}x{width} is not a multiple of the cell {coarse}")
    rng = np.random.default_rng([seed, 0xF1])
    field = rng.random((height // coarse, width // coarse), dtype=np.float32)
    cell, amp = coarse, 1.0
    while cell > fine:
        field = _up2(field)
        cell //= 2
        amp *= persistence
        field += amp * (rng.random(field.shape, dtype=np.float32) - 0.5) * 2.0
    while cell > 1:
        field = _up2(field)
        cell //= 2
    low, high = np.percentile(field, (0.5, 99.5))
    return np.clip((field - low) / max(high - low, 1e-6), 0.0, 1.0).astype(np.float32)


def lut(material: str, hue_jitter: float = 0.0) -> np.ndarray:
    """256 x 3 float32 RGB colour ramp of a material, optionally tinted."""
    stops = MATERIALS[material]
    xs = np.array([p for p, _ in stops], dtype=np.float32)
    cols = np.array([c for _, c in stops], dtype=np.float32)
    grid = np.linspace(0.0, 1.0, 256, dtype=np.float32)
    ramp = np.stack([np.interp(grid, xs, cols[:, k]) for k in range(3)], axis=1)
    tint = np.array([1.0 + hue_jitter, 1.0, 1.0 - hue_jitter], dtype=np.float32)
    return np.clip(ramp * tint, 0, 255).astype(np.float32)


def shade(height_field: np.ndarray, light: tuple[float, float], strength: float) -> np.ndarray:
    """H x W float32 multiplicative hill shading from the wrapped gradient of a height field."""
    gx = np.roll(height_field, -1, axis=1) - np.roll(height_field, 1, axis=1)
    gy = np.roll(height_field, -1, axis=0) - np.roll(height_field, 1, axis=0)
    return np.clip(1.0 + strength * (gx * light[0] + gy * light[1]), 0.4, 1.6)


def colourise(height_field: np.ndarray, detail: np.ndarray, ramp: np.ndarray, shading: np.ndarray,
              gain: float, detail_amount: float = 0.35) -> np.ndarray:
    """H x W x 4 uint8 RGBA (alpha 255): ramp[height] modulated by fine detail, shading and gain."""
    index = np.clip(height_field * 255.0, 0, 255).astype(np.uint8)
    rgb = ramp[index]
    factor = (1.0 - detail_amount + 2.0 * detail_amount * detail) * shading * gain
    rgb *= factor[..., None]
    out = np.empty(height_field.shape + (4,), dtype=np.uint8)
    out[..., :3] = np.clip(rgb, 0, 255)
    out[..., 3] = 255
    return out


def wood(height: int, width: int, seed: int, coarse: int) -> np.ndarray:
    """H x W float32 in [0, 1]: wavy growth rings along x, tileable (ring count is whole)."""
    warp = fractal(height, width, seed, coarse, 0.55)
    rows = np.arange(height, dtype=np.float32)[:, None] / height
    rings = max(4, height // max(8, coarse // 4))
    phase = 2 * np.pi * rings * rows + 5.0 * warp
    return (0.5 + 0.5 * np.sin(phase)).astype(np.float32) ** 1.5

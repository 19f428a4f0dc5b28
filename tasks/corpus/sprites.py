"""Shaded object sprites (RGBA) and sub-pixel compositing onto frames.

Sprites are h x w x 4 uint8 RGBA with premultiplication left out (alpha is coverage);
frames are H x W x C uint8 with C >= 3 (RGB first).
"""

from __future__ import annotations

import math

import cv2
import numpy as np


def _rgba(rgb: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    out = np.empty(alpha.shape + (4,), dtype=np.uint8)
    out[..., :3] = np.clip(rgb, 0, 255)
    out[..., 3] = np.clip(alpha * 255.0, 0, 255)
    return out


def sphere(radius: float, colour: tuple[int, int, int], light: tuple[float, float]) -> np.ndarray:
    """A Lambert-plus-specular shaded ball with an antialiased rim."""
    r = max(1.5, radius)
    size = int(math.ceil(2 * r + 2))
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    x, y = (xx + 0.5 - size / 2) / r, (yy + 0.5 - size / 2) / r
    d2 = x * x + y * y
    z = np.sqrt(np.clip(1.0 - d2, 0.0, 1.0))
    lx, ly = light
    lz = math.sqrt(max(0.0, 1.0 - lx * lx - ly * ly))
    lambert = np.clip(x * lx + y * ly + z * lz, 0.0, 1.0)
    spec = np.clip(x * lx + y * ly + z * lz, 0.0, 1.0) ** 24
    rgb = np.array(colour, np.float32) * (0.25 + 0.85 * lambert)[..., None] + 200.0 * spec[..., None]
    alpha = np.clip((1.0 - np.sqrt(d2)) * r + 0.5, 0.0, 1.0)
    return _rgba(rgb, alpha)


def box(width: float, height: float, colour: tuple[int, int, int], light: tuple[float, float],
        windows: bool = False) -> np.ndarray:
    """A top-down box (a vehicle roof or a crate): bevelled edges lit from `light`."""
    w, h = max(3, int(round(width))), max(3, int(round(height)))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    bevel = max(1.0, 0.18 * min(w, h))
    # Each bevel faces outwards; its brightness follows the light direction.
    nx = np.where(xx < bevel, -1.0, np.where(xx > w - 1 - bevel, 1.0, 0.0))
    ny = np.where(yy < bevel, -1.0, np.where(yy > h - 1 - bevel, 1.0, 0.0))
    facing = 0.75 + 0.35 * (nx * light[0] + ny * light[1])
    rgb = np.array(colour, np.float32) * facing[..., None]
    if windows:
        glass = (np.abs(xx - w / 2) < 0.28 * w) & (np.abs(yy - h / 2) < 0.32 * h) & (np.abs(xx - w * 0.5) > 0.05 * w)
        rgb[glass] = rgb[glass] * 0.35 + np.array([20, 30, 40], np.float32)
    alpha = np.ones((h, w), np.float32)
    return _rgba(rgb, alpha)


def vehicle_side(length: float, colour: tuple[int, int, int], light_y: float) -> np.ndarray:
    """A side view of a small vehicle: body, cabin and two dark wheels, shaded top to bottom."""
    ln = max(6, int(round(length)))
    h = max(4, int(round(0.5 * ln)))
    canvas = np.zeros((h, ln, 4), np.uint8)
    body = tuple(int(c) for c in colour) + (255,)
    cv2.rectangle(canvas, (0, int(0.35 * h)), (ln - 1, int(0.8 * h)), body, -1, cv2.LINE_AA)
    cabin = (int(0.25 * ln), int(0.05 * h)), (int(0.7 * ln), int(0.4 * h))
    cv2.rectangle(canvas, cabin[0], cabin[1], tuple(int(0.8 * c) for c in colour) + (255,), -1, cv2.LINE_AA)
    for cx in (0.22, 0.78):
        cv2.circle(canvas, (int(cx * ln), int(0.8 * h)), max(1, int(0.18 * h)), (20, 20, 22, 255), -1, cv2.LINE_AA)
    ramp = np.linspace(1.15, 0.7, h, dtype=np.float32)[:, None, None] * (1.0 + 0.1 * light_y)
    canvas[..., :3] = np.clip(canvas[..., :3] * ramp, 0, 255)
    return canvas


def shadow(rx: float, ry: float, strength: float) -> np.ndarray:
    """A soft elliptical shadow: black with Gaussian-edged alpha up to `strength`."""
    w, h = int(math.ceil(2.6 * max(rx, 1))), int(math.ceil(2.6 * max(ry, 1)))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    d = ((xx + 0.5 - w / 2) / max(rx, 1)) ** 2 + ((yy + 0.5 - h / 2) / max(ry, 1)) ** 2
    alpha = strength * np.exp(-1.6 * d ** 2)
    return _rgba(np.zeros((h, w, 3), np.float32), alpha)


def paste(frame: np.ndarray, sprite: np.ndarray, cx: float, cy: float, angle_deg: float = 0.0,
          scale: float = 1.0) -> None:
    """Alpha-composite `sprite` centred at (cx, cy), rotated and scaled, in place; clipped to the frame."""
    sh, sw = sprite.shape[:2]
    reach = 0.5 * math.hypot(sw, sh) * scale + 2
    fh, fw = frame.shape[:2]
    x0, y0 = max(0, int(math.floor(cx - reach))), max(0, int(math.floor(cy - reach)))
    x1, y1 = min(fw, int(math.ceil(cx + reach))), min(fh, int(math.ceil(cy + reach)))
    if x1 <= x0 or y1 <= y0:
        return
    m = cv2.getRotationMatrix2D((sw / 2, sh / 2), angle_deg, scale)
    m[0, 2] += cx - sw / 2 - x0
    m[1, 2] += cy - sh / 2 - y0
    patch = cv2.warpAffine(sprite, m, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0))
    alpha = patch[..., 3:4].astype(np.float32) * (1.0 / 255.0)
    roi = frame[y0:y1, x0:x1, :3]
    roi[:] = (roi * (1.0 - alpha) + patch[..., :3] * alpha + 0.5).astype(np.uint8)

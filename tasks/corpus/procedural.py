"""Procedural physical-looking footage: textured terrain seen by a smoothly moving camera.

Three families, each a pure function of (content seed, frame size, frame index t):
- landscape: side view, sky and three ridge layers with parallax, horizontal pan, slow zoom;
- aerial: top-down terrain with roads and vehicles, the camera translating, turning, zooming;
- tabletop: a close view of a wood, stone or fabric surface with balls and crates moving on it.
Any integer t works, negative included (transitions borrow frames either side of a segment).
Frames are H x W x 3 uint8 RGB.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from tasks.corpus import sprites
from tasks.corpus.textures import SURFACES, TERRAINS, cell_size, colourise, fractal, lut, round_up, shade, wood

FAMILIES = ("landscape", "landscape", "aerial", "tabletop")


@dataclass(frozen=True)
class SceneParams:
    family: str
    materials: tuple[str, ...]
    speed: float  # camera speed, px per frame on a 1280 px wide frame
    heading: float  # radians; for a landscape only its sign matters
    zoom_rate: float  # log-zoom per frame
    spin: float  # radians per frame (aerial, tabletop)
    n_objects: int
    gain: float  # overall exposure of the scene, ~1
    sun: tuple[float, float]
    tint: float
    horizon: float  # landscape horizon height, fraction of the frame from the top


def scene_params(seed: int) -> SceneParams:
    """The scene's random choices, cheap to draw (no pixels)."""
    rng = np.random.default_rng([seed, 0x5C])
    family = FAMILIES[int(rng.integers(len(FAMILIES)))]
    if family == "tabletop":
        materials = (SURFACES[int(rng.integers(len(SURFACES)))],)
    else:
        materials = tuple(TERRAINS[int(i)] for i in rng.choice(len(TERRAINS), size=3, replace=False))
    sun_angle = rng.uniform(0, 2 * math.pi)
    return SceneParams(
        family=family, materials=materials,
        speed=float(rng.uniform(1.2, 4.5) if family != "tabletop" else rng.uniform(0.8, 2.5)),
        heading=float(rng.uniform(0, 2 * math.pi)), zoom_rate=float(rng.uniform(-6e-4, 6e-4)),
        spin=float(rng.uniform(-1.2e-3, 1.2e-3)), n_objects=int(rng.integers(1, 5)),
        gain=float(rng.uniform(0.85, 1.2)), sun=(0.8 * math.cos(sun_angle), 0.8 * math.sin(sun_angle)),
        tint=float(rng.uniform(-0.06, 0.06)), horizon=float(rng.uniform(0.3, 0.5)))


def describe(seed: int) -> str:
    p = scene_params(seed)
    if p.family == "landscape":
        side = "left" if math.cos(p.heading) < 0 else "right"
        return f"landscape pan {side} over {p.materials[2]} hills below {p.materials[0]} peaks, {p.n_objects} moving objects"
    if p.family == "aerial":
        return f"aerial drift over {p.materials[0]} terrain with roads, {p.n_objects} vehicles"
    return f"tabletop dolly over {p.materials[0]} surface, {p.n_objects} moving objects"


def _zoom(p: SceneParams, t: float) -> float:
    return float(np.clip(math.exp(p.zoom_rate * t), 0.8, 1.5))


def _colours(rng: np.random.Generator, n: int) -> list[tuple[int, int, int]]:
    return [tuple(int(c) for c in rng.integers(30, 230, size=3)) for _ in range(n)]


class Landscape:
    """Sky + far, mid and near ridge layers (RGBA textures, Th x Tw, wrapping along x)."""

    FACTORS = (0.12, 0.4, 1.0)  # parallax: how far each layer moves relative to the near ground

    def __init__(self, p: SceneParams, seed: int, width: int, height: int):
        self.p, self.w, self.h, self.s = p, width, height, width / 1280.0
        c = cell_size(width)
        self.tw, self.th = round_up(2 * width, c), round_up(1.6 * height, c)
        rng = np.random.default_rng([seed, 0x1A])
        rows = np.arange(self.th, dtype=np.float32)[:, None]
        hz = self.th / 2 + (p.horizon - 0.5) * height  # texture row seen at the horizon
        profile = fractal(c, self.tw, seed + 1, c, 0.55)  # rows of independent ridge profiles
        ridges = [hz - (0.08 + 0.1 * profile[0]) * height,
                  hz + 0.04 * height - 0.1 * profile[c // 3] * height,
                  hz + 0.17 * height - 0.07 * profile[2 * c // 3] * height]
        self.near_ridge = ridges[2]
        top = np.array(rng.uniform([40, 80, 150], [110, 150, 215]), np.float32)
        low = np.array(rng.uniform([170, 180, 190], [215, 220, 230]), np.float32)
        k = np.clip(rows / hz, 0, 1)[..., None]
        sky = np.broadcast_to(top * (1 - k) + low * k, (self.th, self.tw, 3)).copy()
        cloud = np.clip((fractal(self.th, self.tw, seed + 2, c, 0.55) - 0.5) * 2.5, 0, 1)[..., None]
        sky = sky * (1 - 0.8 * cloud) + 235.0 * 0.8 * cloud
        self.layers = []
        for i, (ridge, haze) in enumerate(zip(ridges, (0.45, 0.2, 0.0))):
            heightf = fractal(self.th, self.tw, seed + 10 + i, c, 0.5)
            detail = fractal(self.th, self.tw, seed + 20 + i, max(4, c // 8), 0.7)
            rgba = colourise(heightf, detail, lut(p.materials[i], p.tint), shade(heightf, p.sun, 6.0 + 4 * i), p.gain)
            rgb = rgba[..., :3].astype(np.float32) * (1 - haze) + low * haze
            alpha = np.clip(rows - ridge[None, :] + 0.5, 0, 1)
            if i == 0:  # the far layer is opaque: sky behind the far ridge
                rgb = sky * (1 - alpha[..., None]) + rgb * alpha[..., None]
                alpha = np.ones_like(alpha)
            rgba[..., :3] = np.clip(rgb, 0, 255)
            rgba[..., 3] = (alpha * 255).astype(np.uint8)
            self.layers.append(rgba)
        self.objects = []
        for colour in _colours(rng, p.n_objects):
            kind = "vehicle" if rng.random() < 0.5 else "ball"
            size = rng.uniform(40, 90) * self.s
            sprite = (sprites.vehicle_side(size, colour, p.sun[1]) if kind == "vehicle"
                      else sprites.sphere(size / 2, colour, (p.sun[0] * 0.6, -0.5)))
            self.objects.append((sprite, rng.uniform(0, self.tw), rng.uniform(-3, 3) * self.s,
                                 rng.uniform(0.1, 0.6), size))
        self.shadow = sprites.shadow(30 * self.s, 7 * self.s, 0.5)
        phase = rng.uniform(0, 2 * math.pi, size=2)
        self.phase, self.bob = phase, rng.uniform(1, 5) * self.s

    def camera(self, t: float) -> tuple[float, float, float]:
        p = self.p
        v = math.copysign(p.speed * self.s, math.cos(p.heading))
        period = 150.0  # frames: the operator's pace breathes a little
        x = v * (t + 0.25 * period / (2 * math.pi) * (math.cos(self.phase[0]) - math.cos(2 * math.pi * t / period + self.phase[0])))
        y = self.bob * math.sin(2 * math.pi * t / 110.0 + self.phase[1])
        return x, y, _zoom(p, t)

    def frame(self, t: int) -> np.ndarray:
        x, y, z = self.camera(t)
        out = None
        for layer, f in zip(self.layers, self.FACTORS):
            zl = 1 + (z - 1) * f
            cx = (self.tw / 2 + x * f) % self.tw
            cy = self.th / 2 + y * f
            m = np.float32([[1 / zl, 0, cx - self.w / 2 / zl], [0, 1 / zl, cy - self.h / 2 / zl]])
            warped = cv2.warpAffine(layer, m, (self.w, self.h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                    borderMode=cv2.BORDER_WRAP)
            if out is None:
                out = warped
            else:
                cv2.copyTo(warped, cv2.extractChannel(warped, 3), out)
            if f == 1.0:
                self._objects(out, t, cx, cy, zl)
        return cv2.cvtColor(out, cv2.COLOR_RGBA2RGB)

    def _objects(self, out: np.ndarray, t: int, cx: float, cy: float, z: float) -> None:
        for sprite, x0, v, depth, size in self.objects:
            xo = (x0 + v * t) % self.tw
            ridge = self.near_ridge[int(xo) % self.tw]
            yo = ridge + depth * (self.th - ridge) * 0.5
            dx = (xo - cx + self.tw / 2) % self.tw - self.tw / 2
            u, w = dx * z + self.w / 2, (yo - cy) * z + self.h / 2
            scale = z * (0.7 + depth)
            sprites.paste(out, self.shadow, u, w, scale=scale * size / (60 * self.s))
            sprites.paste(out, sprite, u, w - 0.5 * sprite.shape[0] * scale, scale=scale)


@dataclass(frozen=True)
class _Mover:
    """An object on the ground: straight-line motion, or along a road (x advances, y follows it)."""

    sprite: np.ndarray
    x0: float
    y0: float
    vx: float
    vy: float
    road: tuple[float, float, float, int] | None

    def position(self, t: float, road_y) -> tuple[float, float, float]:
        x = self.x0 + self.vx * t
        if self.road is None:
            return x, self.y0 + self.vy * t, math.atan2(self.vy, self.vx)
        y = float(road_y(self.road, x))
        slope = float(road_y(self.road, x + 1.0)) - y
        return x, y, math.atan2(slope, 1.0) + (math.pi if self.vx < 0 else 0.0)


class Overhead:
    """Aerial terrain or a tabletop surface under a camera that translates, turns and zooms."""

    def __init__(self, p: SceneParams, seed: int, width: int, height: int):
        self.p, self.w, self.h, self.s = p, width, height, width / 1280.0
        c = cell_size(width)
        self.n = n = round_up(1.6 * max(width, height), c)
        rng = np.random.default_rng([seed, 0x0A])
        material = p.materials[0]
        heightf = wood(n, n, seed + 3, c) if material in ("oak", "walnut") else fractal(n, n, seed + 3, c, 0.5)
        detail = fractal(n, n, seed + 4, max(4, c // 8), 0.7)
        self.tex = colourise(heightf, detail, lut(material, p.tint), shade(heightf, p.sun, 8.0), p.gain)
        self.roads: list[tuple[float, float, float, int]] = []
        self.movers: list[_Mover] = []
        colours = _colours(rng, p.n_objects)
        if p.family == "aerial":
            for _ in range(int(rng.integers(1, 3))):
                road = (rng.uniform(0, n), rng.uniform(0.03, 0.12) * n, rng.uniform(0, 2 * math.pi), int(rng.integers(1, 3)))
                self.roads.append(road)
                self._draw_road(road, max(3, int(26 * self.s)))
            for colour in colours:
                road = self.roads[int(rng.integers(len(self.roads)))]
                sprite = sprites.box(44 * self.s, 22 * self.s, colour, p.sun, windows=True)
                speed = rng.uniform(1.0, 4.0) * self.s * rng.choice([-1, 1])
                self.movers.append(_Mover(sprite, rng.uniform(0, n), 0.0, speed, 0.0, road))
        else:
            for colour in colours:
                sprite = (sprites.sphere(rng.uniform(25, 60) * self.s, colour, p.sun) if rng.random() < 0.6
                          else sprites.box(rng.uniform(50, 110) * self.s, rng.uniform(50, 110) * self.s, colour, p.sun))
                angle, speed = rng.uniform(0, 2 * math.pi), rng.uniform(0.5, 3.0) * self.s
                self.movers.append(_Mover(sprite, rng.uniform(0, n), rng.uniform(0, n),
                                          speed * math.cos(angle), speed * math.sin(angle), None))
        self.shadow = sprites.shadow(16.0, 16.0, 0.45)
        self.c0 = rng.uniform(0, n, size=2)
        self.a0 = rng.uniform(0, 2 * math.pi)
        self.sway = (rng.uniform(5, 25) * self.s, rng.uniform(120, 300), rng.uniform(0, 2 * math.pi))

    def _road_y(self, road: tuple[float, float, float, int], x: np.ndarray | float):
        y0, amp, phase, k = road
        return y0 + amp * np.sin(2 * math.pi * k * np.asarray(x) / self.n + phase)

    def _draw_road(self, road, thickness: int) -> None:
        xs = np.arange(-self.n // 8, self.n + self.n // 8, max(2, self.n // 256), dtype=np.float64)
        pts = np.stack([xs, self._road_y(road, xs)], axis=1)
        for dy in (-self.n, 0, self.n):  # draw the wrapped copies so the texture still tiles
            shifted = (pts + [0, dy]).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(self.tex, [shifted], False, (70, 70, 74, 255), thickness, cv2.LINE_AA)
            cv2.polylines(self.tex, [shifted], False, (200, 196, 170, 255), max(1, thickness // 10), cv2.LINE_AA)

    def camera(self, t: float) -> tuple[float, float, float, float]:
        p = self.p
        amp, period, phase = self.sway
        along = p.speed * self.s * t
        side = amp * math.sin(2 * math.pi * t / period + phase)
        x = self.c0[0] + along * math.cos(p.heading) - side * math.sin(p.heading)
        y = self.c0[1] + along * math.sin(p.heading) + side * math.cos(p.heading)
        return x, y, self.a0 + p.spin * t, _zoom(p, t)

    def frame(self, t: int) -> np.ndarray:
        x, y, a, z = self.camera(t)
        ca, sa = math.cos(a) / z, math.sin(a) / z
        m = np.float32([[ca, -sa, x - ca * self.w / 2 + sa * self.h / 2],
                        [sa, ca, y - sa * self.w / 2 - ca * self.h / 2]])
        out = cv2.warpAffine(self.tex, m, (self.w, self.h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                             borderMode=cv2.BORDER_WRAP)
        for mover in self.movers:
            wx, wy, heading = mover.position(t, self._road_y)
            dx = (wx - x + self.n / 2) % self.n - self.n / 2
            dy = (wy - y + self.n / 2) % self.n - self.n / 2
            # world -> screen is the inverse rotation of the camera, then the zoom.
            u = self.w / 2 + z * (math.cos(a) * dx + math.sin(a) * dy)
            v = self.h / 2 + z * (-math.sin(a) * dx + math.cos(a) * dy)
            size = max(mover.sprite.shape[:2])
            sprites.paste(out, self.shadow, u + 6 * self.s * self.p.sun[0], v + 6 * self.s * self.p.sun[1],
                          scale=0.45 * size * z / 16.0)
            sprites.paste(out, mover.sprite, u, v, angle_deg=-math.degrees(heading - a), scale=z)
        return cv2.cvtColor(out, cv2.COLOR_RGBA2RGB)


def scene(seed: int, width: int, height: int) -> Landscape | Overhead:
    """Build the textures of content `seed` at this frame size; call `.frame(t)` for frames."""
    p = scene_params(seed)
    return Landscape(p, seed, width, height) if p.family == "landscape" else Overhead(p, seed, width, height)

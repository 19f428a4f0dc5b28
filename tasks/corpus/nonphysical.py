"""Non-physical footage: flat animation, presentation slides, test patterns. H x W x 3 uint8 RGB."""

from __future__ import annotations

import cv2
import numpy as np

KINDS = ("animation", "slides", "test_pattern")
BARS = [(192, 192, 192), (192, 192, 0), (0, 192, 192), (0, 192, 0), (192, 0, 192), (192, 0, 0), (0, 0, 192)]
WORDS = ("robot", "pipeline", "quarterly", "safety", "review", "warehouse", "budget", "roadmap", "metrics",
         "team", "sensor", "update", "launch", "goals", "summary", "design", "customer", "data")


def describe(kind: str, seed: int) -> str:
    return {"animation": "flat-shaded cartoon shapes", "slides": "presentation slides",
            "test_pattern": "colour bars test pattern"}[kind] + f" #{seed % 1000}"


class Animation:
    """Flat shapes bouncing on a flat background: no texture, no shading, no noise."""

    def __init__(self, seed: int, width: int, height: int):
        rng = np.random.default_rng([seed, 1])
        self.w, self.h = width, height
        self.background = tuple(int(v) for v in rng.integers(60, 230, 3))
        n = int(rng.integers(3, 7))
        self.shapes = [(int(rng.integers(0, 2)), rng.uniform(0.05, 0.15) * height,
                        tuple(int(v) for v in rng.integers(0, 256, 3)),
                        rng.uniform(0.1, 0.9, 2) * (width, height), rng.uniform(-0.01, 0.01, 2) * (width, height))
                       for _ in range(n)]

    def frame(self, i: int) -> np.ndarray:
        out = np.empty((self.h, self.w, 3), np.uint8)
        out[:] = self.background
        for circle, size, colour, start, velocity in self.shapes:
            pos = start + velocity * i
            span = np.array([self.w, self.h], float)
            pos = np.abs((pos % (2 * span)) - span)  # bounce off the edges
            x, y, r = int(pos[0]), int(pos[1]), max(2, int(size))
            if circle:
                cv2.circle(out, (x, y), r, colour, -1, lineType=cv2.LINE_8)
            else:
                cv2.rectangle(out, (x - r, y - r), (x + r, y + r), colour, -1)
        return out


class Slides:
    """A title and bullets on a flat background, the slide changing every few seconds."""

    def __init__(self, seed: int, width: int, height: int, fps: float):
        self.rng_seed, self.w, self.h = seed, width, height
        self.period = max(1, int(np.random.default_rng([seed, 2]).uniform(2.5, 5.0) * fps))
        self._cache: dict[int, np.ndarray] = {}

    def _slide(self, k: int) -> np.ndarray:
        rng = np.random.default_rng([self.rng_seed, 3, k])
        out = np.empty((self.h, self.w, 3), np.uint8)
        out[:] = (245, 245, 240) if rng.random() < 0.7 else tuple(int(v) for v in rng.integers(20, 80, 3))
        ink = (20, 20, 30) if out[0, 0, 0] > 128 else (235, 235, 235)
        scale = self.h / 480
        title = " ".join(rng.choice(WORDS, 3)).title()
        cv2.putText(out, title, (int(0.06 * self.w), int(0.16 * self.h)), cv2.FONT_HERSHEY_DUPLEX, 1.4 * scale, ink,
                    max(1, int(2 * scale)), cv2.LINE_AA)
        cv2.line(out, (int(0.06 * self.w), int(0.2 * self.h)), (int(0.94 * self.w), int(0.2 * self.h)), ink,
                 max(1, int(2 * scale)))
        for j in range(int(rng.integers(3, 6))):
            y = int((0.32 + 0.12 * j) * self.h)
            cv2.circle(out, (int(0.08 * self.w), y - int(8 * scale)), max(2, int(5 * scale)), ink, -1)
            cv2.putText(out, " ".join(rng.choice(WORDS, int(rng.integers(3, 6)))), (int(0.11 * self.w), y),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.9 * scale, ink, max(1, int(2 * scale)), cv2.LINE_AA)
        return out

    def frame(self, i: int) -> np.ndarray:
        k = i // self.period
        if k not in self._cache:
            self._cache = {k: self._slide(k)}
        return self._cache[k].copy()


class TestPattern:
    """SMPTE-like colour bars with a running frame counter."""

    def __init__(self, seed: int, width: int, height: int):
        self.w, self.h = width, height
        self.base = np.zeros((height, width, 3), np.uint8)
        order = np.random.default_rng([seed, 4]).permutation(len(BARS)) if seed % 2 else np.arange(len(BARS))
        edges = np.linspace(0, width, len(BARS) + 1).astype(int)
        for j, b in enumerate(order):
            self.base[: int(0.7 * height), edges[j]:edges[j + 1]] = BARS[b]
        ramp = np.linspace(0, 255, width).astype(np.uint8)
        self.base[int(0.7 * height): int(0.8 * height)] = ramp[None, :, None]
        self.base[int(0.8 * height):] = (16, 16, 16)

    def frame(self, i: int) -> np.ndarray:
        out = self.base.copy()
        scale = self.h / 480
        cv2.putText(out, f"{i // 3600:02d}:{i // 60 % 60:02d}:{i % 60:02d}", (int(0.35 * self.w), int(0.93 * self.h)),
                    cv2.FONT_HERSHEY_SIMPLEX, 1.2 * scale, (235, 235, 235), max(1, int(2 * scale)), cv2.LINE_AA)
        return out


def source(kind: str, seed: int, width: int, height: int, fps: float):
    if kind == "animation":
        return Animation(seed, width, height)
    if kind == "slides":
        return Slides(seed, width, height, fps)
    return TestPattern(seed, width, height)

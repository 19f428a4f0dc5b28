"""Defects and duplicate transforms, applied frame by frame to clean footage (H x W x 3 uint8 RGB)."""

from __future__ import annotations

import cv2
import numpy as np

SUBTITLES = ("Where are we going tonight?", "Keep the doors closed.", "I told you, it is not here.",
             "Move the boxes to aisle four.", "We start again at dawn.", "Did you hear that?",
             "Nobody leaves this room.", "The shipment is late again.")


def _font(h: int) -> tuple[float, int]:
    return max(0.35, h / 720 * 1.1), max(1, round(h / 360))


class Defect:
    """One defect label's change; `apply(frame, i)` is called with consecutive frame indices."""

    def __init__(self, label: str | None, seed: int, width: int, height: int, fps: float):
        self.label, self.w, self.h, self.fps = label, width, height, fps
        self.rng = np.random.default_rng([seed, 7])
        self.first: np.ndarray | None = None
        self.logo = " ".join(self.rng.choice(["NEWS", "LIVE", "TV9", "CAM", "WLX", "HD"], 2))
        self.corner = int(self.rng.integers(4))
        self.lines = [SUBTITLES[j] for j in self.rng.permutation(len(SUBTITLES))]
        self.clock0 = int(self.rng.integers(0, 86400))

    def apply(self, frame: np.ndarray, i: int) -> np.ndarray:
        label = self.label
        if label is None:
            return frame
        if label == "static":
            if self.first is None:
                self.first = frame
            return self.first
        if label == "shake":
            # Erratic hand shake: a new random offset and small roll every frame, 3-6% of the width.
            dx, dy = self.rng.normal(0, 0.045 * self.w, 2)
            angle = self.rng.normal(0, 2.5)
            m = cv2.getRotationMatrix2D((self.w / 2, self.h / 2), angle, 1.08)
            m[:, 2] += (dx, dy)
            return cv2.warpAffine(frame, m, (self.w, self.h), borderMode=cv2.BORDER_REFLECT)
        if label == "blur":
            return cv2.GaussianBlur(frame, (0, 0), max(1.5, 0.012 * self.w))
        if label == "overexposed":
            return np.clip(frame.astype(np.float32) * 2.4 + 70, 0, 255).astype(np.uint8)
        if label == "underexposed":
            return (frame.astype(np.float32) * 0.1).astype(np.uint8)
        if label == "noise":
            noise = self.rng.normal(0, 38, frame.shape)
            return np.clip(frame + noise, 0, 255).astype(np.uint8)
        out = frame.copy()
        scale, thick = _font(self.h)
        if label == "text_subtitle":
            k = int(i // (2.2 * self.fps))
            for row, text in enumerate((self.lines[k % len(self.lines)], self.lines[(k + 3) % len(self.lines)])):
                (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
                org = ((self.w - tw) // 2, int(self.h * (0.86 + 0.08 * row)))
                cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick + 2, cv2.LINE_AA)
                cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 230), thick, cv2.LINE_AA)
        elif label == "text_logo":
            (tw, th), _ = cv2.getTextSize(self.logo, cv2.FONT_HERSHEY_DUPLEX, scale, thick)
            x = int(0.03 * self.w) if self.corner % 2 == 0 else self.w - tw - int(0.03 * self.w)
            y = int(0.05 * self.h) + th if self.corner < 2 else self.h - int(0.05 * self.h)
            cv2.rectangle(out, (x - 4, y - th - 4), (x + tw + 4, y + 6), (200, 30, 30), -1)
            cv2.putText(out, self.logo, (x, y), cv2.FONT_HERSHEY_DUPLEX, scale, (255, 255, 255), thick, cv2.LINE_AA)
        elif label == "text_timestamp":
            t = self.clock0 + i / self.fps
            text = f"2026-11-22 {int(t) // 3600 % 24:02d}:{int(t) // 60 % 60:02d}:{int(t) % 60:02d}.{int(t * 100) % 100:02d}"
            (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale * 0.8, thick)
            org = (self.w - tw - int(0.03 * self.w), int(0.05 * self.h) + th)
            cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale * 0.8, (255, 255, 0), thick, cv2.LINE_AA)
        return out


def transform(frame: np.ndarray, kind: str, seed: int) -> np.ndarray:
    """A near-duplicate of `frame`: re-encoded, rescaled, cropped or brightness-shifted (same size)."""
    rng = np.random.default_rng([seed, 9])  # the same parameters for every frame of a segment
    h, w = frame.shape[:2]
    if kind == "exact":
        return frame
    if kind == "reencode":
        quality = int(rng.integers(25, 45))
        ok, buf = cv2.imencode(".jpg", frame[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
        return cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1]
    if kind == "rescale":
        k = rng.uniform(0.4, 0.6)
        small = cv2.resize(frame, (max(8, int(w * k)), max(8, int(h * k))), interpolation=cv2.INTER_AREA)
        return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    if kind == "crop":
        c = rng.uniform(0.05, 0.15)
        y0, x0 = int(h * c / 2), int(w * c / 2)
        return cv2.resize(frame[y0: h - y0, x0: w - x0], (w, h), interpolation=cv2.INTER_LINEAR)
    shift = int(rng.choice([-1, 1]) * rng.integers(10, 21))
    return np.clip(frame.astype(np.int16) + shift, 0, 255).astype(np.uint8)

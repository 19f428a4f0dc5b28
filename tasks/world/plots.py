"""The physics evaluation's pictures, drawn with PIL (matplotlib is not a dependency): error
against horizon per method, and a strip of true against predicted frames."""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw, ImageFont

COLOURS = {"model": (31, 119, 180), "shuffled": (214, 39, 40), "floor": (127, 127, 127), "ceiling": (44, 160, 44)}
LABELS = {"model": "model (true actions)", "shuffled": "model (shuffled actions)", "floor": "copy last frame (floor)",
          "ceiling": "tokenizer reconstruction (ceiling)"}


def _nice_range(lo: float, hi: float) -> tuple[float, float, float]:
    if hi <= lo:
        hi = lo + 1.0
    raw = (hi - lo) / 5
    step = 10 ** np.floor(np.log10(raw))
    step *= next(m for m in (1, 2, 2.5, 5, 10) if raw <= m * step)
    return np.floor(lo / step) * step, np.ceil(hi / step) * step, step


def _panel(draw: ImageDraw.ImageDraw, box: tuple[int, int, int, int], series: dict[str, list[tuple[int, float]]],
           title: str, ylabel: str, font, from_zero: bool) -> None:
    x0, y0, x1, y1 = box
    left, bottom = x0 + 48, y1 - 28
    top, right = y0 + 22, x1 - 10
    points = [p for pts in series.values() for p in pts]
    draw.text((x0 + 4, y0 + 4), title, fill=(0, 0, 0), font=font)
    if not points:
        draw.text((left + 10, (top + bottom) // 2), "no data", fill=(120, 120, 120), font=font)
        return
    xs = [x for x, _ in points]
    xlo, xhi = min(xs), max(max(xs), min(xs) + 1)
    low = min(y for _, y in points)
    ylo, yhi, ystep = _nice_range(min(0.0, low) if from_zero else low, max(y for _, y in points))

    def at(x: float, y: float) -> tuple[float, float]:
        return (left + (x - xlo) / (xhi - xlo) * (right - left), bottom - (y - ylo) / (yhi - ylo) * (bottom - top))

    for y in np.arange(ylo, yhi + ystep / 2, ystep):
        _, py = at(xlo, y)
        draw.line([(left, py), (right, py)], fill=(225, 225, 225))
        draw.text((x0 + 4, py - 5), f"{y:g}", fill=(60, 60, 60), font=font)
    for x in range(int(xlo), int(xhi) + 1):
        if x % 4 == 0 or x == xlo:
            px, _ = at(x, ylo)
            draw.line([(px, bottom), (px, bottom + 3)], fill=(0, 0, 0))
            draw.text((px - 4, bottom + 5), str(x), fill=(60, 60, 60), font=font)
    draw.rectangle([left, top, right, bottom], outline=(0, 0, 0))
    draw.text((right - 150, bottom + 14), "horizon (video frames)", fill=(60, 60, 60), font=font)
    draw.text((left + 4, top + 2), ylabel, fill=(60, 60, 60), font=font)
    for name, pts in series.items():
        xy = [at(x, y) for x, y in sorted(pts)]
        if len(xy) > 1:
            draw.line(xy, fill=COLOURS.get(name, (0, 0, 0)), width=2)
        for px, py in xy:
            draw.ellipse([px - 2, py - 2, px + 2, py + 2], fill=COLOURS.get(name, (0, 0, 0)))


def error_plot(rows: list[dict], methods=tuple(COLOURS)) -> Image.Image:
    """Position error (px), mask IoU and PSNR (dB) against horizon, one line per method."""
    font = ImageFont.load_default()
    panels = (("pos_err_px", "package position error", "px", True), ("iou", "package mask IoU", "IoU", True),
              ("psnr", "PSNR", "dB", False))
    width, height = 560, 260
    image = Image.new("RGB", (width, height * len(panels) + 70), "white")
    draw = ImageDraw.Draw(image)
    for i, (key, title, unit, from_zero) in enumerate(panels):
        series = {m: [(r["horizon"], r[key]) for r in rows if r["method"] == m and r[key] is not None] for m in methods}
        _panel(draw, (0, i * height, width, (i + 1) * height), series, title, unit, font, from_zero)
    y = height * len(panels) + 6
    for i, m in enumerate(methods):
        px, py = 12 + (i % 2) * 270, y + (i // 2) * 28
        draw.line([(px, py + 6), (px + 24, py + 6)], fill=COLOURS[m], width=3)
        draw.text((px + 30, py), LABELS[m], fill=(0, 0, 0), font=font)
    return image


def frame_strip(rows_of_frames: list[tuple[str, np.ndarray]], horizons: list[int], scale: int = 2) -> Image.Image:
    """A grid: one labelled row per (label, ``n x S x S x 3`` uint8 frames), one column per
    horizon in `horizons` (1-based frame index), frames enlarged `scale` times."""
    font = ImageFont.load_default()
    side = rows_of_frames[0][1].shape[1] * scale
    label_w, head = 150, 16
    image = Image.new("RGB", (label_w + len(horizons) * (side + 2), head + len(rows_of_frames) * (side + 2)), "white")
    draw = ImageDraw.Draw(image)
    for j, h in enumerate(horizons):
        draw.text((label_w + j * (side + 2) + 2, 2), f"h={h}", fill=(0, 0, 0), font=font)
    for i, (label, frames) in enumerate(rows_of_frames):
        y = head + i * (side + 2)
        draw.text((4, y + side // 2 - 5), label, fill=(0, 0, 0), font=font)
        for j, h in enumerate(horizons):
            tile = Image.fromarray(frames[h - 1]).resize((side, side), Image.NEAREST)
            image.paste(tile, (label_w + j * (side + 2), y))
    return image

"""The physics evaluation's pictures: error against horizon per method (a matplotlib plot), and
a strip of true against predicted frames (a grid of frames, put together with PIL)."""

from __future__ import annotations

import io

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image, ImageDraw, ImageFont

COLOURS = {"model": (31, 119, 180), "shuffled": (214, 39, 40), "floor": (127, 127, 127), "ceiling": (44, 160, 44)}
LABELS = {"model": "model (true actions)", "shuffled": "model (shuffled actions)", "floor": "copy last frame (floor)",
          "ceiling": "tokenizer reconstruction (ceiling)"}
PANELS = (("pos_err_px", "package position error", "px", True), ("iou", "package mask IoU", "IoU", True),
          ("psnr", "PSNR", "dB", False))


def error_plot(rows: list[dict], methods=tuple(COLOURS)) -> Image.Image:
    """Position error (px), mask IoU and PSNR (dB) against horizon, one line per method, drawn
    with matplotlib (Agg, no pyplot state)."""
    figure = Figure(figsize=(5.6, 2.6 * len(PANELS) + 0.7), dpi=100, layout="constrained")
    axes = figure.subplots(len(PANELS), 1)
    for ax, (key, title, unit, from_zero) in zip(axes, PANELS):
        ax.set_title(title, loc="left", fontsize="medium")
        ax.set_ylabel(unit)
        ax.grid(True, color="#e1e1e1", linewidth=0.8)
        drawn = False
        for m in methods:
            points = sorted((r["horizon"], r[key]) for r in rows if r["method"] == m and r[key] is not None)
            if points:
                drawn = True
                ax.plot([x for x, _ in points], [y for _, y in points], marker="o", markersize=3, linewidth=1.5,
                        color=np.array(COLOURS.get(m, (0, 0, 0))) / 255, label=LABELS.get(m, m))
        if not drawn:
            ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center", color="#787878")
        elif from_zero:
            ax.set_ylim(bottom=min(0.0, ax.get_ylim()[0]))
    axes[-1].set_xlabel("horizon (video frames)")
    handles, labels = axes[0].get_legend_handles_labels()
    for ax in axes[1:]:
        for h, label in zip(*ax.get_legend_handles_labels()):
            if label not in labels:
                handles.append(h)
                labels.append(label)
    if handles:
        figure.legend(handles, labels, loc="outside lower center", ncols=2, fontsize="small", frameon=False)
    FigureCanvasAgg(figure)
    out = io.BytesIO()
    figure.savefig(out, format="png", metadata={"Software": None})
    return Image.open(io.BytesIO(out.getvalue())).convert("RGB")


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

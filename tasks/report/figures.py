"""The report page's pictures, drawn with matplotlib (Agg, no pyplot state, so threads and
servers may call it): stage timings, rejections, metrics, the lineage graph, and contact
sheets of the videos a run wrote. Each function returns PNG bytes, or None when there is
nothing to draw."""

from __future__ import annotations

import io
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

DPI = 100
PALETTE = ("#4c72b0", "#dd8452", "#55a868", "#c44e52", "#8172b3", "#937860", "#da8bc3", "#8c8c8c", "#ccb974",
           "#64b5cd")
TILE = (160, 120)  # contact sheet tile, width x height in pixels
BACKGROUND = (24, 24, 28)


def png(figure: Figure) -> bytes:
    """The figure as PNG bytes; no timestamp or version in the file, so the same data gives the
    same bytes."""
    FigureCanvasAgg(figure)
    out = io.BytesIO()
    figure.savefig(out, format="png", dpi=DPI, metadata={"Software": None})
    return out.getvalue()


def short(identifier: str, n: int = 12) -> str:
    return identifier if len(identifier) <= n else identifier[:n]


# -- a run's numbers --------------------------------------------------------------------------
def stage_plot(totals: Sequence[tuple[str, int, int, int, float]]) -> bytes | None:
    """Seconds per stage, and inputs against outputs per stage (``stage_totals`` rows)."""
    if not totals:
        return None
    stages = [t[0] for t in totals]
    y = np.arange(len(stages))
    figure = Figure(figsize=(10, 0.9 + 0.38 * len(stages)), layout="constrained")
    seconds, counts = figure.subplots(1, 2, sharey=True)
    seconds.barh(y, [t[4] for t in totals], color=PALETTE[0])
    seconds.set_yticks(y, stages)
    seconds.invert_yaxis()
    seconds.set_xlabel("seconds (sum over stage runs)")
    seconds.set_title("time per stage")
    counts.barh(y - 0.2, [t[2] for t in totals], 0.4, label="in", color=PALETTE[7])
    counts.barh(y + 0.2, [t[3] for t in totals], 0.4, label="out", color=PALETTE[2])
    counts.set_xlabel("items")
    counts.set_title("inputs and outputs per stage")
    counts.legend(loc="lower right", fontsize="small")
    return png(figure)


def rejection_plot(rows: Sequence[tuple[str, str, int]]) -> bytes | None:
    """Rejections per (stage, reason), most first."""
    if not rows:
        return None
    labels = [f"{stage}: {reason}" for stage, reason, _ in rows]
    figure = Figure(figsize=(8, 0.9 + 0.32 * len(rows)), layout="constrained")
    ax = figure.subplots()
    y = np.arange(len(rows))
    ax.barh(y, [n for *_, n in rows], color=PALETTE[3])
    ax.set_yticks(y, labels)
    ax.invert_yaxis()
    ax.set_xlabel("rejected")
    ax.set_title("rejections by stage and reason")
    return png(figure)


def metric_plot(rows: Sequence[tuple[str, int, float, str]], most: int = 9) -> bytes | None:
    """One panel per metric name (at most ``most``): a series (several steps) as lines, one
    per subject (at most five); one value per subject over many subjects as a histogram.
    Names with a single value are left to the table."""
    by_name: dict[str, list[tuple[int, float, str]]] = defaultdict(list)
    for name, step, value, subject in rows:
        by_name[name].append((step, value, subject))
    drawable = [(name, points) for name, points in by_name.items() if len(points) > 1][:most]
    if not drawable:
        return None
    cols = min(3, len(drawable))
    n_rows = -(-len(drawable) // cols)
    figure = Figure(figsize=(4 * cols, 2.8 * n_rows), layout="constrained")
    axes = np.atleast_1d(figure.subplots(n_rows, cols)).ravel()
    for ax, (name, points) in zip(axes, drawable):
        steps = {s for s, _, _ in points}
        if len(steps) > 1:
            series: dict[str, list[tuple[int, float]]] = defaultdict(list)
            for step, value, subject in points:
                series[subject].append((step, value))
            for i, (subject, pts) in enumerate(sorted(series.items())[:5]):
                pts.sort()
                ax.plot([p[0] for p in pts], [p[1] for p in pts], marker=".", color=PALETTE[i % len(PALETTE)],
                        label=short(subject))
            ax.set_xlabel("step")
            if len(series) > 1:
                ax.legend(fontsize="x-small")
        else:
            ax.hist([v for _, v, _ in points], bins=min(30, max(5, len(points) // 3)), color=PALETTE[0])
            ax.set_xlabel("value")
            ax.set_ylabel("count")
        ax.set_title(f"{name} (n={len(points)})", fontsize="medium")
    for ax in axes[len(drawable):]:
        ax.set_visible(False)
    return png(figure)


# -- lineage ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Node:
    artifact_id: str
    kind: str
    layer: int  # a hint: 0 for a subject, -depth for an ancestor, +depth for a descendant
    focus: bool = False


def layered(nodes: Sequence[Node], edges: Sequence[tuple[str, str, str]]) -> dict[str, int]:
    """Column of each node: its layer hint, then pushed right until every child stands right of
    each of its parents (edges among the nodes), counted from 0."""
    layer = {n.artifact_id: n.layer for n in nodes}
    inside = [(p, c) for p, c, _ in edges if p in layer and c in layer and p != c]
    for _ in range(len(layer)):  # a DAG settles in at most as many rounds as it has nodes
        moved = False
        for parent, child in inside:
            if layer[child] < layer[parent] + 1:
                layer[child], moved = layer[parent] + 1, True
        if not moved:
            break
    low = min(layer.values())
    return {k: v - low for k, v in layer.items()}


def lineage_graph(nodes: Sequence[Node], edges: Sequence[tuple[str, str, str]], note: str = "") -> bytes | None:
    """The nodes in columns, parents left of children (``layered``), each a box with its kind
    and short id, subjects outlined in yellow; an arrow per edge from parent to child,
    labelled with its relation when it is not the usual "derived"."""
    if not nodes:
        return None
    column_of = layered(nodes, edges)
    columns: dict[int, list[Node]] = defaultdict(list)
    for node in sorted(nodes, key=lambda n: (column_of[n.artifact_id], n.kind, n.artifact_id)):
        columns[column_of[node.artifact_id]].append(node)
    width = max(columns) + 1
    tallest = max(len(v) for v in columns.values())
    where = {node.artifact_id: (float(x), (len(column) - 1) / 2 - i)  # each column centred
             for x, column in columns.items() for i, node in enumerate(column)}
    colours = {kind: PALETTE[i % len(PALETTE)] for i, kind in enumerate(sorted({n.kind for n in nodes}))}
    figure = Figure(figsize=(max(4.0, 2.4 * width), max(1.6, 0.62 * tallest + 0.6)), layout="constrained")
    ax = figure.subplots()
    boxes = {}
    for node in nodes:
        x, y = where[node.artifact_id]
        boxes[node.artifact_id] = ax.text(
            x, y, f"{node.kind}\n{short(node.artifact_id)}", ha="center", va="center", fontsize=7, family="monospace",
            color="black" if node.focus else "white", zorder=3,
            bbox=dict(boxstyle="round,pad=0.35", fc="#ffd54f" if node.focus else colours[node.kind],
                      ec="black" if node.focus else "none", lw=1.6))
    for parent, child, relation in edges:
        if parent not in boxes or child not in boxes:
            continue
        # from the right edge of the parent's box to the left edge of the child's
        ax.annotate("", xy=(0, 0.5), xycoords=boxes[child], xytext=(1, 0.5), textcoords=boxes[parent],
                    arrowprops=dict(arrowstyle="->", color="#777777", lw=0.9, shrinkA=5, shrinkB=5))
        if relation != "derived":
            (x0, y0), (x1, y1) = where[parent], where[child]
            ax.text((x0 + x1) / 2, (y0 + y1) / 2, relation, fontsize=6, color="#555555", ha="center", va="bottom")
    ax.set_xlim(-0.6, width - 0.4)
    ax.set_ylim(-tallest / 2 - 0.1, tallest / 2 + 0.1)
    ax.set_axis_off()
    if note:
        ax.set_title(note, fontsize=8, loc="left")
    return png(figure)


# -- contact sheets ---------------------------------------------------------------------------
def sample_frames(path: Path, columns: int) -> list[np.ndarray]:
    """``columns`` frames spread evenly over the video (display orientation, RGB), decoding
    only up to the last one needed. Raises what tasks.video raises for a bad file."""
    from tasks.video import display_frames, probe

    n = probe(path).n_frames
    wanted = sorted({int(round(i)) for i in np.linspace(0, max(n - 1, 0), columns)})
    frames, last = [], wanted[-1]
    for i, frame in enumerate(display_frames(path)):
        if i in wanted:
            frames.append(frame)
        if i >= last:
            break
    return frames


def _tile(frame: np.ndarray) -> np.ndarray:
    image = Image.fromarray(frame)
    scale = min(TILE[0] / image.width, TILE[1] / image.height)  # small frames are enlarged too
    image = image.resize((max(1, round(image.width * scale)), max(1, round(image.height * scale))), Image.BILINEAR)
    canvas = Image.new("RGB", TILE, BACKGROUND)
    canvas.paste(image, ((TILE[0] - image.width) // 2, (TILE[1] - image.height) // 2))
    return np.asarray(canvas)


def contact_sheet(rows: Sequence[tuple[str, list[np.ndarray]]], columns: int) -> bytes | None:
    """One row of evenly spaced frames per video, labelled on the left (label, frames)."""
    rows = [(label, frames) for label, frames in rows if frames]
    if not rows:
        return None
    w, h = TILE
    gap = 4
    mosaic = np.full((len(rows) * (h + gap) - gap, columns * (w + gap) - gap, 3), 255, np.uint8)
    for r, (_, frames) in enumerate(rows):
        for c, frame in enumerate(frames[:columns]):
            mosaic[r * (h + gap): r * (h + gap) + h, c * (w + gap): c * (w + gap) + w] = _tile(frame)
    figure = Figure(figsize=(mosaic.shape[1] / DPI + 2.4, mosaic.shape[0] / DPI + 0.5), layout="constrained")
    ax = figure.subplots()
    ax.imshow(mosaic, interpolation="nearest")
    ax.set_yticks([r * (h + gap) + h / 2 for r in range(len(rows))], [label for label, _ in rows], fontsize=7,
                  family="monospace")
    ax.set_xticks([c * (w + gap) + w / 2 for c in range(columns)],
                  [f"{100 * c / max(columns - 1, 1):.0f}%" for c in range(columns)], fontsize=7)
    for side in ax.spines.values():
        side.set_visible(False)
    ax.tick_params(length=0)
    return png(figure)

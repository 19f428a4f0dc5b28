"""The contact sheet (one PNG) and the frames of the panel video.

Contact sheet: a header row with the sample times, then one row per variant: its label
(cell name and verdicts) and ``columns`` frames sampled evenly over the episode. With a
world-model rollout, each sample shows the simulator render and the generated frame side
by side (simulator left). Panel video: every variant's tile (label bar over simulator |
world model) in a grid, frame by frame. All frames are H x W x 3 uint8 RGB.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

GAP = 2  # px between tiles
LABEL_H = 14  # px of the label bar over a video tile
BACKGROUND = (24, 24, 28)
INK = (235, 235, 235)


@dataclass(frozen=True)
class SheetRow:
    """One variant: F x H x W x 3 simulator frames and, when rolled out, the world model's."""

    label: str
    sim: np.ndarray
    world: np.ndarray | None = None
    note: str = ""  # a second line under the label, e.g. the verdicts

    def __post_init__(self):
        for name, frames in (("sim", self.sim), ("world", self.world)):
            if frames is not None and (frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8):
                raise ValueError(f"{self.label}: {name} frames must be F x H x W x 3 uint8, not {frames.shape} {frames.dtype}")
        if self.world is not None and self.world.shape[1:] != self.sim.shape[1:]:
            raise ValueError(f"{self.label}: world-model frames {self.world.shape[1:3]} differ in size "
                             f"from the simulator's {self.sim.shape[1:3]}")


@lru_cache(maxsize=1)
def _font() -> ImageFont.ImageFont:
    return ImageFont.load_default()


def _text(image: Image.Image, xy: tuple[int, int], text: str, width: int) -> None:
    draw = ImageDraw.Draw(image)
    font = _font()
    while text and draw.textlength(text, font=font) > width:  # clip, never spill into a tile
        text = text[:-1]
    draw.text(xy, text, fill=INK, font=font)


def sample_indices(n_frames: int, columns: int) -> np.ndarray:
    """``columns`` frame indices spread evenly from the first frame to the last."""
    if n_frames < 1:
        raise ValueError("no frames to sample")
    return np.unique(np.linspace(0, n_frames - 1, max(1, columns)).round().astype(int))


def _pair(sim: np.ndarray, world: np.ndarray | None, with_world: bool) -> np.ndarray:
    if not with_world:
        return sim
    h, w = sim.shape[:2]
    out = np.full((h, 2 * w + GAP, 3), BACKGROUND, np.uint8)
    out[:, :w] = sim
    if world is not None:
        out[:, w + GAP:] = world
    return out


def contact_sheet(rows: Sequence[SheetRow], columns: int = 6, fps: float = 30.0, label_width: int = 120) -> np.ndarray:
    """Rows = variants, columns = time samples; returns the sheet as H x W x 3 uint8."""
    if not rows:
        raise ValueError("a contact sheet needs at least one row")
    shape = rows[0].sim.shape[1:]
    if any(r.sim.shape[1:] != shape for r in rows):
        raise ValueError("every variant must share the frame size (the panel contract fixes the cameras)")
    with_world = any(r.world is not None for r in rows)
    n = min(min(len(r.sim) for r in rows), min((len(r.world) for r in rows if r.world is not None), default=10**9))
    picks = sample_indices(n, columns)
    h, w = shape[:2]
    cell_w = 2 * w + GAP if with_world else w
    header = 2 * LABEL_H
    width = label_width + len(picks) * (cell_w + GAP)
    height = header + len(rows) * (h + GAP)
    sheet = Image.new("RGB", (width, height), BACKGROUND)
    _text(sheet, (4, 2), "simulator | world model" if with_world else "simulator", label_width - 4)
    for j, i in enumerate(picks):
        _text(sheet, (label_width + j * (cell_w + GAP) + 2, LABEL_H), f"t={i / fps:.2f}s", cell_w - 2)
    canvas = np.asarray(sheet).copy()
    for k, row in enumerate(rows):
        y = header + k * (h + GAP)
        for j, i in enumerate(picks):
            x = label_width + j * (cell_w + GAP)
            canvas[y:y + h, x:x + cell_w] = _pair(row.sim[i], None if row.world is None else row.world[i], with_world)
    sheet = Image.fromarray(canvas)
    for k, row in enumerate(rows):
        y = header + k * (h + GAP)
        _text(sheet, (4, y + 2), row.label, label_width - 6)
        for line, text in enumerate(row.note.split("\n")[:4]):
            _text(sheet, (4, y + 2 + (line + 1) * LABEL_H), text, label_width - 6)
    return np.asarray(sheet)


def video_layout(n_tiles: int) -> tuple[int, int]:
    """(rows, columns) of the panel video's grid: as square as it gets, wider than tall."""
    cols = math.ceil(math.sqrt(n_tiles))
    return math.ceil(n_tiles / cols), cols


def panel_frames(rows: Sequence[SheetRow]) -> Iterator[np.ndarray]:
    """The panel video, frame by frame (as long as the shortest row), even-sized for H.264."""
    with_world = any(r.world is not None for r in rows)
    n = min(min(len(r.sim) for r in rows), min((len(r.world) for r in rows if r.world is not None), default=10**9))
    h, w = rows[0].sim.shape[1:3]
    tile_w = 2 * w + GAP if with_world else w
    tile_h = h + LABEL_H
    grid_r, grid_c = video_layout(len(rows))
    height, width = grid_r * (tile_h + GAP), grid_c * (tile_w + GAP)
    height, width = height + height % 2, width + width % 2
    labels = Image.new("RGB", (width, height), BACKGROUND)
    for k, row in enumerate(rows):
        r, c = divmod(k, grid_c)
        _text(labels, (c * (tile_w + GAP) + 2, r * (tile_h + GAP)), row.label, tile_w - 2)
    base = np.asarray(labels).copy()
    for i in range(n):
        frame = base.copy()
        for k, row in enumerate(rows):
            r, c = divmod(k, grid_c)
            y, x = r * (tile_h + GAP) + LABEL_H, c * (tile_w + GAP)
            frame[y:y + h, x:x + tile_w] = _pair(row.sim[i], None if row.world is None else row.world[i], with_world)
        yield frame


def write_png(path: Path, image: np.ndarray) -> Path:
    """A PNG without timestamps or text chunks: the same image gives the same bytes."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.png")
    Image.fromarray(image).save(tmp, format="PNG", optimize=False, compress_level=6)
    tmp.replace(path)
    return path


@dataclass(frozen=True)
class PanelMedia:
    """The written contact sheet and panel video, and the faces the post-guard hid in each."""

    sheet: Path
    video: Path
    frames: int
    sheet_faces: tuple
    video_faces: tuple


def write_panel_media(rows: Sequence[SheetRow], sheet_path: Path, video_path: Path, fps: float,
                      guard=None, columns: int = 6) -> PanelMedia:
    """Contact sheet PNG and panel MP4 (tasks/mp4.py), each passed through the face post-guard
    (``guard``: a GuardConfig; None or disabled leaves the pixels as rendered)."""
    from tasks.guard.faces import guard_frames, guard_stream
    from tasks.mp4 import write_mp4

    sheet = contact_sheet(rows, columns, fps)
    sheet_faces: list = []
    if guard is not None and guard.enabled:
        guarded, sheet_faces = guard_frames(sheet[None], guard)
        sheet = guarded[0]
    write_png(sheet_path, sheet)
    video_faces: list = []
    count = [0]

    def frames() -> Iterator[np.ndarray]:
        source = panel_frames(rows)
        stream = guard_stream(source, guard) if guard is not None and guard.enabled else ((f, []) for f in source)
        for frame, made in stream:
            video_faces.extend(made)
            count[0] += 1
            yield frame

    write_mp4(video_path, frames(), fps)
    return PanelMedia(Path(sheet_path), Path(video_path), count[0], tuple(sheet_faces), tuple(video_faces))

"""A clip's dedup signature: perceptual hashes and grey thumbnails of sampled frames.

A clip's signature is ``frames`` evenly spaced frames of its analysis frames (T x h x w x 3
uint8 RGB, long side about 256). Each sampled frame gives, after black letterbox or pillarbox
bars are cut off:

- a 64-bit imagehash ``phash`` of the whole picture and of a few crops of it (centred and
  corner-anchored), so a copy that was cropped 5-15% still meets its original under one crop
  hypothesis;
- a ``thumb_size`` x ``thumb_size`` uint8 grey thumbnail for the final check.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import imagehash
import numpy as np
from PIL import Image
from pydantic import BaseModel, ConfigDict, Field

# (keep width, keep height, anchor x, anchor y): the part of the picture a crop keeps and where
# it sits (0 = left/top edge, 0.5 = centred, 1 = right/bottom edge). The first is the picture.
Crop = tuple[float, float, float, float]
DEFAULT_CROPS: tuple[Crop, ...] = (
    (1.0, 1.0, 0.5, 0.5),
    *((k, k, 0.5, 0.5) for k in (0.95, 0.9, 0.85, 0.8)),
    *((k, k, ax, ay) for k in (0.9, 0.8) for ax in (0.0, 1.0) for ay in (0.0, 1.0)),
    (0.85, 1.0, 0.5, 0.5),
    (1.0, 0.85, 0.5, 0.5),
)


class DedupConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    frames: int = Field(5, ge=1, le=32, description="frames sampled per clip")
    thumb_size: int = Field(32, ge=16, le=128)
    time_radius: int = Field(2, ge=0, le=8, description="frames kept either side of each sample: copies cut a frame or two apart")
    crops: tuple[Crop, ...] = DEFAULT_CROPS
    bar_level: int = Field(24, ge=0, le=255, description="rows/columns darker than this at the border are bars")
    min_collisions: int = Field(2, ge=1, description="LSH band collisions a pair needs to become a candidate")
    max_bucket: int = Field(256, ge=2, description="LSH buckets fuller than this are split by more bands; "
                            "if a whole 64-bit hash is that common (black frames), it proposes no pairs")
    max_neighbours: int = Field(8, ge=1, description="pixel checks per clip, nearest hashes first: bounds work in a crowded scene")
    hash_max: float = Field(0.15, gt=0, le=1, description="mean fraction of differing hash bits, best crop hypothesis")
    residual_max: float = Field(9.0, gt=0, description="grey levels: p99.5 of the aligned, blurred thumbnail residual")
    quality_score: str = Field("quality", description="ClipRecord.scores key that ranks copies of equal resolution")


@dataclass(frozen=True, eq=False)
class ClipSignature:
    """hashes: F x C uint64 (sampled frame x crop of DedupConfig.crops).

    thumbs: F x O x S x S uint8 grey, the sampled frame and its neighbours at offsets
    -time_radius..time_radius (clamped to the clip).
    """

    hashes: np.ndarray
    thumbs: np.ndarray
    exact: bool = True  # False: some sampled frame was not decoded, its nearest decoded frame stands in

    @property
    def phash(self) -> str:
        """Hex phash of each sampled whole picture, concatenated (16 hex digits per frame)."""
        return "".join(f"{int(h):016x}" for h in self.hashes[:, 0])


def content_box(grey: np.ndarray, bar_level: int) -> tuple[int, int, int, int]:
    """(top, bottom, left, right) inside black bars, judged over all sampled frames: F x h x w."""
    peak = grey.max(axis=0)
    h, w = peak.shape
    rows = np.flatnonzero(np.percentile(peak, 98, axis=1) >= bar_level)
    cols = np.flatnonzero(np.percentile(peak, 98, axis=0) >= bar_level)
    if rows.size == 0 or cols.size == 0:
        return 0, h, 0, w
    # Letterbox and pillarbox bars come in pairs: a dark edge on one side only is picture (a
    # darkened copy of a shot with a dim border would otherwise lose that border, and no longer
    # line up with its original). Each pair is cut to its narrower bar.
    y = min(int(rows[0]), h - 1 - int(rows[-1]))
    x = min(int(cols[0]), w - 1 - int(cols[-1]))
    top, bottom, left, right = y, h - y, x, w - x
    # A dark scene is not a letterbox: only trust bars that leave most of the picture.
    if bottom - top < h // 2 or right - left < w // 2:
        return 0, h, 0, w
    return top, bottom, left, right


def _crop_box(crop: Crop, w: int, h: int) -> tuple[int, int, int, int]:
    kw, kh, ax, ay = crop
    x0, y0 = ax * (1 - kw) * w, ay * (1 - kh) * h
    return round(x0), round(y0), max(round(x0 + kw * w), round(x0) + 1), max(round(y0 + kh * h), round(y0) + 1)


def _phash_input(grey: np.ndarray) -> np.ndarray:
    # imagehash.phash works on a 32 x 32 picture; shrinking to that with cv2's area filter first
    # leaves its own resize nothing to do and costs a tenth of PIL's Lanczos from 256 px.
    return cv2.resize(grey, (32, 32), interpolation=cv2.INTER_AREA)


def _phash64(grey: np.ndarray) -> np.uint64:
    """imagehash's own ``phash`` of one grey picture, as 64 bits (the reference of ``_phash64_many``)."""
    bits = np.packbits(imagehash.phash(Image.fromarray(_phash_input(grey))).hash.ravel())
    return np.frombuffer(bits.tobytes(), dtype=">u8")[0].astype(np.uint64)


def _phash64_many(smalls: np.ndarray) -> np.ndarray:
    """``_phash64`` of N 32 x 32 uint8 pictures (``_phash_input``) in one go: imagehash's steps
    (a 2-D DCT-II, the 8 x 8 lowest frequencies, each bit above their median) on the stack,
    with the same scipy calls along the same axes, so the bits are imagehash's (test_dedup_signature
    compares them); one call instead of one per crop of every sampled frame."""
    import scipy.fftpack

    dct = scipy.fftpack.dct(scipy.fftpack.dct(smalls, axis=1), axis=2)
    low = dct[:, :8, :8].reshape(len(smalls), 64)
    bits = np.packbits(low > np.median(low, axis=1, keepdims=True), axis=1)
    return np.frombuffer(bits.tobytes(), dtype=">u8").astype(np.uint64)


def sample_positions(length: int, config: DedupConfig = DedupConfig()) -> np.ndarray:
    """F x O frame positions in a clip of ``length`` frames that its signature samples: the
    centres of F equal slices (not the ends: a clip's first and last frames may hold part of
    a fade), each with its neighbours at -time_radius..time_radius, clamped to the clip."""
    centre = np.minimum(((np.arange(config.frames) + 0.5) * length / config.frames).astype(int), length - 1)
    offsets = np.arange(-config.time_radius, config.time_radius + 1)
    return np.clip(centre[:, None] + offsets[None, :], 0, length - 1)


def signature(frames: np.ndarray, config: DedupConfig = DedupConfig(), positions: np.ndarray | None = None,
              length: int | None = None) -> ClipSignature:
    """Signature of one clip from its analysis frames, T x h x w x 3 uint8 RGB (T >= 1).

    ``positions`` (T sorted ints) place the frames in a clip of ``length`` frames when some
    were not decoded; a sampled position without its frame takes the nearest decoded one, and
    the signature is then not ``exact`` (``group`` can ask for the exact frames).
    """
    if not isinstance(frames, np.ndarray) or frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
        got = f"{getattr(frames, 'shape', None)} {getattr(frames, 'dtype', type(frames).__name__)}"
        raise ValueError(f"dedup.signature: expected T x h x w x 3 uint8 RGB frames, got {got}")
    if frames.shape[0] == 0 or min(frames.shape[1:3]) < 8:
        raise ValueError(f"dedup.signature: need at least one frame of 8 x 8 pixels, got shape {frames.shape}")
    n = frames.shape[0]
    if positions is None:
        positions, length = np.arange(n), n
    positions = np.asarray(positions, np.int64)
    if positions.shape != (n,) or np.any(np.diff(positions) <= 0) or length is None or length <= positions[-1]:
        raise ValueError(f"dedup.signature: positions must be {n} increasing frame numbers below length, "
                         f"got {positions.shape} and length {length}")
    planned = sample_positions(int(length), config)  # F x O clip positions
    if n > 1:  # the nearest decoded frame; the earlier one on a tie
        after = np.clip(np.searchsorted(positions, planned), 1, n - 1)
        near = after - (planned - positions[after - 1] <= positions[after] - planned)
    else:
        near = np.zeros_like(planned)
    exact = bool(np.array_equal(positions[near], planned))
    index = near[:, config.time_radius]
    wanted = np.unique(near)
    grey = {int(i): cv2.cvtColor(frames[i], cv2.COLOR_RGB2GRAY) for i in wanted}
    top, bottom, left, right = content_box(np.stack([grey[int(i)] for i in index]), config.bar_level)
    size = config.thumb_size
    small = {i: cv2.resize(g[top:bottom, left:right], (size, size), interpolation=cv2.INTER_AREA) for i, g in grey.items()}
    inputs = []
    for i in index:
        g = np.ascontiguousarray(grey[int(i)][top:bottom, left:right])
        for crop in config.crops:
            x0, y0, x1, y1 = _crop_box(crop, g.shape[1], g.shape[0])
            inputs.append(_phash_input(g[y0:y1, x0:x1]))
    hashes = _phash64_many(np.stack(inputs)).reshape(len(index), len(config.crops))
    thumbs = np.stack([np.stack([small[int(i)] for i in row]) for row in near])
    return ClipSignature(hashes=hashes, thumbs=thumbs, exact=exact)

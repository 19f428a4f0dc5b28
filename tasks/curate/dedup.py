"""Near-duplicate clips: perceptual hashes of sampled frames, grouped so each copy keeps one clip.

A clip's signature is ``frames`` evenly spaced frames of its analysis frames (T x h x w x 3
uint8 RGB, long side about 256). Each sampled frame gives, after black letterbox or pillarbox
bars are cut off:

- a 64-bit imagehash ``phash`` of the whole picture and of a few crops of it (centred and
  corner-anchored), so a copy that was cropped 5-15% still meets its original under one crop
  hypothesis;
- a ``thumb_size`` x ``thumb_size`` uint8 grey thumbnail for the final check.

Grouping runs in three passes, each costlier per pair than the last and each seeing fewer pairs:
banded LSH on 16-bit bands of the hashes proposes candidates (never all n^2 pairs), the mean
Hamming distance under the best crop hypothesis prunes them (keeping each clip's
``max_neighbours`` nearest), and a pixel check accepts a pair only when the thumbnails agree
everywhere once aligned (a crop hypothesis, ECC-refined for near misses) and offset for
brightness, at every sampled frame (each at the best of its neighbouring frames).
That last check is what keeps apart different footage of the same simulator scene, whose hashes
differ in a few bits: a copy differs from its original by codec noise spread thinly, different
footage by an object somewhere else, which a high percentile of the residual sees.

Groups are stars around the best copy (resolution, then quality score, then smallest id), so a
chain of near misses cannot merge two unrelated clips, and the result is the same whatever
order the clips arrive in.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

import cv2
import imagehash
import numpy as np
from PIL import Image
from pydantic import BaseModel, ConfigDict, Field

from schemas.records import ClipRecord

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
BAND_BITS = 16
CROP_MARGIN = 0.05  # fraction of hash bits
QUANTILE = 0.995  # of the residual: different footage differs somewhere, copies nowhere
BANDS = 64 // BAND_BITS


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


class DedupResult(BaseModel):
    """groups: kept id -> every member (kept first, then sorted); removed: removed id -> kept id."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    groups: dict[str, tuple[str, ...]]
    kept: tuple[str, ...]
    removed: dict[str, str]
    candidates: int = 0  # pairs proposed by LSH
    hash_pairs: int = 0  # pairs within hash_max
    checked: int = 0  # pairs given the pixel check (max_neighbours per clip)
    verified: int = 0  # pairs that passed the pixel check
    redecoded: int = 0  # clips whose sampled frames were decoded again for the pixel check


def _content_box(grey: np.ndarray, bar_level: int) -> tuple[int, int, int, int]:
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


def _phash64(grey: np.ndarray) -> np.uint64:
    # imagehash.phash works on a 32 x 32 picture; shrinking to that with cv2's area filter first
    # leaves its own resize nothing to do and costs a tenth of PIL's Lanczos from 256 px.
    small = cv2.resize(grey, (32, 32), interpolation=cv2.INTER_AREA)
    bits = np.packbits(imagehash.phash(Image.fromarray(small)).hash.ravel())
    return np.frombuffer(bits.tobytes(), dtype=">u8")[0].astype(np.uint64)


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
    top, bottom, left, right = _content_box(np.stack([grey[int(i)] for i in index]), config.bar_level)
    size = config.thumb_size
    small = {i: cv2.resize(g[top:bottom, left:right], (size, size), interpolation=cv2.INTER_AREA) for i, g in grey.items()}
    hashes = np.zeros((len(index), len(config.crops)), dtype=np.uint64)
    for f, i in enumerate(index):
        g = np.ascontiguousarray(grey[int(i)][top:bottom, left:right])
        for c, crop in enumerate(config.crops):
            x0, y0, x1, y1 = _crop_box(crop, g.shape[1], g.shape[0])
            hashes[f, c] = _phash64(g[y0:y1, x0:x1])
    thumbs = np.stack([np.stack([small[int(i)] for i in row]) for row in near])
    return ClipSignature(hashes=hashes, thumbs=thumbs, exact=exact)


def _bucket_pairs(slot, value, clip, whole, max_bucket):
    """Pair codes (i * 2^32 + j, i < j) of clips sharing a (slot, value) bucket, one side a whole
    picture, and a mask of the entries that sat in buckets holding more than max_bucket clips."""
    order = np.lexsort((~whole, clip, slot, value))
    slot, value, clip, whole = slot[order], value[order], clip[order], whole[order]
    new_bucket = np.r_[True, (value[1:] != value[:-1]) | (slot[1:] != slot[:-1])]
    bucket = np.cumsum(new_bucket) - 1
    # Each clip once per bucket (its whole picture first), so a clip's own crops add no count.
    first = new_bucket | np.r_[True, clip[1:] != clip[:-1]]
    clips_in = np.bincount(bucket[first], minlength=bucket[-1] + 1)
    crowded = np.empty_like(order, dtype=bool)
    crowded[order] = clips_in[bucket] > max_bucket
    keep = first & (clips_in[bucket] <= max_bucket)
    clip, whole, bucket = clip[keep], whole[keep], bucket[keep]
    end = np.r_[np.flatnonzero(bucket[1:] != bucket[:-1]) + 1, bucket.size]
    run_end = np.repeat(end, np.diff(np.r_[0, end]))
    codes, pos, step = [], np.arange(bucket.size), 1
    while pos.size:
        pos = pos[pos + step < run_end[pos]]
        hit = pos[whole[pos] | whole[pos + step]]
        a, b = clip[hit], clip[hit + step]
        codes.append((np.minimum(a, b) << 32) | np.maximum(a, b))
        step += 1
    return np.concatenate(codes) if codes else np.zeros(0, np.int64), crowded


def _candidates(hashes: np.ndarray, config: DedupConfig) -> np.ndarray:
    """P x 2 int64 index pairs (i < j) that collide in at least min_collisions LSH buckets.

    hashes: N x F x C uint64. A bucket is one (frame, band, 16-bit value). Every crop is filed,
    but a collision counts only when one side is a whole picture: those are the hypotheses the
    hash distance tries, and crop-against-crop collisions would multiply chance matches. A
    bucket crowded past max_bucket clips (one simulator scene's flat walls hash alike) is split
    by the next band too, then the next, rather than dropped or paired n^2.
    """
    n, f, c = hashes.shape
    full = np.repeat(hashes.reshape(-1), BANDS)
    clip = np.repeat(np.arange(n, dtype=np.int64), f * c * BANDS)
    frame = np.tile(np.repeat(np.arange(f), c * BANDS), n)
    whole = np.tile(np.repeat(np.arange(c) == 0, BANDS), n * f)
    band = np.tile(np.arange(BANDS, dtype=np.uint64), n * f * c)
    slot = frame * BANDS + band.astype(np.int64)
    codes = []
    active = np.arange(full.size)
    for width in range(1, BANDS + 1):
        # Bands band..band+width-1, cyclically: rotate the hash right so they sit at the bottom.
        shift = band[active] * np.uint64(BAND_BITS)
        h = full[active]
        rotated = np.where(shift == 0, h, (h >> shift) | (h << ((np.uint64(64) - shift) % np.uint64(64))))
        value = rotated & np.uint64((1 << (BAND_BITS * width)) - 1) if width < BANDS else rotated
        found, crowded = _bucket_pairs(slot[active], value, clip[active], whole[active], config.max_bucket)
        codes.append(found)
        active = active[crowded]
        if not active.size:
            break
    code, count = np.unique(np.concatenate(codes), return_counts=True)
    code = code[count >= config.min_collisions]
    return np.stack([code >> 32, code & 0xFFFFFFFF], axis=1).astype(np.int64)


def _hash_distance(hashes: np.ndarray, pairs: np.ndarray, chunk: int = 50_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pair: best mean fraction of differing bits; its hypothesis (+c = i whole vs j crop c,
    -c = the reverse, 0 = both whole); and whether that crop clearly beats the whole picture."""
    dist = np.empty(len(pairs))
    hyp = np.empty(len(pairs), dtype=np.int64)
    clear = np.empty(len(pairs), dtype=bool)
    for s in range(0, len(pairs), chunk):
        a, b = hashes[pairs[s:s + chunk, 0]], hashes[pairs[s:s + chunk, 1]]  # P x F x C
        fwd = np.bitwise_count(a[:, :, :1] ^ b).mean(axis=1) / 64.0  # i whole vs j crop
        rev = np.bitwise_count(a ^ b[:, :, :1]).mean(axis=1) / 64.0  # i crop vs j whole
        both = np.concatenate([fwd, rev], axis=1)
        best = both.argmin(axis=1)
        dist[s:s + chunk] = both[np.arange(len(best)), best]
        # Look-alike clips fit some crop by chance, a little better than the whole picture;
        # a real crop of more than a few percent beats it clearly.
        clear[s:s + chunk] = fwd[:, 0] - dist[s:s + chunk] >= CROP_MARGIN
        c = best % fwd.shape[1]
        hyp[s:s + chunk] = np.where(best < fwd.shape[1], c, -c)
    return dist, hyp, clear


def _nearest(pairs: np.ndarray, dist: np.ndarray, config: DedupConfig) -> np.ndarray:
    """Indices of pairs within hash_max that are among max_neighbours nearest of either clip (ties by index)."""
    close = np.flatnonzero(dist <= config.hash_max)
    if close.size == 0:
        return close
    src = np.r_[pairs[close, 0], pairs[close, 1]]
    dst = np.r_[pairs[close, 1], pairs[close, 0]]
    order = np.lexsort((dst, np.r_[dist[close], dist[close]], src))
    src = src[order]
    first = np.r_[0, np.flatnonzero(src[1:] != src[:-1]) + 1]
    rank = np.arange(src.size) - np.repeat(first, np.diff(np.r_[first, src.size]))
    return np.unique(np.r_[close, close][order][rank < config.max_neighbours])


def _crop_matrix(crop: Crop, size: int) -> np.ndarray:
    """2 x 3 map from whole-picture thumbnail pixels to the pixels of the other thumbnail's crop."""
    kw, kh, ax, ay = crop
    x0, y0 = ax * (1 - kw) * size, ay * (1 - kh) * size
    return np.array([[kw, 0, x0 + 0.5 * kw - 0.5], [0, kh, y0 + 0.5 * kh - 0.5]], dtype=np.float32)


def _warp_stack(images: np.ndarray, warp: np.ndarray) -> np.ndarray:
    """N x S x S float32 sampled at warp @ (x, y, 1): bilinear, edges replicated (cv2's inverse-map convention)."""
    size = images.shape[-1]
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    out = np.empty_like(images)
    # Pictures as channels of one image: one call instead of N (OpenCV allows up to 512 channels).
    for s in range(0, len(images), 256):
        chunk = np.ascontiguousarray(images[s:s + 256].transpose(1, 2, 0))
        warped = cv2.warpAffine(chunk, warp, (size, size), flags=flags, borderMode=cv2.BORDER_REPLICATE)
        out[s:s + 256] = warped.reshape(size, size, -1).transpose(2, 0, 1)
    return out


def _residual(template: np.ndarray, moving: np.ndarray, warp: np.ndarray) -> np.ndarray:
    """p99 absolute residual (grey levels) per frame and offset, after warping and a brightness offset.

    template: F x S x S float32 (sampled frames); moving: F x O x S x S float32 (with neighbours).
    Returns F x O.
    """
    n_f, n_o, size = moving.shape[0], moving.shape[1], moving.shape[-1]
    warped = _warp_stack(moving.reshape(n_f * n_o, size, size), warp).reshape(moving.shape)
    t = np.broadcast_to(template[:, None], moving.shape)
    # Pixels clipped at either end cannot follow a brightness shift: they set no offset and
    # count as agreeing.
    valid = (t > 8) & (t < 247) & (warped > 8) & (warped < 247)
    d = t - warped
    n_valid = valid.sum(axis=(2, 3))
    offset = (np.where(valid, d, 0).sum(axis=(2, 3)) / np.maximum(n_valid, 1)).astype(np.float32)
    d = np.where(valid, d - offset[..., None, None], np.float32(0))
    chunks = [cv2.GaussianBlur(np.ascontiguousarray(c.transpose(1, 2, 0)), (5, 5), 0).reshape(size, size, -1)
              for c in np.array_split(d.reshape(-1, size, size), max(1, n_f * n_o // 256 + 1))]
    d = np.abs(np.concatenate([c.transpose(2, 0, 1) for c in chunks])).reshape(moving.shape)
    m0 = max(2, size // 10)  # warped borders are replicated, not seen
    d = d[..., m0:-m0, m0:-m0].reshape(n_f, n_o, -1)
    q = int(QUANTILE * (d.shape[-1] - 1))
    return np.partition(d, q, axis=2)[..., q]


def _refine(template: np.ndarray, moving: np.ndarray, warp: np.ndarray) -> np.ndarray | None:
    """ECC affine alignment of two S x S float32 pictures from ``warp``, coarse to fine; None if it fails."""
    def rescale(m: np.ndarray, k: float) -> np.ndarray:
        # Pixel centres sit at i + 0.5, so halving the size is not halving the translation.
        out = m.copy()
        row = m[:, 0] + m[:, 1]
        out[:, 2] = (m[:, 2] + 0.5 * row - 0.5) * k - 0.5 * row + 0.5
        return out

    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    small = [cv2.resize(x, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA) for x in (template, moving)]
    try:
        # Half size first widens the basin for crops that fall between two hypotheses.
        _, half = cv2.findTransformECC(small[0], small[1], rescale(warp, 0.5), cv2.MOTION_AFFINE, criteria, None, 3)
        _, full = cv2.findTransformECC(template, moving, rescale(half, 2.0), cv2.MOTION_AFFINE, criteria, None, 3)
    except cv2.error:
        return None  # no alignment converges: flat or unrelated pictures
    return full


def _footage_distance(sa: ClipSignature, sb: ClipSignature, hyp: int, clear: bool, config: DedupConfig) -> float:
    """Worst over sampled frames of the best residual over neighbouring frames (grey levels).

    The worst, not the mean: a copy agrees with its original at every sampled moment, while two
    takes of a task on repeat can agree at most of them and still differ at one (a forklift
    passing, the gripper holding a box). On the tuning seeds copies stayed at most 8.0 either
    way; the nearest different footage went from 19.0 (mean) to 29.6 (worst).

    Tries both whole pictures, then the crop hypothesis ``hyp`` (> 0: a whole ~ b crop; < 0: b
    whole ~ a crop), refining the alignment with ECC only for near misses.
    """
    far = 3.5 * config.residual_max
    centre = config.time_radius
    score = far + 1.0
    for h in dict.fromkeys((0, hyp)):
        template, moving = (sa, sb) if h >= 0 else (sb, sa)
        t = template.thumbs[:, centre].astype(np.float32)
        m = moving.thumbs.astype(np.float32)
        warp = _crop_matrix(config.crops[abs(h)], config.thumb_size)
        # Gates measured on synthetic sets like tests/tasks/curate/test_dedup.py's: copies stayed
        # under 2.5x residual_max before alignment (crops between hypotheses, frames a step
        # apart); most look-alikes of one simulator-like scene were above 3.5x.
        quick = float(_residual(t, m[:, centre:centre + 1], warp).mean())
        if quick > far:
            score = min(score, quick)
            continue
        residual = _residual(t, m, warp)
        score = min(score, float(residual.min(axis=1).max()))
        # Copies under the whole-picture hypothesis (re-encoded, rescaled, letterboxed, brighter)
        # landed within 1.5x; only a clear crop between two hypotheses earns more alignment work.
        if score <= config.residual_max:
            break
        if score > (far if h and clear else 1.5 * config.residual_max):
            continue
        structure = np.argsort([-cv2.Laplacian(x, cv2.CV_32F).var() for x in t], kind="stable")
        for k in structure[:2]:
            refined = _refine(t[k], m[k, residual[k].argmin()], warp)
            if refined is not None:
                score = min(score, float(_residual(t, m, refined).min(axis=1).max()))
                if score <= config.residual_max:
                    break
        if score <= config.residual_max:
            break
    return score


def group(
    signatures: Mapping[str, ClipSignature],
    quality: Mapping[str, tuple],
    config: DedupConfig = DedupConfig(),
    exact: Callable[[list[str]], Mapping[str, ClipSignature]] | None = None,
) -> DedupResult:
    """Group duplicate clips and keep the best of each group.

    quality: clip id -> comparable tuple, higher is better (see ``quality_key``); ties go to
    the smallest clip id. Clips without an entry rank lowest. ``exact``, given the ids of
    clips whose signatures are not exact and that reach the pixel check, returns their
    signatures from exactly the sampled frames: two copies of fast motion agree only at the
    same moments, and the analysis pass may have decoded each at different ones.
    """
    ids = sorted(signatures)
    if not ids:
        return DedupResult(groups={}, kept=(), removed={})
    size, offsets = config.thumb_size, 2 * config.time_radius + 1
    want = ((config.frames, len(config.crops)), (config.frames, offsets, size, size))
    for i in ids:
        have = (signatures[i].hashes.shape, signatures[i].thumbs.shape)
        if have != want:
            raise ValueError(f"dedup.group: clip {i}: signature shapes {have} do not fit this config {want}: made with another config?")
    hashes = np.stack([signatures[i].hashes for i in ids])
    pairs = _candidates(hashes, config)
    dist, hyp, clear = _hash_distance(hashes, pairs)
    close = _nearest(pairs, dist, config)
    redecode = sorted({ids[i] for i in np.unique(pairs[close]) if not signatures[ids[i]].exact})
    if exact is not None and redecode:
        signatures = {**signatures, **{k: v for k, v in exact(redecode).items() if k in signatures}}
    neighbours: dict[str, set[str]] = {}
    verified = 0
    for p in close:
        a, b = ids[pairs[p, 0]], ids[pairs[p, 1]]
        if _footage_distance(signatures[a], signatures[b], int(hyp[p]), bool(clear[p]), config) <= config.residual_max:
            neighbours.setdefault(a, set()).add(b)
            neighbours.setdefault(b, set()).add(a)
            verified += 1
    # Best first: by id, then (stable sort) by quality descending.
    order = sorted(sorted(ids), key=lambda i: quality.get(i, ()), reverse=True)
    rank = {c: r for r, c in enumerate(order)}
    keeper: dict[str, str] = {}
    for c in order:
        reps = [n for n in neighbours.get(c, ()) if keeper.get(n) == n]
        keeper[c] = min(reps, key=rank.__getitem__) if reps else c
    groups: dict[str, list[str]] = {}
    for c in order:
        groups.setdefault(keeper[c], []).append(c)
    return DedupResult(
        groups={k: (k, *sorted(m for m in v if m != k)) for k, v in sorted(groups.items())},
        kept=tuple(sorted(groups)),
        removed={c: k for c, k in sorted(keeper.items()) if c != k},
        candidates=len(pairs),
        hash_pairs=int((dist <= config.hash_max).sum()),
        checked=len(close),
        verified=verified,
        redecoded=len(redecode) if exact is not None else 0,
    )


def quality_key(clip: ClipRecord, config: DedupConfig = DedupConfig()) -> tuple[int, float]:
    """(pixels, config.quality_score) of a clip, higher is better; a missing score ranks lowest."""
    return clip.width * clip.height, float(clip.scores.get(config.quality_score, float("-inf")))


def apply(clips: Iterable[ClipRecord], signatures: Mapping[str, ClipSignature], result: DedupResult) -> list[ClipRecord]:
    """Clip records with phash set and dedup_group = the kept clip's id.

    Removed copies are marked rejected by stage "dedup" with reason "duplicate" (one reason, so
    counts per reason stay meaningful; the kept copy is their dedup_group).
    """
    out = []
    for clip in clips:
        update: dict = {}
        if clip.clip_id in signatures:
            update["phash"] = signatures[clip.clip_id].phash
        kept = result.removed.get(clip.clip_id)
        if kept is not None:
            update.update(dedup_group=kept, kept=False, reject_stage="dedup", reject_reason="duplicate")
        elif clip.clip_id in result.groups:
            update["dedup_group"] = clip.clip_id
        out.append(clip.model_copy(update=update))
    return out

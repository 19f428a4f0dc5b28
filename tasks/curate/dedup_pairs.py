"""Which clips are copies of each other: candidate pairs from banded LSH on the signature
hashes, their Hamming distance under the best crop hypothesis, and the pixel check.

Grouping runs in three passes, each costlier per pair than the last and each seeing fewer pairs:
banded LSH on 16-bit bands of the hashes proposes candidates (never all n^2 pairs), the mean
Hamming distance under the best crop hypothesis prunes them (keeping each clip's
``max_neighbours`` nearest), and a pixel check accepts a pair only when the thumbnails agree
everywhere once aligned (a crop hypothesis, ECC-refined for near misses) and offset for
brightness, at every sampled frame (each at the best of its neighbouring frames).
That last check is what keeps apart different footage of the same simulator scene, whose hashes
differ in a few bits: a copy differs from its original by codec noise spread thinly, different
footage by an object somewhere else, which a high percentile of the residual sees.
"""

from __future__ import annotations

import cv2
import numpy as np

from tasks.curate.dedup_signature import ClipSignature, Crop, DedupConfig

BAND_BITS = 16
CROP_MARGIN = 0.05  # fraction of hash bits
QUANTILE = 0.995  # of the residual: different footage differs somewhere, copies nowhere
BANDS = 64 // BAND_BITS


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


def candidates(hashes: np.ndarray, config: DedupConfig) -> np.ndarray:
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


def hash_distance(hashes: np.ndarray, pairs: np.ndarray, chunk: int = 50_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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


def nearest(pairs: np.ndarray, dist: np.ndarray, config: DedupConfig) -> np.ndarray:
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


def crop_matrix(crop: Crop, size: int) -> np.ndarray:
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


def pixel_residual(template: np.ndarray, moving: np.ndarray, warp: np.ndarray) -> np.ndarray:
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


def footage_distance(sa: ClipSignature, sb: ClipSignature, hyp: int, clear: bool, config: DedupConfig) -> float:
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
        warp = crop_matrix(config.crops[abs(h)], config.thumb_size)
        # Gates measured on synthetic sets like tests/tasks/curate/test_dedup.py's: copies stayed
        # under 2.5x residual_max before alignment (crops between hypotheses, frames a step
        # apart); most look-alikes of one simulator-like scene were above 3.5x.
        quick = float(pixel_residual(t, m[:, centre:centre + 1], warp).mean())
        if quick > far:
            score = min(score, quick)
            continue
        residual = pixel_residual(t, m, warp)
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
                score = min(score, float(pixel_residual(t, m, refined).min(axis=1).max()))
                if score <= config.residual_max:
                    break
        if score <= config.residual_max:
            break
    return score

"""Gradual transitions (fades through black, dissolves) found on per-frame statistics: mean
luma, gradient energy, and a blurred 64-px grey thumbnail.

- a fade through black is a luma valley near black with monotone ramps either side
  (ThresholdDetector would give one cut mid-fade; the ramps are what must be excluded).
  A side that leaves black in one step of at least ``FADE_JUMP`` of its rise (a linear ramp
  of r frames climbs 1 / (r + 1) per step) is a hard cut into or out of black, not a ramp:
  a cut to black then a fade in is a cut, a too-short black span and a fade of the ramp
  frames; a fade out then a cut out of black is a fade, the black span and a cut;
- a dissolve is a span whose frames are well explained as blends (1-w) P + w Q of the
  frames P and Q either side, with w rising steadily. Candidates come from a dip of the
  gradient energy (a blend of unrelated shots is half as sharp mid-way) or from a peak of
  the change across a few frames. Camera motion leaves a large blend residual; a hard cut
  shows as a jump of w. Smooth real motion (handheld shake, a zoom, a head turning, auto-
  exposure) can still fit a blend on blurred thumbnails, so a candidate is also tested as
  motion: if its two ends are one view (correlation >= ``dissolve_same_view`` at the best
  shift of up to a tenth of the picture) and local motion plus a gain explains its middle
  frame about as well as the blend does (motion residual < ``dissolve_motion`` x blend
  residual, each of 4 x 4 blocks shifted on its own), it is motion, not a dissolve. A real
  dissolve's middle frame holds half of the other shot, which no shift of one end gives
  (ratio 2.4-21 on the corpus dissolves, 0.45-1.2 on the dev set's handheld false ones);
  two views of one place far apart still dissolve (ends unalike after a shift).
"""

from __future__ import annotations

import numpy as np

from tasks.curate.scene_config import SceneConfig, Span
from tasks.curate.views import motion_residual, same_view

FADE_JUMP = 0.6  # share of a fade side's luma rise taken in one step that makes the side a hard cut


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of each run of True."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def _fades(luma: np.ndarray, h: int, max_len: int, config: SceneConfig, ended: bool) -> list[Span]:
    """Fades through black: the darkest frame within h either side, near black, with luma
    ramps (at least two frames) out to shots at least ``fade_depth`` brighter."""
    n = len(luma)
    found = []
    for v in np.flatnonzero(luma <= config.fade_black):
        lo, hi = max(0, v - h), min(n, v + h + 1)
        if luma[v] > luma[lo:hi].min() or np.any(luma[lo:v] <= luma[v]) or (v + h >= n and not ended):
            continue  # not the first darkest frame around, or not yet seen in full
        floor = luma[v] + 2.0

        def out(t: int, nxt: int) -> bool:  # is frame nxt one step further out along a ramp?
            # A ramp climbs about (luma - floor) / distance per frame; content drifting in
            # the shot next to the fade climbs far slower.
            slope = (luma[nxt] - floor) / (abs(nxt - v) + 1)
            return luma[nxt] <= floor or luma[nxt] - luma[t] > max(config.fade_step, 0.015 * luma[nxt], 0.25 * slope)

        a = b = int(v)
        while a > 0 and b - a < max_len and out(a, a - 1):
            a -= 1
        while b < n - 1 and b - a < max_len and out(b, b + 1):
            b += 1
        if b - a > max_len or (b == n - 1 and not ended):
            continue
        ramps = b - a - 1 - int(np.sum(luma[a + 1: b] <= floor))
        if ramps < 2 or max(luma[a], luma[b]) < luma[v] + config.fade_depth:
            continue  # a dark shot between hard cuts, not a fade
        end = b + 1 if b == n - 1 and out(b - 1, b) else b
        # A side reached in one step of most of its rise is a hard cut into or out of black,
        # not a ramp (a linear ramp of r frames climbs 1 / (r + 1) of the rise per step).
        cut_in = a < v and luma[a] - luma[a + 1] >= FADE_JUMP * (luma[a] - luma[v])
        cut_out = end == b and b > v and luma[b] - luma[b - 1] >= FADE_JUMP * (luma[b] - luma[v])
        if cut_in and cut_out:
            continue
        if cut_in:  # the cut at the first black frame; the fade starts where luma leaves black
            start = a + 1
            while start < end and luma[start] <= floor:
                start += 1
            found += [(a + 1, a + 1, "cut"), (start, end, "fade")]
        elif cut_out:  # the fade ends at the first black frame; the cut at the new shot's first
            stop = b - 1
            while stop > a + 1 and luma[stop - 1] <= floor:
                stop -= 1
            found += [(a + 1, stop, "fade"), (b, b, "cut")]
        else:
            found.append((a + 1, end, "fade"))
    return found


def _blend_fit(thumbs: np.ndarray, a: int, b: int) -> tuple[float, float, float, float] | None:
    """How well frames a..b-1 are blends (1-w) P + w Q of P = thumbs[a-1] and Q = thumbs[b].

    Returns (mean |Q - P|, mean residual / mean |Q - P|, correlation of w with time, largest
    step of w, ends included).
    """
    p, q = thumbs[a - 1].ravel(), thumbs[b].ravel()
    inner = thumbs[a:b].reshape(b - a, -1)
    direction = q - p
    norm = float(direction @ direction)
    if norm <= 0:
        return None
    w = (inner - p) @ direction / norm
    change = float(np.abs(direction).mean())
    residual = float(np.abs(inner - p - w[:, None] * direction).mean()) / change
    order = float(np.corrcoef(w, np.arange(len(w)))[0, 1]) if np.ptp(w) > 0 else 0.0
    jump = float(np.abs(np.diff(np.concatenate([[0.0], w, [1.0]]))).max())
    return change, residual, order, jump


def _motion_vs_blend(thumbs: np.ndarray, a: int, b: int) -> float:
    """The middle frame of a..b-1: its residual as local motion of either end over its
    residual as a blend of the two (> 1: the blend explains it better)."""
    p, q, m = thumbs[a - 1], thumbs[b], thumbs[(a + b) // 2]
    d = q - p
    w = float(((m - p) * d).sum() / max(float((d * d).sum()), 1e-9))
    blend = float(np.abs(m - p - w * d).mean())
    return min(motion_residual(p, m), motion_residual(q, m)) / max(blend, 1e-6)


def change_gap(max_len: int) -> int:
    """k of the dissolve finder's change across 2k frames, for transitions up to ``max_len``."""
    return max(2, (max_len // 2 + 2) // 3)


def frame_change(thumbs: np.ndarray, gap: int) -> np.ndarray:
    """N float64: change[i] = mean |thumbs[i] - thumbs[i - 2 gap]| of N x th x tw float32
    thumbnails (0 for the first 2 gap frames). Each value depends only on its two frames, so
    a stream can append one per frame instead of measuring every window again."""
    change = np.zeros(len(thumbs))
    change[2 * gap:] = np.abs(thumbs[2 * gap:] - thumbs[: len(thumbs) - 2 * gap]).mean(axis=(1, 2))
    return change


def _dissolves(sharp: np.ndarray, thumbs: np.ndarray, h: int, max_len: int, config: SceneConfig,
               ended: bool, cache: dict, offset: int, change: np.ndarray | None) -> list[Span]:
    """Dissolves: for each candidate centre, the best-fitting blend span of a few widths."""
    n = len(sharp)
    pad = np.full(h, -np.inf)
    windows = np.lib.stride_tricks.sliding_window_view(np.concatenate([pad, sharp, pad]), h + 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        dip = np.nan_to_num(sharp / np.minimum(windows[:n].max(axis=1), windows[h: h + n].max(axis=1)), nan=1.0)
    centres = {(r0 + r1) // 2: (r0, r1) for r0, r1 in _runs(dip < config.dissolve_edge)
               if r1 - r0 <= max_len + 2 and dip[r0:r1].min() <= config.dissolve_dip}
    # Shots of unequal sharpness need not dip: also try where the change across 2k frames
    # peaks at 1.5 times its level 3k frames either side.
    k = change_gap(max_len)
    if n > 8 * k:
        dk = np.zeros(n)
        dk[k: n - k] = (frame_change(thumbs, k) if change is None else change)[2 * k:]
        c = np.arange(4 * k, n - 4 * k)
        peak = ((dk[c] >= config.dissolve_min_change) & (dk[c] >= dk[c - 1]) & (dk[c] > dk[c + 1])
                & (dk[c] >= 1.5 * np.minimum(dk[c - 3 * k], dk[c + 3 * k])))
        for centre in c[peak].tolist():
            centres.setdefault(centre, (centre - k // 2, centre + k // 2 + 1))
    found = []
    for c, (r0, r1) in sorted(centres.items()):
        if c + max_len // 2 + h >= n and not ended:
            continue
        best = None
        for a, b in {(r0, r1)} | {(c - m, c + m + 1) for m in (k // 2, k, 3 * k // 2, 2 * k)}:
            a, b = max(a, 1), min(b, n - 1)
            if b - a < 3 or b - a > max_len:
                continue
            key = (a + offset, b + offset)
            if key not in cache:
                cache[key] = _blend_fit(thumbs, a, b)
            fit = cache[key]
            if (fit is not None and fit[0] >= config.dissolve_min_change and fit[1] <= config.dissolve_residual
                    and fit[2] >= 0.8 and fit[3] <= config.dissolve_max_step and (best is None or fit[1] < best[0])):
                # Two moments of one shot (ends alike after a shift) whose middle frame local
                # motion explains about as well as a blend does: camera or subject motion.
                if key + ("motion",) not in cache:
                    cache[key + ("motion",)] = (_motion_vs_blend(thumbs, a, b) >= config.dissolve_motion
                                                or same_view(thumbs[a - 1], thumbs[b]) < config.dissolve_same_view)
                if cache[key + ("motion",)]:
                    best = (fit[1], a, b)
        if best is not None:
            found.append((best[1], best[2], "dissolve"))
    return found


def find_transitions(luma: np.ndarray, sharp: np.ndarray, thumbs: np.ndarray, max_len: int,
                     config: SceneConfig, ended: bool = False, cache: dict | None = None,
                     offset: int = 0, change: np.ndarray | None = None) -> list[Span]:
    """Gradual transitions in N frames, as sorted, disjoint (start, end exclusive, kind), and
    (c, c, "cut") for a hard cut into or out of black that borders a fade.

    luma: N mean luma (0..255); sharp: N mean squared grey gradient; thumbs: N x th x tw
    float32 blurred grey thumbnails. Unless the video has ``ended``, candidates that later
    frames could still change are left out. ``cache`` (with ``offset`` added to keys) keeps
    blend fits between calls on overlapping windows. ``change`` is
    ``frame_change(thumbs, change_gap(max_len))`` when the caller keeps it already (the first
    2 gap values are not read).
    """
    h = max_len // 2 + 2
    fades = _fades(luma, h, max_len, config, ended)
    dissolves = _dissolves(sharp, thumbs, h, max_len, config, ended, {} if cache is None else cache, offset,
                           change)
    # A fade is also a blend (with black); its luma ramps bound it better than a blend fit.
    found = sorted(fades + [d for d in dissolves if not any(d[0] < b and a < d[1] for a, b, _ in fades)])
    cuts = [span for span in found if span[2] == "cut"]
    merged: list[Span] = []
    for a, b, kind in (span for span in found if span[2] != "cut"):
        if merged and a <= merged[-1][1]:
            pa, pb, pkind = merged[-1]
            merged[-1] = (pa, max(pb, b), "fade" if "fade" in (kind, pkind) else kind)
        else:
            merged.append((a, b, kind))
    return sorted(merged + [c for c in cuts if not any(a < c[0] < b for a, b, _ in merged)])

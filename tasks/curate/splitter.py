"""The streaming scene split: ``SceneSplitter`` takes analysis frames one at a time and gives
back spans (scenes, too short shots, transitions) as soon as no later frame can change them.

Hard cuts come from a PySceneDetect detector (``detectors.py``) fed frame by frame, with
FrameTimecodes built from the frames' timestamps, and pass the checks of ``cut_checks.py``;
fades and dissolves come from ``transitions.py``; the rows it keeps and the spans cut from
them from ``scene_rows.py``.

The analysis decode leaves out frames nothing predicts from (``skip_unreferenced``), which
stretches the detector's window and moves its ratio: on sintel.mp4 it lost three cuts a full
decode finds. Where the two decoded frames around such a gap differ by at least the
detector's own floor (``min_content_val``, measured with its HSV score), the frames between
them are decoded exactly (``exact.ExactFrames``) and pushed in order, and so are the gaps over
the next ``adaptive_window`` frames: every cut candidate is then scored on the frames a full
decode gives. Below that floor no cut can be hiding in the gap.

A decoder that loses a slice conceals it by stretching rows into vertical streaks
(``tasks/curate/smear.py``) and often holds that picture until the next intra frame. Neither
the smeared frame nor the change where the picture comes back, right after it or after the
held copies of it, is a cut (armwrestle.mp4: smear at 229, held 231-267, back at 268); the
smeared frames are listed in the decode report and reject their clip (quality ``smeared``).
"""

from __future__ import annotations

from collections.abc import Callable
from fractions import Fraction

import cv2
import numpy as np
from scenedetect.common import FrameTimecode, Timecode
from scenedetect.detector import FlashFilter

from tasks.curate.cut_checks import picture_cuts, unrelated, view_returns
from tasks.curate.decode import AnalysisFrame
from tasks.curate.detectors import RgbAdaptiveDetector, RgbContentDetector
from tasks.curate.scene_config import Scene, SceneConfig, Span
from tasks.curate.scene_rows import MAX_FILL, SceneRows, frame_features
from tasks.curate.smear import SMEAR_MIN
from tasks.curate.transitions import change_gap, find_transitions

MICROSECOND = Fraction(1, 1_000_000)
MAX_REFILL = 16  # longest run of frames decoded on demand: H.264 allows at most 16 B-frames in a row
HELD_STEP = 0.5  # mean grey change (blurred thumbnail) under which a decoded frame repeats the one before


def _detector(config: SceneConfig):
    if config.detector == "content":
        return RgbContentDetector(threshold=config.content_threshold, min_scene_len=config.min_cut_gap_s,
                                  filter_mode=FlashFilter.Mode.SUPPRESS)
    return RgbAdaptiveDetector(adaptive_threshold=config.adaptive_threshold, min_scene_len=config.min_cut_gap_s,
                               window_width=config.adaptive_window, min_content_val=config.min_content_val,
                               weak_threshold=config.cut_weak_ratio if config.cut_weak_ratio < config.adaptive_threshold
                               else None)


class SceneSplitter(SceneRows):
    """Push analysis frames in order; get spans back as soon as they are final.

    ``for f in frames: handle(splitter.push(f))`` then ``handle(splitter.finish())``. Spans
    come out in order and tile the pushed frames: kept ``scene``s, ``too_short`` shots and
    ``transition``s. ``fps`` is the source's average rate (it sizes windows in frames).
    """

    def __init__(self, fps: float, config: SceneConfig = SceneConfig(), keep_frames: bool = True,
                 exact: Callable[[list[int]], list[AnalysisFrame]] | None = None):
        max_len = max(3, round(config.max_transition_s * fps))
        super().__init__(fps, config, keep_frames, change_gap(max_len))
        # Frames a fast decode left out, decoded exactly on demand (``exact.ExactFrames``):
        # asked for where the two decoded frames around them suggest a boundary.
        self.exact = exact
        self.refilled = 0  # frames pushed from ``exact``
        self.exact_until = -1  # frames up to this index are all decoded
        self.last_hsv: np.ndarray | None = None  # HSV of the last frame pushed (``frame_features``)
        self.max_len = max_len
        # Frames after which no boundary can change, and context kept before the open span.
        self.lag = self.max_len + 2 * (self.max_len // 2 + 2) + config.adaptive_window + 2
        self.absorb = max(2, round(0.25 * fps))  # a detector cut this near a transition is it
        self.detector = _detector(config)
        self.rate = Fraction(self.fps).limit_denominator(1001)
        self.cuts: list[int] = []  # positions of first frames after a hard cut
        self.head: list[np.ndarray] = []  # unblurred thumbnails of the first frames (see finish)
        self.cut_checks: dict[int, bool] = {}  # cut position: rejected by _view_returns
        self.weak: list[int] = []  # positions of detector peaks below its threshold (see _unrelated)
        self.weak_checks: dict[int, bool] = {}  # weak peak position: confirmed by _unrelated
        self.peak: np.ndarray | None = None  # running maximum of the unblurred thumbnails (letterbox bars)
        self.fits: dict = {}
        self.by_pts: dict[int, int] = {}
        self.open = 0  # position where the open span starts
        self.open_cause = "start"
        self.checked = 0  # frontier of the previous settle
        self.settled = -16  # rows at the previous settle, less one
        self.last: tuple | None = None  # (index, time, luma, thumb, sharp) of the last decoded frame
        self.smeared: list[int] = []  # source frame numbers of concealment-smeared frames (tasks/curate/smear.py)
        self.last_smear = -1  # position of the last smeared frame
        self.held_from = 0  # position where the current run of unchanged decoded frames starts
        self.recovered: set[int] = set()  # positions where a smeared or held-after-smear picture ends

    def push(self, frame: AnalysisFrame) -> list[Scene]:
        """Take the next frame (in decoded order); return the spans that became final.

        Positions count source frames: when one or two frame numbers were skipped (the
        analysis pass leaves out frames nothing predicts from), each gets a row whose
        statistics are interpolated between its neighbours, so every window of the transition
        finder spans the same time whichever frames were decoded. The rows carry no picture:
        spans hold only decoded frames. Longer gaps (frames lost to errors) are not filled.
        """
        features = frame_features(frame.image)
        out: list[Scene] = []
        if self.exact is not None and self.last is not None and 1 < frame.index - self.last[0] <= MAX_REFILL + 1 \
                and self.last_hsv is not None and self.last_hsv.shape == features[6].shape:
            # A cut between the two decoded frames changes the picture across the gap at least
            # about as much as it does between its own two frames, and the detector never cuts
            # below min_content_val: under that, the frames left out cannot hold a cut.
            # The frames after one are decoded too, as far as the detector's window reaches,
            # so that the candidate's ratio is measured against neighbours one frame apart.
            change = cv2.absdiff(features[6], self.last_hsv)
            if frame.index <= self.exact_until or float(np.mean(change)) >= self.config.min_content_val:
                if frame.index > self.exact_until:
                    self.exact_until = frame.index + self.config.adaptive_window + 1
                for extra in self.exact(list(range(self.last[0] + 1, frame.index))):
                    if self.last[0] < extra.index < frame.index:
                        self.refilled += 1
                        out += self._push(extra, frame_features(extra.image))
        self.last_hsv = features[6]
        return out + self._push(frame, features)

    def _push(self, frame: AnalysisFrame, features) -> list[Scene]:
        luma, thumb, sharp, small, raw, smear, hsv = features
        held = self.last is not None and float(np.abs(thumb - self.last[3]).mean()) < HELD_STEP
        if self.last is not None and 1 < frame.index - self.last[0] <= MAX_FILL + 1:
            i0, t0, l0, th0, s0, r0 = self.last
            steps = frame.index - i0
            for k in range(1, steps):
                w = k / steps
                self._row(i0 + k, t0 + w * (frame.time - t0), (1 - w) * l0 + w * luma, (1 - w) * th0 + w * thumb,
                          (1 - w) * s0 + w * sharp, None, decoded=False, raw=(1 - w) * r0 + w * raw)
        gap = frame.index - self.last[0] if self.last is not None else 1
        self.last = (frame.index, frame.time, luma, thumb, sharp, raw)
        pos = self._row(frame.index, frame.time, luma, thumb, sharp, frame.image, decoded=True, raw=raw)
        self._corruption(pos, frame.index, smear, held)
        self.peak = raw.copy() if self.peak is None or self.peak.shape != raw.shape else np.maximum(self.peak, raw)
        if pos < 2 * self.config.adaptive_window and pos == len(self.head):
            self.head.append(raw)
        pts = round(frame.time / MICROSECOND)
        self.by_pts[pts] = pos
        code = FrameTimecode(Timecode(pts=pts, time_base=MICROSECOND), fps=self.rate)
        for cut in self.detector.process_frame(code, small, gap, hsv):
            self.cuts.append(self.by_pts.get(cut.pts, pos))
        weak = getattr(self.detector, "weak", None)  # peaks below the threshold (see _unrelated)
        if weak:
            self.weak += [self.by_pts.get(cut.pts, pos) for cut in weak]
            weak.clear()
        if len(self.by_pts) > 64:
            del self.by_pts[next(iter(self.by_pts))]
        if pos - self.settled < 16:
            return []
        self.settled = pos
        return self._settle(pos + 1 - self.lag)

    def _corruption(self, pos: int, index: int, smear: float, held: bool) -> None:
        """Mark where a decoder's concealment ends. A smeared frame (``smear.SMEAR_MIN``) is the
        stream breaking, not a new shot, and decoders often hold the broken picture until the
        next intra frame: the change where the picture comes back, right after the smear or
        after the held copies of it (each changing less than ``HELD_STEP`` from the one before),
        is the stream recovering, not a cut. Neither marks a cut (armwrestle.mp4: smear at 229,
        held 231-267, the picture back at 268)."""
        if smear >= SMEAR_MIN:
            self.smeared.append(index)
            self.last_smear = pos
            self.recovered.add(pos)
        elif not held and self.last_smear >= max(0, self.held_from - 2):
            self.recovered.add(pos)
        if not held:
            self.held_from = pos

    def finish(self) -> list[Scene]:
        """The remaining spans, once the last frame has been pushed."""
        if self.pushed < 1 + 2 * self.config.adaptive_window and self.config.detector == "adaptive":
            # The detector's window never filled: no frame was judged. Each pair of frames is
            # judged on the pictures instead (slides one frame each).
            self.cuts += picture_cuts(self.head, self.config)
        out = self._settle(self.pushed, final=True)
        out += self._close(self.open, self.pushed, self.open_cause)
        self.open = self.pushed
        return out

    def _boundaries(self, final: bool) -> list[Span]:
        spans: list[Span] = []
        if self.config.transitions and self.pushed > self.base:
            # Search only where a new boundary can still start, with `lag` frames of context
            # before it (spans nearer the window's edge could be artefacts of the edge).
            start = max(self.open, self.checked - self.max_len)
            lo = max(self.base, start - self.lag)
            found = find_transitions(self.luma.view(lo - self.base), self.sharp.view(lo - self.base),
                                     self.thumbs.view(lo - self.base), self.max_len, self.config,
                                     ended=final, cache=self.fits, offset=lo, change=self.change.view(lo - self.base))
            spans = [(a + lo, b + lo, kind) for a, b, kind in found if a + lo >= start]
        near = self.absorb
        found = sorted(self.cuts)
        gap = max(1, round(self.config.min_cut_gap_s * self.fps))
        for c in sorted(self.weak):
            if not any(abs(c - k) < gap for k in found) and self._unrelated(c):
                found = sorted(found + [c])
        cuts = [(c, c, "cut") for c in found if not any(a - near <= c < b + near for a, b, _ in spans)
                and c not in self.recovered and not self._view_returns(c, final)]
        return sorted(s for s in spans + cuts if s[0] > self.open or (s[2] != "cut" and s[1] > self.open))

    def _unrelated(self, cut: int) -> bool:
        """``cut_checks.unrelated`` of the pictures either side of a weak detector peak, once a peak."""
        if cut not in self.weak_checks:
            if cut - 1 < self.base:
                return False
            before, after = self.raw.view(cut - 1 - self.base)[:2]
            self.weak_checks[cut] = unrelated(before, after, self.peak, self.config)
        return self.weak_checks[cut]

    def _view_returns(self, cut: int, final: bool) -> bool:
        """``cut_checks.view_returns`` of a detector cut, once the frames it needs are pushed."""
        if cut in self.cut_checks:
            return self.cut_checks[cut]
        last = cut + max(1, round(self.config.cut_return_s * self.fps))
        if cut - 1 < self.base or (last >= self.pushed and not final):
            return False  # (not yet decided: a cut is only used max_len frames after it)
        back = min(round(self.config.cut_enter_s * self.fps), cut - 1 - self.base)
        until = min(last, self.pushed - 1) - cut + back + 2
        self.cut_checks[cut] = view_returns(self.thumbs.view(cut - 1 - back - self.base), back, until, self.peak,
                                            cut in self.weak_checks, self.config)
        return self.cut_checks[cut]

    def _settle(self, frontier: int, final: bool = False) -> list[Scene]:
        out: list[Scene] = []
        for a, b, kind in self._boundaries(final):
            if not final and (b > frontier or (kind == "cut" and a + self.max_len > frontier)):
                break  # a transition found later may still swallow a recent cut
            a = max(a, self.open)
            out += self._close(self.open, a, self.open_cause)
            if kind == "cut":
                self.open, self.open_cause = a, "cut"
            else:
                out.append(self._span("transition", a, b, "cut" if a > self.open else self.open_cause, kind))
                self.open, self.open_cause = b, "transition"
        if not final:
            out += self._trim_long(frontier)
            self.checked = max(self.checked, frontier)
            if len(self.fits) > 4096:  # fits far behind the frontier are never asked for again
                self.fits = {key: fit for key, fit in self.fits.items() if key[0] > frontier - 2 * self.lag}
        self._forget()
        return out

    def _trim_long(self, frontier: int) -> list[Scene]:
        start_time = self._time(self.open)
        if frontier <= self.open or self._time(frontier) - start_time <= 2 * self.config.max_scene_s:
            return []
        times = np.asarray(self.times[self.open - self.base: frontier - self.base])
        end = self.open + int(np.searchsorted(times, start_time + self.config.max_scene_s))
        part = self._span("scene", self.open, end, self.open_cause, split_after=True)
        self.open, self.open_cause = end, "split"
        return [part]

    def _forget(self) -> None:
        if not self._forget_rows(self.open, self.open - self.lag):
            return
        self.cuts = [c for c in self.cuts if c >= self.base]
        self.weak = [c for c in self.weak if c >= self.base]
        self.recovered = {c for c in self.recovered if c >= self.base}
        self.fits = {key: fit for key, fit in self.fits.items() if key[0] > self.base}

"""Video-type filter: physical footage versus animation, slides, screens and test patterns.

Camera footage and physically based renders share statistics that drawn content lacks:
shading gradients and texture make most pixels differ from their neighbours, colours are
many, and edges point every way. Drawn content is made of flat fills bounded by crisp
edges. Measured on ``n_samples`` frames inside the letterbox:

- ``flat``: fraction of pixels whose 5x5 neighbourhood spans at most ``flat_range`` grey
  levels in every channel (a fill; codec ringing is smoothed away first);
- ``crisp``: of the pixels that are not flat, the fraction whose neighbourhood spans more
  than ``crisp_range`` levels (a fill boundary; a dark shot is flat but its edges are soft);
- ``colours``: how many 4-bit-per-channel colours cover 95 % of the contrast-stretched
  picture (``filter_base.palette_size``);
- ``axis_edges``: share of long-edge pixels (Canny components spanning 15 % of the short
  side) whose gradient lies within 4 degrees of horizontal or vertical (bars, grids);
- ``lines``: share of gradient energy in the 5 % strongest columns and rows of its
  projection (edges running through the whole picture);
- ``saturated``: fraction of strongly saturated pixels (colour bars);
- ``still``: fraction of pixels that never change over the sampled frames; ``change``:
  median fraction that changes from a sampled frame to the next frame (slides barely do).

A small decision list maps these to a type; the allow/block lists say which types pass.

Rendered films (3D CGI, cel animation) are scored against camera footage by a small logistic
regression fitted by ``bench/fit_video_type.py`` on real and corpus clips; its coefficients
live in ``video_type_model.json``. Its inputs are ``smooth`` (share of soft shading gradients,
0.5-4 grey levels a pixel: a film render lights its surfaces smoothly), ``bflat`` (flat fills
that survive a bilateral filter, i.e. codec blocking and grain) and ``edge_kurtosis`` (kurtosis
of the gradient magnitude: a clean render is smooth shading with a few sparse edges, footage has
texture and grain everywhere). Its probability is reported as ``type_rendered``; it decides only
when ``rendered_min`` is set (the fit's threshold is 0.9). Fitted on the 26 real videos in
../shared/data and three tuning seeds of the corpus, it raises the leave-one-video-out accuracy
on the real files (physical or not) from 0.846 with the rules alone to 0.885: it catches
Caminandes and keeps every camera file and the aloha simulator render, but misses Sintel (p about
0.9, under the threshold in most windows), Popeye (HEVC blocking) and the film leader. On the
corpus it calls 12 of 138 held-out physical segments rendered (blurred, noisy and a few clean
procedural renders: the platform's simulator footage is itself rendered), so by default it
reports and does not reject (figures in the JSON's ``evaluation``).
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import ClassVar, Literal

import cv2
import numpy as np

from tasks.curate.filter_base import (
    FilterConfig,
    Verdict,
    active_box,
    check_frames,
    judged_once,
    palette_size,
    sample_indices,
)

VideoType = Literal["physical", "animation", "slides", "test_pattern", "screen"]


class VideoTypeConfig(FilterConfig):
    stage: ClassVar[str] = "video_type"

    allow: tuple[VideoType, ...] = ("physical",)
    block: tuple[VideoType, ...] = ()  # blocked even when allowed
    n_samples: int = 8
    flat_range: int = 3
    # Drawn content: a handful of flat colours (camera footage and renders have dozens).
    drawn_colours: float = 8.0
    # Bars and grids: long edges nearly all axis-aligned, a still picture, a modest palette.
    long_edge: float = 0.15  # an edge is long from this fraction of the short side
    pattern_colours: float = 64.0
    pattern_axis: float = 0.75
    pattern_still: float = 0.75
    bars_saturated: float = 0.6  # colour bars: strongly saturated ...
    bars_axis: float = 0.6  # ... with mostly axis-aligned long edges
    steps_colours: float = 16.0  # grey steps and ramps: a dozen shades, frozen, axis-aligned
    steps_still: float = 0.97
    steps_axis: float = 0.55
    # Drawn and (nearly) never changing from one frame to the next: slides. On the tuning seeds
    # every deck measured 0 and the slowest cartoon 0.007.
    slides_change: float = 0.002
    # ... or each picture stays on screen this long (s, the median time from a sampled frame to
    # the next): a variable-frame-rate deck stores one frame per page, so every stored frame
    # differs from the next, yet each is held for seconds; animation runs at 8 or more a second.
    slides_hold_s: float = 0.4
    # A page held on screen: mostly flat fills, nothing changing between samples, and a palette
    # that anti-aliased text on a coloured ground widens past drawn_colours but that stays far
    # below footage's (a frozen camera shot keeps its shading: dozens of colours, little flat).
    page_colours: float = 20.0
    page_flat: float = 0.6  # slides measured 0.67-0.74; a flat-shaded sim render (aloha) 0.56
    page_crisp: float = 0.25  # a still dark shot is as flat with as few colours, but soft (crisp 0.0)
    # A held page whose text is finer still (more anti-aliased shades, less flat): what gives it
    # away is that nearly every pixel that is not flat sits on a hard edge. On the tuning seeds
    # slides measured crisp 0.64-0.82 at 7-25 colours; footage of at most 40 colours and half
    # flat at most 0.38 (a frozen shot 0.23, a dark one 0.0), and no footage at all reached
    # crisp 0.6 and half flat with fewer than 114 colours.
    deck_colours: float = 40.0
    deck_flat: float = 0.5
    deck_crisp: float = 0.55
    # A moving cartoon with shaded or anti-aliased fills has a dozen colours or more, but it is
    # still mostly flat and its non-flat pixels are hard fill boundaries. Underexposed footage is
    # as flat with as few colours, but its edges are soft (crisp 0.0 against 0.34-0.46).
    crisp_range: int = 40
    cartoon_colours: float = 20.0
    cartoon_flat: float = 0.78
    cartoon_crisp: float = 0.25
    # Screen captures are not in the corpus; this rule is deliberately strict (a still
    # warehouse aisle render has axis edges 0.72 and lines 0.42).
    screen_axis: float = 0.85
    screen_lines: float = 0.5
    screen_still: float = 0.95
    # The fitted rendered-versus-camera model (see the module docstring): scenes the rules call
    # physical become "animation" at this probability or above; None: never decides.
    rendered_min: float | None = None
    # Measure the model's inputs and report type_rendered even when it does not decide. Off by
    # default: its bilateral filter on 8 samples is about a fifth of the analysis pass's filter
    # time, spent on a score nothing reads (bench/curate_speed.py).
    measure_rendered: bool = False

    def judge(self, frames: np.ndarray, times: np.ndarray) -> Verdict:
        return judge(frames, times, self)  # the module's judge below


MODEL_PATH = Path(__file__).with_name("video_type_model.json")


@lru_cache(maxsize=4)
def load_model(path: str = str(MODEL_PATH)) -> dict | None:
    """The fitted model (features, standardisation, coefficients), or None if it is absent."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def model_inputs(scores: dict[str, float], features: list[str], log: list[str]) -> np.ndarray:
    """The model's input vector from a scene's scores (log-scaled where the model says)."""
    return np.array([np.log(scores[f] + 1e-2) if f in log else scores[f] for f in features], np.float64)


def rendered_probability(scores: dict[str, float], model: dict | None = None) -> float:
    """Probability that a scene is a rendered film rather than camera footage (nan: no model)."""
    model = model if model is not None else load_model()
    if not model:
        return float("nan")
    x = (model_inputs(scores, model["features"], model["log"]) - np.asarray(model["mean"])) / np.asarray(model["scale"])
    z = float(x @ np.asarray(model["coef"]) + model["intercept"])
    return float(1.0 / (1.0 + np.exp(-z)))


def edge_kurtosis(frame: np.ndarray) -> float:
    """Kurtosis of the grey gradient magnitude of one h x w x 3 uint8 RGB frame: high when a few
    sparse edges sit on smooth shading (a render), low when texture and grain are everywhere."""
    g = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY).astype(np.float32)
    mag = cv2.magnitude(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)) / 8.0
    m, v = float(mag.mean()), float(mag.var())
    return float(((mag - m) ** 4).mean() / (v * v + 1e-9))


def shading(frame: np.ndarray) -> tuple[float, float]:
    """(smooth, bflat) of one h x w x 3 uint8 RGB frame. ``smooth``: fraction of pixels whose grey
    gradient (after a 5x5 Gaussian) is 0.5-4 levels a pixel, soft shading as a film render lights
    its surfaces (flat fills have none, texture and edges more). ``bflat``: fraction of pixels whose
    5x5 neighbourhood spans at most 6 levels in every channel after an edge-keeping bilateral filter
    (fills that survive codec blocking and grain)."""
    g = cv2.GaussianBlur(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY).astype(np.float32), (5, 5), 0)
    mag = cv2.magnitude(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)) / 8.0
    smooth = float(((mag > 0.5) & (mag < 4.0)).mean())
    soft = cv2.bilateralFilter(np.ascontiguousarray(frame), 7, 30, 5)
    k = np.ones((5, 5), np.uint8)
    span = _channel_max(cv2.subtract(cv2.dilate(soft, k), cv2.erode(soft, k)))
    return smooth, float((span <= 6).mean())


def frame_features(frame: np.ndarray, config: VideoTypeConfig) -> tuple[float, ...]:
    """(flat, colours, axis_edges, lines, saturated, crisp) of one h x w x 3 uint8 RGB frame."""
    soft = cv2.GaussianBlur(frame, (3, 3), 0)
    k = np.ones((5, 5), np.uint8)
    span = _channel_max(cv2.subtract(cv2.dilate(soft, k), cv2.erode(soft, k)))  # dilate >= erode: no clipping
    flat = float((span <= config.flat_range).mean())
    crisp = float((span > config.crisp_range).mean() / max(1.0 - flat, 1e-6))
    colours = palette_size(frame)
    grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    g = grey.astype(np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1)
    # Orientation of long edges only: glyphs of a burned-in counter or caption are short and
    # point every way, the boundaries of bars and grids are long and axis-aligned.
    edges = cv2.Canny(grey, 60, 150)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(edges, connectivity=8)
    long_ids = np.zeros(n, bool)
    long_ids[1:] = np.maximum(stats[1:, 2], stats[1:, 3]) >= config.long_edge * min(grey.shape)
    on_long = long_ids[labels]
    if on_long.sum() >= 20:
        angle = np.degrees(np.arctan2(np.abs(gy[on_long]), np.abs(gx[on_long])))
        axis_edges = float((np.minimum(angle, 90.0 - angle) <= 4.0).mean())
    else:
        axis_edges = 0.0
    # Lines that run through the whole picture (bars, grids) pile their gradient into a few
    # columns or rows of the projection; perspective and texture spread it out.
    ax, ay = np.abs(gx), np.abs(gy)
    lines = (_top_share(ax.mean(axis=0)) * ax.sum() + _top_share(ay.mean(axis=1)) * ay.sum()) / (ax.sum() + ay.sum() + 1e-6)
    hsv = cv2.cvtColor(frame, cv2.COLOR_RGB2HSV)
    saturated = cv2.countNonZero(cv2.inRange(hsv, (0, 160, 100), (255, 255, 255))) / (hsv.shape[0] * hsv.shape[1])
    return flat, colours, axis_edges, float(lines), saturated, crisp


def _channel_max(a: np.ndarray) -> np.ndarray:
    """``a.max(axis=-1)`` of a ... x 3 uint8 array, channel by channel (numpy reduces a 3-wide
    last axis an order of magnitude slower; the result is the same)."""
    if a.ndim == 3:
        r, g, b = cv2.split(a)
        return cv2.max(cv2.max(r, g), b)
    return np.maximum(np.maximum(a[..., 0], a[..., 1]), a[..., 2])


def _top_share(profile: np.ndarray, share: float = 0.05) -> float:
    """Fraction of a 1-D profile's total held by its top ``share`` of entries."""
    k = max(1, int(share * profile.size))
    return float(np.sort(profile)[-k:].sum() / (profile.sum() + 1e-6))


def classify(scores: dict[str, float], config: VideoTypeConfig) -> str:
    """The video type named by the features in ``scores`` (see the module docstring)."""
    still = scores["colours"] <= config.pattern_colours and scores["still"] >= config.pattern_still
    pattern = still and (
        scores["axis_edges"] >= config.pattern_axis
        or (scores["saturated"] >= config.bars_saturated and scores["axis_edges"] >= config.bars_axis)
        or (config.drawn_colours < scores["colours"] <= config.steps_colours and scores["still"] >= config.steps_still
            and scores["axis_edges"] >= config.steps_axis))
    if pattern:
        return "test_pattern"
    held = scores["change"] <= config.slides_change or scores.get("hold_s", 0.0) >= config.slides_hold_s
    page = held and ((scores["colours"] <= config.page_colours and scores["flat"] >= config.page_flat
                      and scores["crisp"] >= config.page_crisp)
                     or (scores["colours"] <= config.deck_colours and scores["flat"] >= config.deck_flat
                         and scores["crisp"] >= config.deck_crisp))
    cartoon = (scores["colours"] <= config.cartoon_colours and scores["flat"] >= config.cartoon_flat
               and scores["crisp"] >= config.cartoon_crisp)
    if scores["colours"] <= config.drawn_colours or page or cartoon:
        return "slides" if held else "animation"
    if (scores["axis_edges"] >= config.screen_axis and scores["lines"] >= config.screen_lines
            and scores["still"] >= config.screen_still):
        return "screen"
    return "physical"


@judged_once
def judge(frames: np.ndarray, times: np.ndarray, config: VideoTypeConfig) -> Verdict:
    """Judge the content type of one scene: frames T x h x w x 3 uint8 RGB, times T seconds."""
    if not config.enabled:
        return Verdict(keep=True)
    check_frames(frames, times)
    index = sample_indices(len(frames), config.n_samples)
    picked = frames[index]
    top, bottom, left, right = active_box(picked)
    picked = picked[:, top:bottom, left:right]
    features = np.array([frame_features(f, config) for f in picked])
    grey = _channel_max(picked).astype(np.int16)
    still = float(((grey.max(axis=0) - grey.min(axis=0)) <= 6).mean())
    # Change from each sample to the frame after it: a deck changes in rare jumps, a cartoon
    # every frame (samples seconds apart would see every slide change of a quick deck).
    after = _channel_max(frames[np.minimum(index + 1, len(frames) - 1), top:bottom, left:right]).astype(np.int16)
    steps = index + 1 < len(frames)
    change = float(np.median((np.abs(after - grey) > 6)[steps].mean(axis=(1, 2)))) if steps.any() else 0.0
    scores = dict(zip(("flat", "colours", "axis_edges", "lines", "saturated", "crisp"), map(float, np.median(features, axis=0))))
    scores["still"] = still
    scores["change"] = change
    scores["hold_s"] = float(np.median(np.diff(times)[index[steps]])) if steps.any() else 0.0
    kind = classify(scores, config)
    if config.measure_rendered or config.rendered_min is not None:
        scores["edge_kurtosis"] = float(np.median([edge_kurtosis(f) for f in picked]))
        scores["smooth"], scores["bflat"] = map(float, np.median([shading(f) for f in picked], axis=0))
        scores["rendered"] = rendered_probability(scores)
    if kind == "physical" and config.rendered_min is not None and scores["rendered"] >= config.rendered_min:
        kind = "animation"
    keep = kind in config.allow and kind not in config.block
    return Verdict(keep=keep, reason=None if keep else f"non_physical:{kind}",
                   scores={f"type_{k}": v for k, v in scores.items()}, tags=(f"type:{kind}",))


def looks_drawn(frames: np.ndarray, times: np.ndarray) -> bool:
    """Whether the default video-type rules call a scene anything but physical footage: the
    other filters leave exposure and stillness of drawn pages to this one. The same samples as
    the filter's own verdict (with fewer, a deck the filter rejects as slides could still read
    as footage here, and be rejected twice: as static and as slides)."""
    return "type:physical" not in judge(frames, times, VideoTypeConfig()).tags

"""Video-type filter: physical footage versus colour bars, slides and flat animation, with
allow and block lists."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest

from tasks.curate.filter_base import palette_size
from tasks.curate.video_type import VideoTypeConfig, _channel_max, _top_share, classify, frame_features, judge

H, W, FPS, T = 144, 256, 30.0, 60
TIMES = np.arange(T) / FPS
FONT = cv2.FONT_HERSHEY_SIMPLEX


def footage(seed: int = 0) -> np.ndarray:
    """A pan over shaded texture with objects, plus mild sensor noise: camera-like."""
    rng = np.random.default_rng(seed)
    big = cv2.resize(rng.random((24, 70, 3)).astype(np.float32), (W + 120, H), interpolation=cv2.INTER_CUBIC)
    big = np.clip(big * 170 + 40, 0, 255).astype(np.uint8)
    for _ in range(60):
        c = tuple(int(v) for v in rng.integers(20, 235, 3))
        cv2.circle(big, (int(rng.integers(W + 120)), int(rng.integers(H))), int(rng.integers(3, 12)), c, -1)
    frames = np.stack([big[:, i:i + W] for i in range(T)]).astype(np.float32)
    return np.clip(frames + rng.normal(0, 2.0, frames.shape), 0, 255).astype(np.uint8)


def colour_bars() -> np.ndarray:
    bars = [(191, 191, 191), (191, 191, 0), (0, 191, 191), (0, 191, 0), (191, 0, 191), (191, 0, 0), (0, 0, 191)]
    base = np.zeros((H, W, 3), np.uint8)
    for i, c in enumerate(bars):
        base[: H * 2 // 3, i * W // 7:(i + 1) * W // 7] = c
    base[H * 3 // 4:, : W // 3] = (0, 33, 76)
    base[H * 3 // 4:, W // 3: 2 * W // 3] = (255, 255, 255)
    frames = np.repeat(base[None], T, axis=0)
    for t in range(T):  # a running counter, as test signals carry
        cv2.rectangle(frames[t], (88, 78), (168, 98), (0, 0, 0), -1)
        cv2.putText(frames[t], f"00:00:{t // 30:02d}:{t % 30:02d}", (92, 93), FONT, 0.4, (255, 255, 255), 1)
    return frames


def slides() -> np.ndarray:
    frames = np.empty((T, H, W, 3), np.uint8)
    for t in range(T):
        frames[t] = (246, 244, 238)
        frames[t, :22] = (0, 84, 147)
        cv2.putText(frames[t], "Fleet summary", (10, 16), FONT, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        for k in range(1 + t // 20):  # bullets build in
            cv2.circle(frames[t], (16, 44 + 22 * k), 2, (0, 84, 147), -1)
            cv2.putText(frames[t], "route planning and loads", (24, 48 + 22 * k), FONT, 0.35, (30, 30, 34), 1, cv2.LINE_AA)
    return frames


def animation() -> np.ndarray:
    frames = np.empty((T, H, W, 3), np.uint8)
    for t in range(T):
        frames[t] = (142, 202, 230)
        frames[t, 100:] = (106, 153, 78)
        cv2.circle(frames[t], (30 + 3 * t, 60), 18, (230, 57, 70), -1, cv2.LINE_AA)
        cv2.circle(frames[t], (30 + 3 * t, 60), 18, (20, 20, 24), 2, cv2.LINE_AA)
        pts = np.array([[200 - 2 * t, 90], [230 - 2 * t, 90], [215 - 2 * t, 60]], np.int32)
        cv2.fillPoly(frames[t], [pts], (255, 183, 3), cv2.LINE_AA)
    return frames


def test_footage_is_physical_even_letterboxed_or_black_and_white():
    cfg = VideoTypeConfig()
    frames = footage()
    assert judge(frames, TIMES, cfg).tags == ("type:physical",)
    boxed = np.zeros_like(frames)
    boxed[:, 16:128] = frames[:, 16:128]
    assert judge(boxed, TIMES, cfg).keep
    mono = np.repeat(frames.mean(axis=3, keepdims=True).astype(np.uint8), 3, axis=3)
    assert judge(mono, TIMES, cfg).keep


def test_drawn_content_is_rejected_with_its_type():
    cfg = VideoTypeConfig()
    assert judge(colour_bars(), TIMES, cfg).reason == "non_physical:test_pattern"
    assert judge(slides(), TIMES, cfg).reason == "non_physical:slides"
    assert judge(animation(), TIMES, cfg).reason == "non_physical:animation"


def test_allow_and_block_lists():
    allow_slides = VideoTypeConfig(allow=("physical", "slides"))
    assert judge(slides(), TIMES, allow_slides).keep
    assert not judge(colour_bars(), TIMES, allow_slides).keep
    no_footage = VideoTypeConfig(block=("physical",))
    verdict = judge(footage(), TIMES, no_footage)
    assert not verdict.keep and verdict.reason == "non_physical:physical"


def test_classify_decision_list():
    cfg = VideoTypeConfig()
    base = {"flat": 0.1, "colours": 120.0, "axis_edges": 0.25, "lines": 0.1, "saturated": 0.0, "still": 0.1, "change": 0.5,
            "crisp": 0.3}
    assert classify(base, cfg) == "physical"
    assert classify({**base, "colours": 3.0, "change": 0.0}, cfg) == "slides"
    assert classify({**base, "colours": 3.0, "change": 0.2}, cfg) == "animation"
    assert classify({**base, "colours": 20.0, "axis_edges": 0.9, "still": 0.95}, cfg) == "test_pattern"
    # Axis-aligned long edges alone (a corridor, shelves) are not a test pattern while things move.
    assert classify({**base, "colours": 20.0, "axis_edges": 0.9, "still": 0.3}, cfg) == "physical"


def dark_slides() -> np.ndarray:
    """A slide deck on a dark coloured ground with anti-aliased light text, two slides: the
    anti-aliasing widens the palette past drawn_colours, as in the corpus's dark slides."""
    frames = np.empty((T, H, W, 3), np.uint8)
    for t in range(T):
        k = t // 30
        frames[t] = (38, 52, 71) if k == 0 else (61, 29, 44)
        cv2.putText(frames[t], "Quarterly review" if k == 0 else "Sensor roadmap", (14, 24), cv2.FONT_HERSHEY_DUPLEX,
                    0.6, (235, 235, 235), 1, cv2.LINE_AA)
        for j in range(4):
            cv2.putText(frames[t], "safety metrics team launch", (24, 56 + 20 * j), FONT, 0.4, (235, 235, 235), 1,
                        cv2.LINE_AA)
    return frames


def test_held_page_with_a_wider_palette_is_slides_but_frozen_footage_is_not():
    cfg = VideoTypeConfig()
    page = dark_slides()
    verdict = judge(page, TIMES, cfg)
    assert verdict.reason == "non_physical:slides", verdict.scores
    # Frozen camera footage: nothing changes either, but shading keeps its palette wide.
    frozen = np.repeat(footage()[:1], T, axis=0)
    assert judge(frozen, TIMES, cfg).keep
    base = {"flat": 0.7, "colours": 18.0, "axis_edges": 0.3, "lines": 0.2, "saturated": 0.0, "still": 0.9, "change": 0.0,
            "crisp": 0.3}
    assert classify(base, cfg) == "slides"
    assert classify({**base, "colours": cfg.page_colours + 1}, cfg) == "physical"
    assert classify({**base, "flat": cfg.page_flat - 0.01}, cfg) == "physical"
    assert classify({**base, "change": 0.2}, cfg) == "physical"  # a moving dark scene of a few tones
    assert classify({**base, "crisp": 0.0}, cfg) == "physical"  # a still dark scene: soft edges
    # Finer text: more shades and less flat, but every non-flat pixel on a hard edge.
    deck = {**base, "colours": 26.0, "flat": 0.57, "crisp": 0.7}
    assert classify(deck, cfg) == "slides"
    assert classify({**deck, "crisp": 0.4}, cfg) == "physical"  # a frozen shot's edges are soft
    assert classify({**deck, "colours": cfg.deck_colours + 1}, cfg) == "physical"
    assert classify({**deck, "flat": cfg.deck_flat - 0.01}, cfg) == "physical"
    assert classify({**deck, "change": 0.2}, cfg) == "physical"


def shaded_cartoon() -> np.ndarray:
    """Ten differently coloured discs sliding over a sky and a lawn: more colours than
    drawn_colours, but flat fills bounded by hard edges."""
    rng = np.random.default_rng(1)
    colours = [tuple(int(c) for c in rng.integers(30, 240, 3)) for _ in range(10)]
    frames = np.empty((T, H, W, 3), np.uint8)
    for t in range(T):
        frames[t] = (142, 202, 230)
        frames[t, 100:] = (106, 153, 78)
        for i, c in enumerate(colours):
            cv2.circle(frames[t], ((20 + 47 * i + 2 * t * (1 if i % 2 else -1)) % W, 25 + (i * 37) % 100), 16, c, -1)
    return frames


def test_a_cartoon_with_a_dozen_colours_is_animation_but_a_dark_shot_is_not():
    cfg = VideoTypeConfig()
    frames = shaded_cartoon()
    verdict = judge(frames, TIMES, cfg)
    assert verdict.scores["type_colours"] > cfg.drawn_colours
    assert verdict.reason == "non_physical:animation", verdict.scores
    assert judge(frames, TIMES, cfg.model_copy(update={"cartoon_flat": 1.1})).keep  # the rule is what rejects it
    # An underexposed moving shot is as flat with as few colours, but its edges are soft.
    dark = {"flat": 0.9, "colours": 17.0, "axis_edges": 0.3, "lines": 0.2, "saturated": 0.0, "still": 0.3,
            "change": 0.2, "crisp": 0.0}
    assert classify(dark, cfg) == "physical"
    assert classify({**dark, "crisp": 0.4}, cfg) == "animation"


def frame_features_reference(frame: np.ndarray, config: VideoTypeConfig) -> tuple[float, ...]:
    """``frame_features`` as first written: int16 spans and numpy reductions over channels."""
    soft = cv2.GaussianBlur(frame, (3, 3), 0)
    k = np.ones((5, 5), np.uint8)
    span = (cv2.dilate(soft, k).astype(np.int16) - cv2.erode(soft, k)).max(axis=2)
    flat = float((span <= config.flat_range).mean())
    crisp = float((span > config.crisp_range).mean() / max(1.0 - flat, 1e-6))
    grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    g = grey.astype(np.float32)
    gx, gy = cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(cv2.Canny(grey, 60, 150), connectivity=8)
    long_ids = np.zeros(n, bool)
    long_ids[1:] = np.maximum(stats[1:, 2], stats[1:, 3]) >= config.long_edge * min(grey.shape)
    on_long = long_ids[labels]
    axis_edges = 0.0
    if on_long.sum() >= 20:
        angle = np.degrees(np.arctan2(np.abs(gy[on_long]), np.abs(gx[on_long])))
        axis_edges = float((np.minimum(angle, 90.0 - angle) <= 4.0).mean())
    ax, ay = np.abs(gx), np.abs(gy)
    lines = (_top_share(ax.mean(axis=0)) * ax.sum() + _top_share(ay.mean(axis=1)) * ay.sum()) / (ax.sum() + ay.sum() + 1e-6)
    hsv = cv2.cvtColor(frame, cv2.COLOR_RGB2HSV)
    saturated = float(((hsv[..., 1] >= 160) & (hsv[..., 2] >= 100)).mean())
    return flat, palette_size(frame), axis_edges, float(lines), saturated, crisp


def test_frame_features_equal_the_reference(real_frames):
    config = VideoTypeConfig()
    pictures = [f for frames in real_frames.values() for f in frames[::25]]
    pictures += [footage()[0], colour_bars()[0], slides()[-1], animation()[10], footage()[5][10:130, 20:240]]
    for frame in pictures:
        assert frame_features(frame, config) == frame_features_reference(frame, config)
    stack = np.stack(pictures[-5:-1])
    assert np.array_equal(_channel_max(stack), stack.max(axis=3))
    assert np.array_equal(_channel_max(pictures[-1]), pictures[-1].max(axis=2))


def test_a_quick_deck_is_slides_even_when_every_sample_shows_another_slide():
    """Slides every 8 frames, samples about 8 frames apart: consecutive samples all differ, but
    each sample and the frame after it are the same slide."""
    frames = np.empty((T, H, W, 3), np.uint8)
    for t in range(T):
        frames[t] = (246, 244, 238)
        cv2.putText(frames[t], f"Slide {t // 8}", (14, 30), cv2.FONT_HERSHEY_DUPLEX, 0.8, (20, 20, 60), 2, cv2.LINE_AA)
        cv2.rectangle(frames[t], (20 + 12 * (t // 8), 60), (80 + 12 * (t // 8), 120), (0, 84, 147), -1)
    verdict = judge(frames, TIMES, VideoTypeConfig())
    assert verdict.scores["type_change"] <= VideoTypeConfig().slides_change
    assert verdict.reason == "non_physical:slides", verdict.scores


def lit_render(t: int) -> np.ndarray:
    """A film-like render: a lit sky gradient (about 0.8 grey levels a pixel) and a shaded ball
    crossing it, no grain (a near-flat backdrop reads as a simulator's)."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    sky = 60 + (x + 2 * t) * 0.5 + y * 0.6
    img = np.stack([sky * 0.7, sky * 0.8, sky], -1)
    d = np.sqrt((x - 60 - 3 * t) ** 2 + (y - 80) ** 2)
    ball = np.clip(200 - 2.2 * d, 0, 255)
    img[d < 40] = np.stack([ball, ball * 0.4, ball * 0.3], -1)[d < 40]
    return np.clip(img, 0, 255).astype(np.uint8)


def test_the_fitted_model_scores_a_clean_render_above_camera_footage():
    from tasks.curate.video_type import load_model

    model = load_model()
    assert model is not None and model["features"] and "lovo" in model["evaluation"]
    render = np.stack([lit_render(t) for t in range(24)])
    camera = footage()[:24]
    times = TIMES[:24]
    measured = VideoTypeConfig(measure_rendered=True)
    r, c = judge(render, times, measured), judge(camera, times, measured)
    # The rules call both physical (dozens of colours, moving); the model tells them apart.
    assert "type:physical" in r.tags and "type:physical" in c.tags
    assert r.scores["type_edge_kurtosis"] > 3 * c.scores["type_edge_kurtosis"]
    assert r.scores["type_rendered"] > 10 * c.scores["type_rendered"]
    # By default the model reports and does not decide; rendered_min lets it.
    threshold = (r.scores["type_rendered"] + c.scores["type_rendered"]) / 2
    assert judge(render, times, VideoTypeConfig(rendered_min=threshold)).reason == "non_physical:animation"
    assert judge(camera, times, VideoTypeConfig(rendered_min=threshold)).keep


def test_real_cgi_scores_above_real_camera_footage():
    from tasks.curate.decode import analysis_frames
    from tasks.curate.video_type import load_model
    from tests.support import SHARED_DATA

    folder = SHARED_DATA / "videos-dev"
    if not (folder / "sintel.mp4").is_file():
        pytest.skip("../shared/data is absent")
    p = {}
    for name in ("caminandes.mp4", "tos.mp4", "hikers.mp4"):
        frames = np.stack([f.image for f in itertools.islice(analysis_frames(folder / name), 60)])
        p[name] = judge(frames, np.arange(len(frames)) / 24.0, VideoTypeConfig(measure_rendered=True)).scores["type_rendered"]
    threshold = load_model()["evaluation"]["threshold"]
    assert p["caminandes.mp4"] >= threshold > max(p["tos.mp4"], p["hikers.mp4"]), p


def test_a_variable_frame_rate_deck_with_one_frame_per_page_is_slides():
    # As slides.avi stores it: one frame per page, each shown for about a second, so every
    # stored frame differs from the next; a cartoon with the same frames at 30 fps is animation.
    pages = slides()[[0, 20, 40, 59]]
    assert judge(pages, np.array([0.0, 1.1, 2.2, 3.3]), VideoTypeConfig()).reason == "non_physical:slides"
    cartoon = animation()
    assert judge(cartoon, TIMES, VideoTypeConfig()).reason == "non_physical:animation"


def test_shading_sees_soft_gradients_and_fills_under_blocking():
    from tasks.curate.video_type import shading

    yy, xx = np.mgrid[0:H, 0:W]
    sky = np.clip(90 + xx * 0.45 + yy * 0.6, 0, 255)  # a lit render: soft shading everywhere
    render = np.stack([sky * 0.7, sky * 0.8, sky], -1).astype(np.uint8)
    cv2.circle(render, (128, 80), 40, (180, 60, 40), -1)
    assert shading(render)[0] > 0.6 > 0.3 > shading(footage()[0])[0] > shading(animation()[0])[0]
    # A two-colour cel fill under 8x8 codec blocks and grain: the plain flat measure loses half
    # of it, the bilateral one keeps it; textured footage stays far from flat either way.
    rng = np.random.default_rng(0)
    cel = np.zeros((H, W, 3), np.float32)
    cel[:] = (200, 170, 120)
    cel[40:100, 60:180] = (60, 120, 200)
    blocks = np.kron(rng.normal(0, 2, (H // 8, W // 8)), np.ones((8, 8)))[..., None]
    cel = np.clip(cel + blocks + rng.normal(0, 1.5, cel.shape), 0, 255).astype(np.uint8)
    assert shading(cel)[1] > 0.9 > 0.6 > frame_features(cel, VideoTypeConfig())[0]
    assert shading(footage()[0])[1] < 0.2
    scores = judge(footage(), TIMES, VideoTypeConfig(measure_rendered=True)).scores
    assert 0 <= scores["type_smooth"] <= 1 and 0 <= scores["type_bflat"] <= 1

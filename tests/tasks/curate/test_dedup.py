"""Dedup: copies (re-encoded, rescaled, cropped, letterboxed, brightness-shifted) collapse to
one group; different clips of the same generator, and of the same simulator-like scene, do not."""

from __future__ import annotations

import itertools
import random

import av
import cv2
import numpy as np
import pytest

from schemas.records import ClipRecord
from tasks.curate import dedup, dedup_pairs
from tasks.curate.dedup import ClipSignature, DedupConfig, group, quality_key, signature

H, W, T = 144, 256, 40


def _texture(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    img = np.zeros((h, w, 3), np.float32)
    for octave, amp in ((4, 1.0), (8, 0.6), (16, 0.35), (32, 0.2)):
        small = rng.normal(size=(octave * h // w + 2, octave + 2, 3)).astype(np.float32)
        img += amp * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    img = (img - img.min()) / (img.max() - img.min())
    return (40 + 180 * img).astype(np.uint8)


def drifting(seed: int) -> np.ndarray:
    """Procedural 'drifting textured landscape': one generator, content set by the seed."""
    rng = np.random.default_rng(seed)
    big = _texture(rng, 2 * H, 2 * W)
    vx, vy = rng.uniform(-2, 2, 2)
    return np.stack([big[int(H / 2 + vy * t):int(H / 2 + vy * t) + H, int(W / 2 + vx * t):int(W / 2 + vx * t) + W] for t in range(T)])


def _background() -> np.ndarray:
    bg = np.zeros((H, W, 3), np.uint8)
    bg[: H // 3] = (90, 100, 110)
    bg[H // 3:] = (150, 140, 120)
    cv2.rectangle(bg, (90, 70), (170, 130), (60, 80, 140), -1)
    cv2.rectangle(bg, (98, 76), (162, 124), (40, 50, 90), -1)
    return bg


def arm_scene(cell: int) -> np.ndarray:
    """Simulator-like: one fixed scene, an arm moving between end points that sit on a 12 px
    grid by ``cell``, so two cells' paths differ by at least 12 px (5% of the width) somewhere."""
    bg = _background()
    base = np.array([40, 120])
    assert 0 <= cell < 12
    p0 = np.array([80, 50]) + 12 * np.array([cell % 4, cell // 4])
    k = cell * 5 % 12  # another walk over the same 4 x 3 grid
    p1 = np.array([170, 85]) + 12 * np.array([k % 4, k // 4])
    frames = []
    for t in range(T):
        f = bg.copy()
        ee = p0 + (p1 - p0) * t / (T - 1)
        elbow = (base + ee) / 2 + np.array([0, -30])
        pts = [tuple(int(v) for v in p) for p in (base, elbow, ee)]
        cv2.rectangle(f, (122, 92), (138, 108), (180, 120, 60), -1)
        cv2.line(f, pts[0], pts[1], (200, 200, 210), 7)
        cv2.line(f, pts[1], pts[2], (200, 200, 210), 5)
        cv2.circle(f, pts[2], 5, (30, 30, 30), -1)
        frames.append(f)
    return np.stack(frames)


def _decode(path) -> np.ndarray:
    with av.open(str(path)) as container:
        return np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])


def _resize(frames: np.ndarray, w: int, h: int) -> np.ndarray:
    return np.stack([cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA) for f in frames])


def crop(frames: np.ndarray, frac: float, ax: float, ay: float, keep_size: bool) -> np.ndarray:
    h, w = frames.shape[1:3]
    ch, cw = round(h * (1 - frac)), round(w * (1 - frac))
    y, x = round((h - ch) * ay), round((w - cw) * ax)
    out = frames[:, y:y + ch, x:x + cw]
    return _resize(out, w, h) if keep_size else np.ascontiguousarray(out)


def letterbox(frames: np.ndarray, frac: float) -> np.ndarray:
    h, w = frames.shape[1:3]
    nh = round(h * (1 - frac)) // 2 * 2
    out = np.zeros_like(frames)
    out[:, (h - nh) // 2:(h - nh) // 2 + nh] = _resize(frames, w, nh)
    return out


def brightness(frames: np.ndarray, delta: int) -> np.ndarray:
    return np.clip(frames.astype(np.int16) + delta, 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def corpus(make_video):
    """clip id -> (frames, content id): 12 originals with two copies each, and 8 lone clips."""
    transforms = {
        "reencode": lambda f: _decode(make_video(f, crf=32)),
        "half": lambda f: _resize(f, W // 2, H // 2),
        "crop10": lambda f: crop(f, 0.10, 0.5, 0.5, keep_size=True),
        "crop12_corner": lambda f: crop(f, 0.12, 0.0, 0.0, keep_size=False),
        "crop6_corner": lambda f: crop(f, 0.06, 1.0, 1.0, keep_size=True),
        "letterbox": lambda f: letterbox(f, 0.12),
        "bright+20": lambda f: brightness(f, 20),
        "bright-20": lambda f: brightness(f, -20),
    }
    names = itertools.cycle(transforms)
    clips = {}
    for i in range(10):
        for kind, frames in (("tex", drifting(100 + i)), ("arm", arm_scene(i))):
            cid = f"{kind}{i}"
            clips[cid] = (frames, cid)
            if i >= 6:
                continue  # lone clips: negatives only
            for n in range(2):
                name = next(names)
                # Copies are cut a frame later, as a scene detector may cut a re-encoded copy.
                shift = frames[n:len(frames) - 1 + n]
                clips[f"{cid}_{name}"] = (transforms[name](shift), cid)
    return clips


@pytest.fixture(scope="module")
def signatures(corpus):
    return {cid: signature(frames) for cid, (frames, _) in corpus.items()}


def _pairs(groups) -> set[tuple[str, str]]:
    return {tuple(sorted(p)) for members in groups for p in itertools.combinations(members, 2)}


def test_copies_collapse_and_lookalikes_stay_apart(corpus, signatures):
    quality = {cid: (frames.shape[1] * frames.shape[2],) for cid, (frames, _) in corpus.items()}
    result = group(signatures, quality)
    truth: dict[str, list[str]] = {}
    for cid, (_, content) in corpus.items():
        truth.setdefault(content, []).append(cid)
    found, expected = _pairs(result.groups.values()), _pairs(truth.values())
    missed, wrong = sorted(expected - found), sorted(found - expected)
    assert not missed and not wrong, f"missed {missed}; merged different clips {wrong}"
    # Every original outranks its copies here (larger or equal picture, smaller id).
    assert set(result.kept) == set(truth)
    assert result.removed == {c: content for c, (_, content) in corpus.items() if c != content}
    assert result.candidates < len(corpus) * (len(corpus) - 1) / 2


def test_grouping_does_not_depend_on_order(corpus, signatures):
    quality = {cid: (frames.shape[1] * frames.shape[2],) for cid, (frames, _) in corpus.items()}
    reference = group(signatures, quality)
    ids = list(signatures)
    for seed in range(3):
        random.Random(seed).shuffle(ids)
        shuffled = {cid: signatures[cid] for cid in ids}
        assert group(shuffled, {c: quality[c] for c in reversed(ids)}) == reference


def test_keeps_larger_then_better_then_smallest_id(corpus):
    frames = corpus["tex0"][0]
    sigs = {
        "a_small": signature(_resize(frames, W // 2, H // 2)),
        "b_big_worse": signature(frames),
        "c_big_better": signature(brightness(frames, 10)),
        "d_big_better": signature(brightness(frames, -10)),
    }
    def clip(cid, w, h, q):
        return ClipRecord(clip_id=cid, source_id="s", source_uri="u", start_frame=0, end_frame=T, start_s=0,
                          end_s=T / 25, fps=25, width=w, height=h, scores={"quality": q})
    records = [clip("a_small", W // 2, H // 2, 0.99), clip("b_big_worse", W, H, 0.2),
               clip("c_big_better", W, H, 0.9), clip("d_big_better", W, H, 0.9)]
    result = group(sigs, {r.clip_id: quality_key(r) for r in records})
    assert result.kept == ("c_big_better",)
    assert result.removed == {"a_small": "c_big_better", "b_big_worse": "c_big_better", "d_big_better": "c_big_better"}
    marked = {r.clip_id: r for r in dedup.apply(records, sigs, result)}
    assert marked["c_big_better"].kept and marked["c_big_better"].dedup_group == "c_big_better"
    assert not marked["a_small"].kept and marked["a_small"].reject_stage == "dedup"
    assert marked["a_small"].reject_reason == "duplicate" and marked["a_small"].dedup_group == "c_big_better"
    assert marked["b_big_worse"].phash == sigs["b_big_worse"].phash and len(marked["b_big_worse"].phash) == 16 * 5


def test_grouping_scales_without_all_pairs():
    """2,000 clips of random content and 100 exact copies: candidates stay near the copies."""
    rng = np.random.default_rng(0)
    cfg = DedupConfig()
    n = 2000
    thumbs = rng.integers(0, 255, size=(n, cfg.frames, 2 * cfg.time_radius + 1, 8, 8), dtype=np.uint8)
    thumbs = np.stack([cv2.resize(t.reshape(-1, 8), (cfg.thumb_size, cfg.thumb_size * t.shape[0] * t.shape[1]))
                       .reshape(t.shape[0], t.shape[1], cfg.thumb_size, cfg.thumb_size) for t in thumbs])
    hashes = rng.integers(0, 2**63, size=(n, cfg.frames, len(cfg.crops)), dtype=np.uint64)
    sigs = {f"c{i:05d}": ClipSignature(hashes=hashes[i], thumbs=thumbs[i]) for i in range(n)}
    for i in range(0, 200, 2):
        sigs[f"c{i:05d}"] = sigs[f"c{i + 1:05d}"]
    result = group(sigs, {})
    assert result.candidates < 5 * 100
    assert result.removed == {f"c{i + 1:05d}": f"c{i:05d}" for i in range(0, 200, 2)}


def test_signature_layout_and_bad_input():
    frames = drifting(1)
    sig = signature(frames, DedupConfig(frames=3, time_radius=1, thumb_size=24))
    assert sig.hashes.shape == (3, len(dedup.DEFAULT_CROPS)) and sig.hashes.dtype == np.uint64
    assert sig.thumbs.shape == (3, 3, 24, 24) and sig.thumbs.dtype == np.uint8
    assert signature(frames[:1]).hashes.shape[0] == 5  # a one-frame clip still has every slot
    with pytest.raises(ValueError, match="uint8"):
        signature(frames.astype(np.float32))
    with pytest.raises(ValueError, match="at least one frame"):
        signature(frames[:0])
    with pytest.raises(ValueError, match="clip a: signature shapes .* another config"):
        group({"a": sig, "b": signature(frames)}, {})


def test_a_darkened_copy_of_a_shot_with_a_dim_border_is_found(corpus):
    frames = corpus["arm0"][0].astype(np.int16)
    frames[:, :6] = np.minimum(frames[:, :6], 30)  # a dim border the copy pushes under bar_level
    frames[:, :, :8] = np.minimum(frames[:, :, :8], 30)
    original = np.clip(frames, 0, 255).astype(np.uint8)
    copy = brightness(original, -14)
    result = group({"a": signature(original), "b": signature(copy)}, {})
    assert result.removed == {"b": "a"}


def test_takes_that_differ_at_one_sampled_moment_are_not_copies(corpus):
    """Two takes of a task on repeat can match at most sampled moments: a forklift passing
    through one of them still makes them different footage."""
    frames = corpus["arm1"][0]
    other = frames.copy()
    other[-T // 5:, 40:70, 170:210] = (210, 160, 20)  # something crosses during the last fifth
    sa, sb = signature(frames), signature(other)
    per_frame = dedup_pairs.pixel_residual(sa.thumbs[:, 2].astype(np.float32), sb.thumbs.astype(np.float32),
                                dedup_pairs.crop_matrix(DedupConfig().crops[0], 32)).min(axis=1)
    assert per_frame.mean() <= DedupConfig().residual_max < per_frame.max()  # a mean would merge them
    assert group({"a": sa, "b": sb}, {}).removed == {}


def racing(seed: int, speed: int = 11) -> np.ndarray:
    """A texture passing fast (``speed`` px a frame): a frame apart is a different picture."""
    big = _texture(np.random.default_rng(seed), H, W + speed * T)
    return np.stack([big[:, speed * t: speed * t + W] for t in range(T)])


def test_signature_samples_positions_and_says_when_it_is_not_exact():
    frames = racing(5)
    every = np.arange(T)
    full = signature(frames, positions=every, length=T)
    assert full.exact and np.array_equal(full.thumbs, signature(frames).thumbs)
    odd = signature(frames[1::2], positions=every[1::2], length=T)
    assert not odd.exact and odd.thumbs.shape == full.thumbs.shape
    # Each sampled position takes its nearest decoded frame.
    wanted = dedup.sample_positions(T)
    assert all(np.array_equal(odd.thumbs[f, o], full.thumbs[f, o]) for f in range(5) for o in range(5)
               if wanted[f, o] % 2 == 1)
    with pytest.raises(ValueError, match="increasing frame numbers below length"):
        signature(frames[:3], positions=[0, 2, 1], length=T)
    with pytest.raises(ValueError, match="increasing frame numbers below length"):
        signature(frames[:3], positions=[0, 1, 2], length=2)


def test_copies_decoded_at_different_moments_are_found_with_their_exact_frames():
    # The analysis pass decodes reference frames only, and where they fall depends on each
    # encoding: here the original kept its even frames and a brighter copy its odd ones.
    original = racing(6)
    copy = brightness(original, 12)
    every = np.arange(T)
    approximate = {"a": signature(original[::2], positions=every[::2], length=T),
                   "b": signature(copy[1::2], positions=every[1::2], length=T)}
    exact = {"a": signature(original), "b": signature(copy)}
    asked = []

    def redecode(ids):
        asked.append(list(ids))
        return {i: exact[i] for i in ids}

    assert group(approximate, {}).removed == {}  # a frame apart, fast motion is not a copy
    result = group(approximate, {}, exact=redecode)
    assert result.removed == {"b": "a"} and result.redecoded == 2 and asked == [["a", "b"]]
    assert group(exact, {}, exact=redecode).redecoded == 0 and len(asked) == 1  # exact ones are not asked for

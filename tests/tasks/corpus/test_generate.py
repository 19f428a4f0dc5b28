"""The labelled corpus: truth consistent with the pixels, labels real, duplicates near-identical."""

import json

import av
import cv2
import numpy as np
import pytest

from tasks.corpus.config import CorpusConfig
from tasks.corpus.generate import _content, _segment, corpus_lineage, generate_corpus

SIZE = (128, 72)


def _decode(path):
    with av.open(str(path)) as container:
        return np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    root = tmp_path_factory.mktemp("corpus")
    videos = generate_corpus(root, seed=3, minutes=3.0, n_videos=3, width=SIZE[0], height=SIZE[1], sim_fraction=0.15)
    return root, [(v, json.loads(v.truth.read_text()), _decode(v.video)) for v in videos]


def _grey(frames):
    return frames.astype(np.float32).mean(axis=-1)


def test_truth_tiles_the_video_and_matches_its_frames(corpus):
    _, videos = corpus
    for v, truth, frames in videos:
        spans = sorted([(s["start"], s["end"]) for s in truth["segments"]] +
                       [(t["start"], t["end"]) for t in truth["transitions"]])
        assert spans[0][0] == 0 and spans[-1][1] == truth["n_frames"] == len(frames)
        assert all(a[1] == b[0] for a, b in zip(spans, spans[1:]))
        after_transition = {t["end"] for t in truth["transitions"]}
        assert truth["cuts"] == [s["start"] for s in truth["segments"][1:] if s["start"] not in after_transition]
        assert all(2.5 * truth["fps"] <= s["end"] - s["start"] <= 20 * truth["fps"] for s in truth["segments"])


def test_every_label_appears_and_cuts_are_real(corpus):
    _, videos = corpus
    labels = {s["label"] for _, truth, _ in videos for s in truth["segments"]}
    assert len(labels - {None}) >= 10 and None in labels
    for _, truth, frames in videos:
        g = _grey(frames)
        jumps = np.abs(np.diff(g, axis=0)).mean(axis=(1, 2))
        for s in truth["segments"]:
            if s["label"] is None:
                inside = jumps[s["start"]: s["end"] - 1]
                for cut in truth["cuts"]:
                    if cut == s["start"] or cut == s["end"]:
                        assert jumps[cut - 1] > 2 * np.median(inside) + 1.0, (truth["video"], cut)


def _by_label(videos, label):
    return [frames[s["start"]: s["end"]] for _, truth, frames in videos for s in truth["segments"] if s["label"] == label]


def _clean(videos):
    return [frames[s["start"]: s["end"]] for _, truth, frames in videos for s in truth["segments"]
            if s["label"] is None and s["source"] == "procedural"]


def test_labels_are_measurable(corpus):
    _, videos = corpus
    clean = _clean(videos)
    lap = lambda seg: np.median([cv2.Laplacian(f, cv2.CV_32F).var() for f in _grey(seg[::10])])
    motion = lambda seg: np.abs(np.diff(_grey(seg), axis=0)).mean()
    for seg in _by_label(videos, "static"):
        assert motion(seg) < 1.0
    for seg in _by_label(videos, "blur"):
        assert lap(seg) < 0.3 * np.median([lap(c) for c in clean])
    for seg in _by_label(videos, "overexposed"):
        assert seg.mean() > 170
    for seg in _by_label(videos, "underexposed"):
        assert seg.mean() < 40
    for seg in _by_label(videos, "shake"):
        assert motion(seg) > 2 * np.median([motion(c) for c in clean])


def test_overlay_text_only_touches_the_text_area():
    from tasks.corpus.plan import ContentSpec, SegmentPlan

    for label in ("text_subtitle", "text_logo", "text_timestamp"):
        seg = SegmentPlan(start=0, end=30, label=label, defect_seed=5,
                          content=ContentSpec(content_id="c0", kind="procedural", seed=9, scene="x"))
        config = CorpusConfig()
        with_text = np.stack(list(_segment(seg, 320, 180, 30.0, [], config)))
        plain = np.stack(list(_content(seg, 320, 180, 30.0, [], config)))
        changed = (np.abs(with_text.astype(int) - plain).max(axis=-1) > 0).mean(axis=(1, 2))
        assert (changed > 0.002).all() and (changed < 0.15).all(), label


def test_duplicates_are_near_identical_to_their_originals(corpus):
    _, videos = corpus
    by_name = {truth["video"]: (truth, frames) for _, truth, frames in videos}
    small = lambda seg: np.stack([cv2.resize(f, (32, 18), interpolation=cv2.INTER_AREA) for f in seg[::15]]).astype(float)
    pairs = 0
    for _, truth, frames in videos:
        for s in truth["segments"]:
            ref = s["duplicate_of"]
            if ref is None:
                continue
            otruth, oframes = by_name[ref["video"]]
            o = otruth["segments"][ref["segment"]]
            assert o["content_id"] == s["content_id"] and o["label"] is None
            copy, original = small(frames[s["start"]: s["end"]]), small(oframes[o["start"]: o["end"]])
            assert np.abs(copy - original).mean() < 25, ref["transform"]
            pairs += 1
    assert pairs >= 1


def test_same_seed_same_bytes(tmp_path):
    a = generate_corpus(tmp_path / "a", seed=8, minutes=0.2, width=64, height=36, sim_fraction=0)
    b = generate_corpus(tmp_path / "b", seed=8, minutes=0.2, width=64, height=36, sim_fraction=0)
    c = generate_corpus(tmp_path / "c", seed=9, minutes=0.2, width=64, height=36, sim_fraction=0)
    assert a[0].video.read_bytes() == b[0].video.read_bytes() and a[0].truth.read_text() == b[0].truth.read_text()
    assert a[0].video.read_bytes() != c[0].video.read_bytes()


def test_lineage(corpus):
    root, videos = corpus
    batch = corpus_lineage([v for v, _, _ in videos], "stage", None, root)
    assert sorted({a.kind for a in batch.artifacts}) == ["ground_truth", "raw_video"]
    assert sum(e.relation == "labelled_by" for e in batch.edges) == 3
    assert all(not a.uri.startswith("/") for a in batch.artifacts)


def test_two_takes_of_one_simulator_scene_are_different_footage():
    """Takes start at a time their seed draws: from the same start, two seeds of one scene differ
    only by controller noise, so their opening seconds are the same footage (dedup rightly
    merged such a pair, against a truth that called them different content)."""
    from tasks.corpus.generate import default_manifests
    from tasks.corpus.plan import ContentSpec, SegmentPlan

    sims = default_manifests()
    index = next(i for i, m in enumerate(sims) if m.name == "mobile-rig-aisle")
    camera = sims[index].cameras[0].name

    def take(seed, config):
        spec = ContentSpec(content_id=f"c{seed}", kind="sim", seed=seed, scene="x", manifest=index, camera=camera)
        seg = SegmentPlan(start=0, end=20, label=None, defect_seed=1, content=spec)
        return np.stack(list(_content(seg, 64, 36, 30.0, sims, config))).astype(np.float32)

    same_start = CorpusConfig(sim_take_start_s=0.0)
    assert np.abs(take(11, same_start) - take(12, same_start)).mean() < 1.0
    assert np.abs(take(11, CorpusConfig()) - take(12, CorpusConfig())).mean() > 5.0

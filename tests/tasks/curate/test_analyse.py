"""The per-video analysis: its dedup signatures, cached and exact on demand."""

from __future__ import annotations

import numpy as np

from schemas.records import ClipRecord
from tasks.curate import analyse, dedup
from tasks.curate.config import CurateConfig
from tasks.curate.decode import AnalysisConfig, analysis_frames
from tests.tasks.curate.test_dedup import racing


def test_exact_signatures_equal_those_of_a_pass_decoding_every_frame(make_video, tmp_path):
    path = make_video(np.concatenate([racing(7, 6), racing(8, 6)]), fps=25, gop=15)
    config = CurateConfig()
    every = list(analysis_frames(path, AnalysisConfig(skip_unreferenced=False)))
    skipped = list(analysis_frames(path, config.analysis))
    assert len(skipped) < len(every)
    spans = {"a": (path, 3, 38), "b": (path, 40, 80), "gone": (tmp_path / "deleted.mp4", 0, 10)}
    got = analyse.exact_signatures(spans, config)
    assert sorted(got) == ["a", "b"]  # a source that cannot be opened gives none
    for cid in ("a", "b"):
        _, start, end = spans[cid]
        reference = dedup.signature(np.stack([f.image for f in every[start:end]]), config.dedup)
        assert got[cid].exact
        np.testing.assert_array_equal(got[cid].hashes, reference.hashes)
        np.testing.assert_array_equal(got[cid].thumbs, reference.thumbs)
        inside = [f for f in skipped if start <= f.index < end]
        approximate = dedup.signature(np.stack([f.image for f in inside]), config.dedup,
                                      positions=np.array([f.index for f in inside]) - start, length=end - start)
        assert not approximate.exact and not np.array_equal(approximate.thumbs, reference.thumbs)


def test_a_cached_analysis_keeps_whether_each_signature_is_exact(tmp_path):
    frames = racing(9)
    clips = analyse.VideoAnalysis(source="x.mp4", sha256="0" * 64, bytes=1)
    for cid, positions in (("c1", np.arange(0, 40, 2)), ("c2", np.arange(40))):
        clips.clips.append(ClipRecord(clip_id=cid, source_id="s", source_uri="x.mp4", start_frame=0, end_frame=40,
                                      start_s=0.0, end_s=1.6, fps=25.0, width=256, height=144, kept=True))
        clips.signatures[cid] = dedup.signature(frames[positions], positions=positions, length=40)
    analyse.save(clips, tmp_path / "a.json")
    loaded = analyse.load(tmp_path / "a.json")
    assert {cid: s.exact for cid, s in loaded.signatures.items()} == {"c1": False, "c2": True}

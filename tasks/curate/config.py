"""CurateConfig: every stage's frozen config in one contract, hashed into each input key."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict

from schemas.hashing import content_hash
from tasks.manifests import read_text, safe_mapping, validated
from tasks.curate.captions import CaptionConfig
from tasks.curate.decode import AnalysisConfig
from tasks.curate.dedup import DedupConfig
from tasks.curate.motion import MotionConfig
from tasks.curate.overlay_text import OverlayTextConfig
from tasks.curate.quality import QualityConfig
from tasks.curate.scenes import SceneConfig
from tasks.curate.shards import ShardConfig
from tasks.curate.video_type import VideoTypeConfig
from tasks.guard.config import GuardConfig
from tasks.video import EncodeConfig

VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v")


class CurateConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    analysis: AnalysisConfig = AnalysisConfig()
    scenes: SceneConfig = SceneConfig()
    motion: MotionConfig = MotionConfig()
    quality: QualityConfig = QualityConfig()
    overlay_text: OverlayTextConfig = OverlayTextConfig()
    video_type: VideoTypeConfig = VideoTypeConfig()
    captions: CaptionConfig = CaptionConfig()
    dedup: DedupConfig = DedupConfig(quality_score="sharpness")
    encode: EncodeConfig = EncodeConfig()
    shards: ShardConfig = ShardConfig()
    # Both guards run by default (issue 10). Detection on every 5th frame, with the boxes of the
    # detections either side carried over the frames between, keeps the 20 px floor at a fifth
    # of the cost; `guard: {enabled: false}` turns them off for footage without people.
    guard: GuardConfig = GuardConfig(detect_every=5)

    def filters(self):
        return self.motion, self.quality, self.overlay_text, self.video_type

    def analysis_hash(self) -> str:
        """What decides a video's analysis result (not encoding, sharding or decoder threads)."""
        return content_hash(self.model_dump(mode="json", exclude=DECODER_THREADS, include={
            "analysis", "scenes", "motion", "quality", "overlay_text", "video_type", "captions", "dedup", "guard"}))

    def encode_hash(self) -> str:
        """What decides a kept clip's bytes: the encoder and the face guard (not decoder threads)."""
        return content_hash(self.model_dump(mode="json", exclude=DECODER_THREADS, include={"encode", "guard"}))

    def for_batch(self, videos: int, workers: int) -> CurateConfig:
        """This config for ``videos`` sources on a pool of ``workers``: when every worker has a
        video of its own, each video is decoded on one thread, since FFmpeg's frame threads
        then add only their own overhead (bench/curate_speed.py, 5 videos on 2 workers: the
        curation's CPU fell from 177.6 to 156.8 s, the codec work alone's from 128.3 to
        121.1). Fewer videos than workers keep frame threads, so one video still uses every
        core. Threading set in the config is left alone; it never changes a result, so it is
        not part of any key."""
        if workers < 2 or videos < workers:
            return self
        update = {}
        if not DECODER_THREADS["analysis"] & self.analysis.model_fields_set:
            update["analysis"] = self.analysis.model_copy(update={"thread_type": "NONE"})
        if not DECODER_THREADS["encode"] & self.encode.model_fields_set:
            update["encode"] = self.encode.model_copy(update={"decode_thread_type": "NONE"})
        return self.model_copy(update=update)


# Decoder threading: how fast frames come, never which frames.
DECODER_THREADS = {"analysis": {"thread_type", "threads"}, "encode": {"decode_threads", "decode_thread_type"}}


class ConfigError(ValueError):
    """One line: the file, the field and the problem."""


def load_config(path: Path | str | None) -> CurateConfig:
    """A YAML file of overrides, read like a manifest (safe YAML only), or the defaults.
    Raises ConfigError naming the file and each field's problem."""
    if path is None:
        return CurateConfig()
    where = str(path)
    data = safe_mapping(read_text(Path(path), ConfigError), where, "curate config", ConfigError)
    return validated(CurateConfig, data, where, ConfigError)

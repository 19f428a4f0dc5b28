"""CurateConfig: keys, and decoder threads chosen for a batch."""

from tasks.curate.config import CurateConfig
from tasks.curate.decode import AnalysisConfig
from tasks.curate.encode import EncodeConfig


def test_one_decoder_thread_per_video_only_when_every_worker_has_a_video():
    config = CurateConfig()
    assert config.for_batch(1, 2) is config and config.for_batch(5, 1) is config
    busy = config.for_batch(2, 2)
    assert busy.analysis.thread_type == "NONE" and busy.encode.decode_thread_type == "NONE"
    assert busy.for_batch(1, 2) is busy  # a config is only ever narrowed, never widened back
    chosen = CurateConfig(analysis=AnalysisConfig(thread_type="FRAME", threads=2),
                          encode=EncodeConfig(decode_threads=4)).for_batch(8, 2)
    assert (chosen.analysis.thread_type, chosen.analysis.threads) == ("FRAME", 2)  # set by the user: kept
    assert chosen.encode.decode_thread_type == "AUTO" and chosen.encode.decode_threads == 4


def test_decoder_threads_are_in_no_key():
    config = CurateConfig()
    busy = config.for_batch(4, 2)
    assert busy.analysis_hash() == config.analysis_hash() and busy.encode_hash() == config.encode_hash()
    other = CurateConfig(analysis=AnalysisConfig(long_side=128), encode=EncodeConfig(crf=30))
    assert other.analysis_hash() != config.analysis_hash() and other.encode_hash() != config.encode_hash()

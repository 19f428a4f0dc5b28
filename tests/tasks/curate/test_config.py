"""CurateConfig: keys, decoder threads chosen for a batch, and YAML overrides read safely."""

import re

import pytest

from tasks.curate.config import ConfigError, CurateConfig, load_config
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


def test_overrides_from_yaml(tmp_path):
    assert load_config(None) == CurateConfig()
    path = tmp_path / "curate.yaml"
    path.write_text("analysis: {long_side: 128}\noverlay_text: {action: tag}\n")
    config = load_config(path)
    assert config.analysis.long_side == 128 and config.overlay_text.action == "tag"
    assert config.scenes == CurateConfig().scenes  # everything else stays the default


@pytest.mark.parametrize("text, problem", [
    ("analysis: {long_sid: 128}\n", r"analysis\.long_sid: Extra inputs are not permitted"),
    ("analysis: {long_side: 2}\n", r"analysis\.long_side: Input should be greater than or equal to 16"),
    ("- a list\n", "the top level must be a mapping"),
    ("analysis: {long_side: [1\n", "not valid YAML"),
    ("a: &x 1\nb: *x\n", "alias"),
    ("", "empty curate config"),
])
def test_bad_overrides_name_the_file_and_the_problem(tmp_path, text, problem):
    path = tmp_path / "curate.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=f"curate.yaml: .*{problem}"):
        load_config(path)


def test_a_missing_config_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="nope.yaml: no such file"):
        load_config(tmp_path / "nope.yaml")


@pytest.mark.parametrize("text, problem", [
    # Both crashed curate after the clips were cut: ArrowException, IndexError (issue: bad shard config).
    ('shards: {compression: "bogus"}\n',
     "shards.compression: Input should be 'gzip', 'brotli', 'lz4' or 'zstd'$"),
    ("shards: {resolutions: []}\n", r"shards\.resolutions: Tuple should have at least 1 item after validation, not 0$"),
    # pyarrow refuses any level for these, and the writer always sets one (ArrowInvalid before).
    ("shards: {compression: snappy}\n", "shards.compression: Input should be 'gzip', 'brotli', 'lz4' or 'zstd'$"),
    ("shards: {compression: none}\n", "shards.compression: Input should be 'gzip', 'brotli', 'lz4' or 'zstd'$"),
    ("shards: {compression: gzip, compression_level: 12}\n", r"shards\.compression_level: 12 is outside gzip's levels, 1 to 9$"),
    # libx264 only warned and encoded without these: a typo went unnoticed.
    ("encode: {x264_params: 'keyitn=60'}\n", "encode.x264_params: Value error, x264 has no option 'keyitn'$"),
    ("encode: {x264_params: 'keyint=often'}\n", "encode.x264_params: Value error, x264 cannot read keyint='often'$"),
    ("encode: {x264_params: 'keyint=60:bframes'}\n", "encode.x264_params: Value error, 'bframes' is not key=value"),
])
def test_shard_and_x264_settings_the_writers_cannot_use_are_refused_in_one_line(tmp_path, text, problem):
    path = tmp_path / "curate.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    line = str(info.value)
    assert "\n" not in line and line.startswith(f"{path}: ") and re.search(problem, line), line


@pytest.mark.parametrize("codec", ["gzip", "brotli", "lz4", "zstd"])
def test_every_codec_the_config_takes_writes_a_shard(tmp_path, codec):
    import pyarrow as pa

    from schemas.records import ClipRecord
    from tasks.curate.shards import ShardConfig, read_shard, write_shards

    path = tmp_path / "curate.yaml"
    path.write_text(f"shards: {{compression: {codec}, resolutions: [[100, small]]}}\n")
    config = load_config(path).shards
    assert pa.Codec.is_available(codec) and config == ShardConfig(compression=codec, resolutions=((100, "small"),))
    clip = ClipRecord(clip_id="c0", source_id="s0", source_uri="raw/a.mp4", start_frame=0, end_frame=30, start_s=0.0,
                      end_s=1.0, fps=30.0, width=64, height=48, scores={}, tags=(), caption="a clip")
    shards = write_shards([clip], tmp_path, "ab" * 32, config.model_copy(update={"embed_clips": False}))
    assert [s.uri.split("/")[-3] for s in shards] == ["ltsmall"]
    assert read_shard(tmp_path / shards[0].uri).num_rows == 1

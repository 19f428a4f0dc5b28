"""CurateConfig: keys, decoder threads chosen for a batch, and YAML overrides read safely."""

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

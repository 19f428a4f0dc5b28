"""Captions: the offline facts backend states only known and measured facts; the vlm backend
loads a local transformers model (a tiny random one built here) and never downloads."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from schemas.records import ClipRecord
from tasks.curate.captions import (
    CaptionConfig,
    CaptionContext,
    FactsCaptioner,
    VLMCaptioner,
    facts_caption,
    make_captioner,
)
from tasks.manifests import load

MANIFESTS = Path(__file__).resolve().parents[3] / "manifests"
FRAMES = np.zeros((4, 36, 64, 3), np.uint8)


def _clip(**update) -> ClipRecord:
    clip = ClipRecord(clip_id="clip7", source_id="src", source_uri="raw.mp4", start_frame=30, end_frame=165,
                      start_s=1.0, end_s=5.5, fps=30.0, width=1280, height=720,
                      scores={"motion_mean": 3.21234, "sharpness": 123.4, "luma_mean": 88.0, "shake": 0.1},
                      tags=("type:physical", "exposure:dark", "camera:pan_left"))
    return clip.model_copy(update=update)


def _sentences(text: str) -> list[str]:
    return re.split(r"(?<=\.) (?=[A-Z])", text)


def test_simulator_clip_states_manifest_facts():
    manifest = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    text = make_captioner().caption(FRAMES, _clip(), CaptionContext(manifest=manifest, camera="front_left"))
    assert text == (
        'A simulated robot arm does a bin pick task: "pick the brown package out of the bin and lift it clear". '
        "Seen from the front left camera. "
        "Conditions: dim light (60 lux), a forklift crossing at 1.5 m/s and an occluder hiding 30% of the target. "
        "A 4.5 s clip at 1280x720 and 30 fps. "
        "The camera pans left; dark exposure; physical footage. "
        "Measured mean frame change 3.21 grey levels, sharpness 123 and mean brightness 88 of 255."
    )


@pytest.mark.parametrize("name", sorted(p.name for p in MANIFESTS.glob("*.yaml")))
def test_every_shipped_manifest_captions_cleanly(name):
    manifest = load(MANIFESTS / name)
    text = facts_caption(_clip(), CaptionContext(manifest=manifest))
    assert manifest.task.instruction in text
    for sentence in _sentences(text):
        assert sentence[0].isupper() and sentence.endswith("."), sentence
    assert not re.search(r"None|nan|_", text.replace(manifest.task.instruction, "")), text
    if not manifest.stressors:
        assert "No stressors." in text


def test_plain_footage_says_only_what_was_measured():
    bare = facts_caption(_clip(tags=(), scores={}), CaptionContext())
    assert bare == "A 4.5 s clip at 1280x720 and 30 fps."
    # Tag order from the filters does not change the text; unknown tags are still stated.
    a = facts_caption(_clip(tags=("camera:zoom_in", "overlay:text", "weather:light_rain")), CaptionContext())
    b = facts_caption(_clip(tags=("weather:light_rain", "overlay:text", "camera:zoom_in")), CaptionContext())
    assert a == b and "The camera zooms in; burned-in text; weather light rain." in a
    # Only configured scores, only when finite.
    config = CaptionConfig(scores=("shake", "quality"))
    assert facts_caption(_clip(), CaptionContext(), config).endswith("Measured shake 0.1.")
    assert "Measured" not in facts_caption(_clip(scores={"shake": float("inf")}), CaptionContext(), config)


def test_config_and_frames_are_checked():
    with pytest.raises(ValueError, match="needs model_dir"):
        CaptionConfig(backend="vlm")
    assert isinstance(make_captioner(), FactsCaptioner)
    with pytest.raises(ValueError, match="clip clip7: expected T x h x w x 3 uint8"):
        make_captioner().caption(FRAMES[..., 0], _clip(), CaptionContext())


def _tiny_model(folder: Path) -> None:
    """A randomly initialised ViT encoder + GPT-2 decoder with a 12-word tokenizer, saved to folder."""
    import torch
    from tokenizers import Tokenizer, models, pre_tokenizers
    from transformers import (GPT2Config, PreTrainedTokenizerFast, ViTConfig, VisionEncoderDecoderConfig,
                              VisionEncoderDecoderModel)

    words = ["<pad>", "<s>", "</s>", "<unk>", "a", "robot", "arm", "picks", "box", "the", "forklift", "light"]
    tokenizer = Tokenizer(models.WordLevel({w: i for i, w in enumerate(words)}, unk_token="<unk>"))
    tokenizer.pre_tokenizer = pre_tokenizers.Whitespace()
    PreTrainedTokenizerFast(tokenizer_object=tokenizer, bos_token="<s>", eos_token="</s>", pad_token="<pad>",
                            unk_token="<unk>").save_pretrained(folder)
    encoder = ViTConfig(image_size=32, patch_size=16, hidden_size=16, num_hidden_layers=1, num_attention_heads=2,
                        intermediate_size=32)
    decoder = GPT2Config(vocab_size=len(words), n_positions=64, n_embd=16, n_layer=1, n_head=2,
                         add_cross_attention=True, is_decoder=True, bos_token_id=1, eos_token_id=2, pad_token_id=0)
    config = VisionEncoderDecoderConfig.from_encoder_decoder_configs(encoder, decoder)
    config.decoder_start_token_id, config.pad_token_id, config.eos_token_id = 1, 0, 2
    torch.manual_seed(0)
    VisionEncoderDecoderModel(config=config).save_pretrained(folder)
    _vit_processor()(size={"height": 32, "width": 32}).save_pretrained(folder)


def _vit_processor():
    import transformers

    # transformers 5 names the torchvision-free ViT processor ...Pil; 4.x has only ViTImageProcessor.
    return getattr(transformers, "ViTImageProcessorPil", None) or transformers.ViTImageProcessor


def test_vlm_backend_loads_local_model_and_generates(tmp_path, monkeypatch):
    pytest.importorskip("transformers")
    import torch
    import transformers

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")  # any attempt to reach a hub fails loudly
    _tiny_model(tmp_path / "tiny")
    frames = np.random.default_rng(0).integers(0, 256, (5, 36, 64, 3), dtype=np.uint8)
    captioner = make_captioner(CaptionConfig(backend="vlm", model_dir=tmp_path / "tiny", max_new_tokens=6))
    assert isinstance(captioner, VLMCaptioner)
    text = captioner.caption(frames, _clip(), CaptionContext())
    assert text == captioner.caption(frames, _clip(), CaptionContext())  # greedy: deterministic
    # The same answer straight from the model on the middle frame.
    model = transformers.VisionEncoderDecoderModel.from_pretrained(tmp_path / "tiny", local_files_only=True).eval()
    pixels = _vit_processor().from_pretrained(tmp_path / "tiny")(images=frames[2], return_tensors="pt")
    with torch.inference_mode():
        ids = model.generate(**pixels, max_new_tokens=6, do_sample=False, num_beams=1)
    tokenizer = transformers.AutoTokenizer.from_pretrained(tmp_path / "tiny", local_files_only=True)
    assert text == " ".join(tokenizer.batch_decode(ids, skip_special_tokens=True)[0].split())
    assert set(text.split()) <= {"a", "robot", "arm", "picks", "box", "the", "forklift", "light"}
    assert len(ids[0]) > 1  # it generated something, even if the words are random

    with pytest.raises(FileNotFoundError, match="missing: not a local transformers model directory"):
        VLMCaptioner(CaptionConfig(backend="vlm", model_dir=tmp_path / "missing"))


def test_vlm_backend_with_a_processor_and_prompt(tmp_path, monkeypatch):
    """BLIP-style checkpoints ship one processor and take a text prefix; a tiny random one here."""
    pytest.importorskip("transformers")
    import torch
    import transformers
    from tokenizers import Tokenizer, models, pre_tokenizers

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    words = ["[PAD]", "[CLS]", "[SEP]", "[UNK]", "[MASK]", "a", "photo", "of", "robot", "arm", "box"]
    vocab = Tokenizer(models.WordLevel({w: i for i, w in enumerate(words)}, unk_token="[UNK]"))
    vocab.pre_tokenizer = pre_tokenizers.Whitespace()
    tokenizer = transformers.BertTokenizerFast(tokenizer_object=vocab, cls_token="[CLS]", sep_token="[SEP]",
                                               pad_token="[PAD]", unk_token="[UNK]", mask_token="[MASK]")
    images = getattr(transformers, "BlipImageProcessorPil", None) or transformers.BlipImageProcessor
    config = transformers.BlipConfig(
        text_config=dict(vocab_size=len(words), hidden_size=16, num_hidden_layers=1, num_attention_heads=2,
                         intermediate_size=32, max_position_embeddings=32, bos_token_id=1, sep_token_id=2,
                         pad_token_id=0, eos_token_id=2),
        vision_config=dict(hidden_size=16, num_hidden_layers=1, num_attention_heads=2, intermediate_size=32,
                           image_size=32, patch_size=16),
        projection_dim=16)
    torch.manual_seed(0)
    transformers.BlipForConditionalGeneration(config).save_pretrained(tmp_path / "blip")
    transformers.BlipProcessor(image_processor=images(size={"height": 32, "width": 32}), tokenizer=tokenizer).save_pretrained(tmp_path / "blip")
    captioner = make_captioner(CaptionConfig(backend="vlm", model_dir=tmp_path / "blip", max_new_tokens=4, prompt="a photo of"))
    assert captioner.processor is not None
    text = captioner.caption(FRAMES, _clip(), CaptionContext())
    assert text.startswith("a photo of") and set(text.split()) <= set(words[5:])

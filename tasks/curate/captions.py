"""Clip captions behind one interface, ``Captioner.caption(frames, clip, context) -> str``.

Backends (``CaptionConfig.backend``):

- ``"facts"`` (default): offline, CPU, no weights. States only what is known or measured:
  for simulator clips the manifest's embodiment, task instruction, camera and stressors; for
  every clip its length, size, frame rate, the filters' tags (camera motion, exposure, content
  type, overlay text) and a few named scores. Same inputs, same text.
- ``"vlm"``: an image-to-text model through ``transformers`` (optional extra ``vlm``), loaded
  only from ``model_dir`` with ``local_files_only=True``; it captions the clip's middle frame.

frames are the clip's analysis frames, T x h x w x 3 uint8 RGB (long side about 256).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas.manifest import ScenarioManifest
from schemas.records import ClipRecord

# Score name -> (words, unit): which measurements a facts caption may state, and how.
SCORE_WORDS = {
    "motion_mean": ("mean frame change", " grey levels"),
    "motion_global": ("camera speed", " frame widths/s"),
    "sharpness": ("sharpness", ""),
    "luma_mean": ("mean brightness", " of 255"),
    "noise": ("noise", ""),
    "quality": ("quality", ""),
}
TAG_WORDS = {
    "camera:still": "the camera is still",
    "camera:shake": "the camera shakes",
    "camera:pan_left": "the camera pans left",
    "camera:pan_right": "the camera pans right",
    "camera:pan_up": "the camera tilts up",
    "camera:pan_down": "the camera tilts down",
    "camera:zoom_in": "the camera zooms in",
    "camera:zoom_out": "the camera zooms out",
    "exposure:normal": "normal exposure",
    "exposure:dark": "dark exposure",
    "exposure:bright": "bright exposure",
    "type:physical": "physical footage",
    "type:animation": "animation",
    "type:slides": "slides",
    "type:screen": "a screen capture",
    "type:test_pattern": "a test pattern",
    "overlay:text": "burned-in text",
}
TAG_ORDER = ("camera", "exposure", "type", "overlay")
EMBODIMENT_WORDS = {"arm": "robot arm", "mobile": "mobile robot", "vehicle": "vehicle"}


class CaptionContext(BaseModel):
    """What is known about a clip beyond its pixels: for simulator clips, its manifest and camera."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    manifest: ScenarioManifest | None = None
    camera: str | None = None


class CaptionConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    backend: Literal["facts", "vlm"] = "facts"
    scores: tuple[str, ...] = ("motion_mean", "sharpness", "luma_mean")  # stated when measured
    model_dir: Path | None = Field(None, description="local transformers model directory (vlm only)")
    max_new_tokens: int = Field(32, ge=1, le=512)
    prompt: str | None = Field(None, max_length=500, description="text prefix, for vlm models that ship a processor (e.g. BLIP)")

    @model_validator(mode="after")
    def _backend_needs(self) -> "CaptionConfig":
        if self.backend == "vlm" and self.model_dir is None:
            raise ValueError("backend 'vlm' needs model_dir, a local model directory")
        return self


class Captioner(Protocol):
    def caption(self, frames: np.ndarray, clip: ClipRecord, context: CaptionContext) -> str: ...


def _check_frames(frames: np.ndarray, clip: ClipRecord) -> None:
    ok = isinstance(frames, np.ndarray) and frames.dtype == np.uint8 and frames.ndim == 4 and frames.shape[-1] == 3
    if not ok or len(frames) == 0:
        got = f"{getattr(frames, 'shape', None)} {getattr(frames, 'dtype', type(frames).__name__)}"
        raise ValueError(f"caption of clip {clip.clip_id}: expected T x h x w x 3 uint8 RGB frames (T >= 1), got {got}")


def _num(value: float) -> str:
    return f"{value:.3g}"


def _join(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _sentence(text: str) -> str:
    return text[:1].upper() + text[1:] + "."


def _stressor(s) -> str:
    kind = s.kind
    if kind == "dim_light":
        return f"dim light ({s.lux:g} lux)"
    if kind == "forklift_crossing":
        return f"a forklift crossing at {s.speed_mps:g} m/s"
    if kind == "occluder":
        return f"an occluder hiding {s.coverage:.0%} of the target"
    if kind == "camera_jitter":
        return f"camera jitter of {s.amplitude_deg:g} degrees at {s.frequency_hz:g} Hz"
    if kind == "distractors":
        return f"{s.count} distractor object{'s' if s.count != 1 else ''}"
    if kind == "appearance":
        return f"colour jitter of {s.colour_jitter:g}" + (" with random textures" if s.texture else "")
    return kind.replace("_", " ")


def _scenario(manifest: ScenarioManifest, camera: str | None) -> list[str]:
    body = EMBODIMENT_WORDS.get(manifest.embodiment.kind, manifest.embodiment.kind)
    robot = manifest.embodiment.robot
    named = "" if robot.startswith("builtin") else f" ({robot})"  # built-in bodies are described by kind
    task = manifest.task.kind.replace("_", " ")
    out = [_sentence(f'a simulated {body}{named} does a {task} task: "{manifest.task.instruction.strip()}"')]
    if camera:
        out.append(_sentence(f"seen from the {camera.replace('_', ' ')} camera"))
    stressors = [_stressor(s) for s in manifest.stressors]
    out.append(_sentence(f"conditions: {_join(stressors)}" if stressors else "no stressors"))
    return out


def _tags(tags: tuple[str, ...]) -> list[str]:
    def rank(tag: str) -> tuple[int, str]:
        kind = tag.split(":", 1)[0]
        return (TAG_ORDER.index(kind) if kind in TAG_ORDER else len(TAG_ORDER), tag)

    words = []
    for tag in sorted(set(tags), key=rank):
        known = TAG_WORDS.get(tag)
        words.append(known or tag.replace(":", " ").replace("_", " "))
    return [_sentence("; ".join(words))] if words else []


def facts_caption(clip: ClipRecord, context: CaptionContext, config: CaptionConfig = CaptionConfig()) -> str:
    """The factual caption: scenario (simulator clips), then length, size, tags and named scores."""
    parts = _scenario(context.manifest, context.camera) if context.manifest else []
    duration = clip.end_s - clip.start_s
    parts.append(_sentence(f"a {duration:.1f} s clip at {clip.width}x{clip.height} and {clip.fps:g} fps"))
    parts += _tags(clip.tags)
    stated = []
    for name in config.scores:
        value = clip.scores.get(name)
        if value is not None and np.isfinite(value):
            words, unit = SCORE_WORDS.get(name, (name.replace("_", " "), ""))
            stated.append(f"{words} {_num(value)}{unit}")
    if stated:
        parts.append(_sentence("measured " + _join(stated)))
    return " ".join(parts)


class FactsCaptioner:
    def __init__(self, config: CaptionConfig = CaptionConfig()):
        self.config = config

    def caption(self, frames: np.ndarray, clip: ClipRecord, context: CaptionContext) -> str:
        _check_frames(frames, clip)
        return facts_caption(clip, context, self.config)


class VLMCaptioner:
    """Captions the middle frame with a local image-to-text model; never downloads anything."""

    def __init__(self, config: CaptionConfig):
        if config.model_dir is None:
            raise ValueError("VLMCaptioner needs CaptionConfig.model_dir")
        try:
            import torch
            import transformers
        except ImportError:
            raise RuntimeError("captions: the vlm backend needs transformers (pip install 'worldline[vlm]')") from None
        self.config = config
        self.torch = torch
        path = Path(config.model_dir)
        if not (path / "config.json").is_file():
            raise FileNotFoundError(f"{path}: not a local transformers model directory (no config.json)")
        local = {"local_files_only": True}
        try:
            self.model = transformers.AutoModelForImageTextToText.from_pretrained(path, **local).eval()
            try:
                self.processor = transformers.AutoProcessor.from_pretrained(path, **local)
                self.tokenizer = getattr(self.processor, "tokenizer", None)
                self.image_processor = getattr(self.processor, "image_processor", None)
            except (OSError, ValueError, TypeError, KeyError):
                self.processor = None
            if self.processor is None or self.image_processor is None:
                # Encoder-decoder checkpoints often ship a tokenizer and an image processor, no processor.
                self.processor = None
                self.image_processor = transformers.AutoImageProcessor.from_pretrained(path, **local)
                self.tokenizer = transformers.AutoTokenizer.from_pretrained(path, **local)
        except (OSError, ValueError) as exc:
            raise RuntimeError(f"{path}: cannot load the caption model: {exc}") from None

    def caption(self, frames: np.ndarray, clip: ClipRecord, context: CaptionContext) -> str:
        _check_frames(frames, clip)
        image = frames[len(frames) // 2]
        if self.processor is not None:
            kwargs = {"text": self.config.prompt} if self.config.prompt else {}
            inputs = self.processor(images=image, return_tensors="pt", **kwargs)
        else:
            inputs = self.image_processor(images=image, return_tensors="pt")
        with self.torch.inference_mode():
            out = self.model.generate(**inputs, max_new_tokens=self.config.max_new_tokens, do_sample=False, num_beams=1)
        text = self.tokenizer.batch_decode(out, skip_special_tokens=True)[0]
        return " ".join(text.split())


def make_captioner(config: CaptionConfig = CaptionConfig()) -> Captioner:
    """The backend the config names; a vlm backend loads its model once, here."""
    return VLMCaptioner(config) if config.backend == "vlm" else FactsCaptioner(config)

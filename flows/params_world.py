"""Parameters of the world-model flows: tokenize, train, evaluate-physics."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from flows.params import (ActionTotals, Batch, ComputeParams, EncodeFrames, FlowParams, FocusCrops, Horizon, PanelEpisodes, Patch,
                          Refused, SamplerSteps, Seed, Share, Side, Steps, Weight, Window)

HELDOUT_FIRST_SEED = 10_000  # the first held-out seed: never one the world model trained on


def _known(presets: dict, name: str, field: str, what: str) -> None:
    if name not in presets:
        raise Refused(f"{{{field}}}: unknown {what} preset {name!r}; known: {', '.join(sorted(presets))}")


class TokenizeParams(ComputeParams):
    shards: str = Field(description="a folder of curated shards, or a manifest hash (12+ hex digits)")
    preset_name: str = Field("tiny-dv4x8x8", description="tokenizer preset (models/tokenizer.py PRESETS)")
    steps: Steps = Field(200, description="training steps")
    size: Side = Field(64, description="frames are centre-cropped and resized to size x size")
    crop: Side | None = Field(None, description="train on random crops of this side (default: whole frames)")
    batch_size: Batch = Field(4, description="clips per training step")
    seed: Seed = 0
    max_encode_frames: EncodeFrames = 129
    motion_weight: Weight = Field(0.0, description="extra L1 weight on pixels that change between frames (up to 1 "
                                                   "+ this)")
    focus_crops: FocusCrops = Field(1, description="candidate crops per window; the one that changes most is "
                                                   "trained on")
    init: str | None = Field(None, description="continue from this tokenizer checkpoint (folder or id; same preset)")
    cli_arguments = ("shards",)
    cli_names = {"preset_name": "--preset", "batch_size": "--batch", "compile_model": "--compile"}
    cli_hidden = ("seed", "max_encode_frames")

    @model_validator(mode="after")
    def _fits_the_preset(self):
        from models.tokenizer import PRESETS

        _known(PRESETS, self.preset_name, "preset_name", "tokenizer")
        compression = PRESETS[self.preset_name].spatial_compression
        for name, side in (("size", self.size), ("crop", self.crop)):
            if side is not None and side % compression:
                raise Refused(f"{{{name}}}: {side} is not a multiple of {self.preset_name}'s spatial compression "
                              f"{compression}")
        if self.crop is not None and self.crop > self.size:
            raise Refused(f"{{crop}}: {self.crop} is larger than {{size}} {self.size}")
        return self


class TrainParams(ComputeParams):
    manifest: str = Field(description="manifest YAML whose simulated episodes post-train the model (or an episode "
                                      "folder, or a manifest hash)")
    tokenizer: str | None = Field(None, description="tokenizer checkpoint folder or id; default the newest discrete "
                                                    "one with token shards (continuous with --family diffusion)")
    token_shards: str | None = Field(None, description="token shard folder; default the tokenizer's token shards")
    preset_name: str = Field("tiny-wm", description="world model preset: *-wm (models/world_model.py PRESETS), or "
                                                    "*-dwm with --family diffusion (models/diffusion_world.py)")
    pretrain_steps: Steps = Field(200, description="pre-training steps")
    posttrain_steps: Steps = Field(100, description="post-training steps")
    camera: str | None = Field(None, description="post-train on this camera or rig only (default: every camera)")
    window: Window | None = Field(None, description="latent frames per training window (default: the preset's "
                                                    "max_frames)")
    seed: Seed = 0
    patch: Patch | None = Field(None, description="codes per token side (default: the smallest that keeps a latent "
                                                  "frame at 64 tokens or fewer)")
    batch_size: Batch = Field(8, description="windows per training step")
    change_weight: Weight = Field(0.0, description="extra loss weight on codes that change from one latent frame to "
                                                   "the next")
    self_condition: Share = Field(0.0, description="share of post-training windows whose input frames after the "
                                  "first are the model's own rollout (open-loop robustness)")
    action_totals: ActionTotals = Field(0, description="post-training: the first N action values also enter as "
                                        "running totals since the episode's start (3 for ee_delta actions: the "
                                        "commanded hand's offset, which a few-frame window cannot add up)")
    also: list[str] | None = Field(None, description="another manifest (YAML, episode folder or hash) whose "
                                   "episodes join post-training; repeatable")
    family: Literal["autoregressive", "diffusion"] = Field(
        "autoregressive", description="autoregressive: next-code prediction on a discrete tokenizer's codes; "
        "diffusion: flow matching on a continuous tokenizer's latents (a *-dwm preset)")
    cli_arguments = ("manifest",)
    cli_names = {"token_shards": "--tokens", "preset_name": "--preset", "pretrain_steps": "--steps",
                 "posttrain_steps": "--post-steps", "batch_size": "--batch", "compile_model": "--compile"}
    cli_hidden = ("seed",)

    @model_validator(mode="after")
    def _known_preset(self):
        from models.diffusion_world import PRESETS as DIFFUSION
        from models.world_model import PRESETS

        ours, theirs = (DIFFUSION, PRESETS) if self.family == "diffusion" else (PRESETS, DIFFUSION)
        if self.preset_name in theirs:
            kind = "an autoregressive (*-wm)" if self.family == "diffusion" else "a diffusion (*-dwm)"
            raise Refused(f"{{preset_name}} {self.preset_name!r} is {kind} world model preset; {{family}} "
                          f"{self.family} takes {', '.join(sorted(ours))}")
        _known(ours, self.preset_name, "preset_name", "diffusion world model" if self.family == "diffusion"
               else "world model")
        if self.family == "diffusion":
            for name in ("change_weight", "self_condition"):
                if getattr(self, name):
                    raise Refused(f"{{{name}}}: the autoregressive world model's option; {{family}} diffusion "
                                  "has no codes to weigh or roll out in training")
        return self

    def presets(self) -> dict:
        from models.diffusion_world import PRESETS as DIFFUSION
        from models.world_model import PRESETS

        return DIFFUSION if self.family == "diffusion" else PRESETS

    def check_tokenizer(self, folder: str | None) -> None:
        """A tokenizer checkpoint folder's variant against the family: the diffusion world model
        denoises a continuous tokenizer's latents (the autoregressive family's own check stays
        where it was: ``flows.cli_checks.tokenizer``, ``tasks.world.inputs.tokenizer_checkpoint``)."""
        from models.tokenizer import TokenizerConfig
        from tasks.checkpoint_files import CheckpointError, model_config, read_config

        if self.family != "diffusion" or not folder or not Path(folder).is_dir():
            return
        try:
            variant = model_config(TokenizerConfig, read_config(Path(folder), "tokenizer", "tokenizer checkpoint"),
                                   "tokenizer", Path(folder)).variant
        except CheckpointError:
            return  # the loader says what is wrong with it
        if variant != "continuous":
            raise Refused(f"{{tokenizer}} {self.tokenizer}: a {variant} tokenizer; {{family}} diffusion needs a "
                          "continuous one (it denoises latents, not codes)")

    def check_episodes(self, folder: Path) -> None:
        """The camera and the action totals against the first episode of ``manifest``."""
        from tasks.world.data import read_meta, read_steps

        PRESETS = self.presets()

        meta = read_meta(folder)
        cameras, rigs = meta.get("cameras", []), meta.get("rigs", [])
        if self.camera is not None and self.camera not in cameras + rigs:
            raise Refused(f"{{camera}} {self.camera!r}: the episodes of {self.manifest} have cameras "
                          f"{', '.join(cameras)}" + (f" and rigs {', '.join(rigs)}" if rigs else ""))
        if self.action_totals:
            width, room = read_steps(folder)[1].shape[1], PRESETS[self.preset_name].action_dim
            if self.action_totals > width or width + self.action_totals > room:
                raise Refused(f"{{action_totals}} {self.action_totals}: the episodes of {self.manifest} have "
                              f"{width} action values a step and preset {self.preset_name} takes {room} values in all")


class HeldoutBase(FlowParams):
    """What a world model's evaluation on held-out seeds of a manifest takes (physics, camera, rig)."""

    manifest: str = Field(description="scenario manifest YAML")
    world_model: str | None = Field(None, description="post-trained world-model checkpoint folder or id, "
                                    "autoregressive or diffusion (default: the newest post-trained one in lineage)")
    tokenizer: str | None = Field(None, description="its tokenizer's checkpoint folder or id (default: the one it "
                                                    "was trained with)")
    episodes: PanelEpisodes = Field(10, description="held-out episodes")
    first_seed: Seed = Field(HELDOUT_FIRST_SEED, description="seeds first_seed.. (never those the model trained on)")
    horizon: Horizon = Field(4, description="latent frames predicted per window")
    context: int | None = None
    stride: int = 2
    shuffle_seed: int = 0
    sampler_steps: SamplerSteps = Field(8, description="a diffusion world model's Euler sampling steps per window "
                                                       "(an autoregressive one decodes greedily)")
    cli_arguments = ("manifest",)
    cli_paths = ("manifest",)
    cli_hidden = ("context", "stride", "shuffle_seed")


class HeldoutParams(HeldoutBase):
    camera: str | None = Field(None, description="world-mounted camera (default: the first)")


class RigParams(HeldoutBase):
    manifest: str = Field(description="manifest YAML with a rig (`rigs:`) of cameras riding on the vehicle")
    rig: str | None = Field(None, description="the rig whose tiled video the world model generates "
                                              "(default: the manifest's first)")
    horizon: Horizon = Field(2, description="latent frames predicted per window (the ego-motion is measured "
                                            "after each)")


class PhysicsParams(HeldoutParams):
    move_threshold_cm: float = 2.0
    cli_hidden = ("context", "stride", "move_threshold_cm", "shuffle_seed")


class CameraParams(HeldoutParams):
    manifest: str = Field(description="manifest YAML of a rig whose cameras ride on the base (its action their motion)")
    camera: str | None = Field(None, description="camera riding on the base (default: the first)")

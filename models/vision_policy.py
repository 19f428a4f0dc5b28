"""Vision policy: camera frames and proprioception to the next end-effector move.

Tensor contract: ``frames`` is ``B x C x 3 x H x W`` uint8 (C cameras, each downscaled to
H x W, RGB); ``proprio`` is ``B x proprio_size`` float32 (the robot's own joint angles and
velocities, grip and commanded pose: tasks/policy/vision_obs.py); the output is ``B x 5``
float32 ``[dx, dy, dz (m), dyaw (rad), grip in [0, 1]]`` as for the state policy
(models/bc_policy.py). Nothing the simulator knows about objects enters.

Each camera has its own convolutional encoder ending in a spatial softmax (Levine et al.,
"End-to-End Training of Deep Visuomotor Policies", 2016): every feature map becomes the
expected image position of its activation, so the head sees *where* things are (the package,
the goal marker, the gripper) as coordinates, which is what a push or a grasp needs. Frames
are standardised per channel by statistics of the training set; proprioception and actions
are standardised as in the state policy, all kept as buffers so a checkpoint carries them.

``encoder="tokenizer"`` puts the project's video tokenizer's encoder (models/tokenizer.py),
frozen, in place of the first convolutions: a frame alone is a clip of one frame, whose
first latent frame depends on it only (the tokenizer is causal), so each frame gives its
``H/s x W/s`` grid of latents (``tokenizer_layer="latent"``: the bounded code values the
world model reads) or of the encoder's last hidden features (``"hidden"``, before the
projection to codes); two trainable convolutions and the spatial softmax follow. The
encoder's weights are copied in from a tokenizer checkpoint (``load_tokenizer``) and saved
with the policy's, so the checkpoint stands alone.
"""

from __future__ import annotations

from typing import Literal

import torch
from pydantic import BaseModel, ConfigDict, Field, model_validator
from torch import nn

from models.tokenizer import Encoder, TokenizerConfig, VideoTokenizer
from models.tokenizer_layers import FSQ

VISION_SCHEMA_VERSION = 1
ACTION_SIZE = 5


class VisionConfig(BaseModel):
    """Architecture; its JSON is saved beside every checkpoint."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    schema_version: int = VISION_SCHEMA_VERSION
    name: str = "custom"
    cameras: int = Field(1, ge=1, le=8)
    image_size: int = Field(64, ge=16, le=256)
    proprio_size: int = Field(ge=1)
    action_size: int = ACTION_SIZE
    channels: int = Field(32, ge=4, le=256)
    keypoints: int = Field(16, ge=2, le=128)
    hidden: int = Field(256, ge=8, le=4096)
    encoder: Literal["cnn", "tokenizer"] = "cnn"
    tokenizer: TokenizerConfig | None = Field(None, description="the tokenizer whose encoder it is (encoder tokenizer)")
    tokenizer_layer: Literal["latent", "hidden"] = "latent"

    @model_validator(mode="after")
    def _encoder(self) -> "VisionConfig":
        if (self.encoder == "tokenizer") != (self.tokenizer is not None):
            raise ValueError("a tokenizer config goes with encoder 'tokenizer', and only with it")
        if self.tokenizer is not None and self.image_size % self.tokenizer.spatial_compression:
            raise ValueError(f"image size {self.image_size} is not a multiple of the tokenizer's spatial compression "
                             f"{self.tokenizer.spatial_compression}")
        return self


PRESETS = {"tiny": dict(channels=16, keypoints=16, hidden=128), "small": dict(channels=32, keypoints=32, hidden=256)}


def preset(name: str, cameras: int, image_size: int, proprio_size: int, tokenizer: TokenizerConfig | None = None,
           layer: str = "latent") -> VisionConfig:
    """A named size; ``tiny`` trains at tens of steps per second on one CPU core at 64 px. With
    ``tokenizer``, the encoder is that tokenizer's (``layer``: latent or hidden)."""
    encoder = dict(encoder="tokenizer", tokenizer=tokenizer, tokenizer_layer=layer) if tokenizer else {}
    return VisionConfig(name=name, cameras=cameras, image_size=image_size, proprio_size=proprio_size,
                        **PRESETS[name], **encoder)


class SpatialSoftmax(nn.Module):
    """B x K x H x W feature maps -> B x 2K expected (x, y) in [-1, 1] of each map's softmax."""

    def __init__(self, height: int, width: int):
        super().__init__()
        ys, xs = torch.meshgrid(torch.linspace(-1, 1, height), torch.linspace(-1, 1, width), indexing="ij")
        self.register_buffer("grid", torch.stack([xs.reshape(-1), ys.reshape(-1)], 1), persistent=False)

    def forward(self, maps: torch.Tensor) -> torch.Tensor:
        b, k = maps.shape[:2]
        weights = torch.softmax(maps.reshape(b, k, -1), dim=-1)
        return (weights @ self.grid).reshape(b, 2 * k)


class CameraEncoder(nn.Module):
    """3 x S x S -> 2 x keypoints coordinates (stride 2 once, so the maps keep S/2 resolution)."""

    def __init__(self, config: VisionConfig):
        super().__init__()
        c = config.channels
        self.conv = nn.Sequential(
            nn.Conv2d(3, c, 5, stride=2, padding=2), nn.GELU(),
            nn.Conv2d(c, c, 3, padding=1), nn.GELU(),
            nn.Conv2d(c, c, 3, padding=1), nn.GELU(),
            nn.Conv2d(c, config.keypoints, 1))
        side = (config.image_size + 1) // 2
        self.softmax = SpatialSoftmax(side, side)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.softmax(self.conv(x))


class TokenizerCameraEncoder(nn.Module):
    """3 x S x S in [-1, 1] -> 2 x keypoints coordinates: the tokenizer's encoder, frozen (no
    gradient, always in eval mode), on the frame as a one-frame clip, then two trainable
    convolutions and a spatial softmax over the S/s x S/s grid."""

    def __init__(self, config: VisionConfig):
        super().__init__()
        tok = config.tokenizer
        self.layer = config.tokenizer_layer
        self.encoder = Encoder(tok).requires_grad_(False)
        self.fsq = FSQ(tok.fsq_levels) if tok.variant == "discrete" else None
        width = tok.code_channels if self.layer == "latent" else tok.channels[-1]
        c = config.channels
        self.conv = nn.Sequential(nn.Conv2d(width, c, 3, padding=1), nn.GELU(), nn.Conv2d(c, config.keypoints, 1))
        side = config.image_size // tok.spatial_compression
        self.softmax = SpatialSoftmax(side, side)

    def train(self, mode: bool = True) -> "TokenizerCameraEncoder":
        super().train(mode)
        self.encoder.eval()
        return self

    def latents(self, x: torch.Tensor) -> torch.Tensor:
        """B x 3 x S x S in [-1, 1] -> B x width x S/s x S/s, without gradient."""
        with torch.no_grad():
            if self.layer == "hidden":
                return self.encoder.hidden(x[:, :, None])[:, :, 0]
            h = self.encoder(x[:, :, None])
            return (self.fsq(h)[0] if self.fsq is not None else torch.tanh(h))[:, :, 0]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.softmax(self.conv(self.latents(x)))


class VisionPolicyNet(nn.Module):
    def __init__(self, config: VisionConfig):
        super().__init__()
        self.config = config
        camera = TokenizerCameraEncoder if config.encoder == "tokenizer" else CameraEncoder
        self.encoders = nn.ModuleList(camera(config) for _ in range(config.cameras))
        size = config.cameras * 2 * config.keypoints + config.proprio_size
        self.head = nn.Sequential(nn.Linear(size, config.hidden), nn.GELU(),
                                  nn.Linear(config.hidden, config.hidden), nn.GELU(),
                                  nn.Linear(config.hidden, config.action_size))
        self.register_buffer("pixel_mean", torch.full((config.cameras, 3, 1, 1), 127.5))
        self.register_buffer("pixel_std", torch.full((config.cameras, 3, 1, 1), 64.0))
        for name, n in (("proprio_mean", config.proprio_size), ("act_mean", config.action_size)):
            self.register_buffer(name, torch.zeros(n))
        for name, n in (("proprio_std", config.proprio_size), ("act_std", config.action_size)):
            self.register_buffer(name, torch.ones(n))

    def set_statistics(self, frames: torch.Tensor, proprio: torch.Tensor, act: torch.Tensor) -> None:
        """Standardise with the training set's statistics (a constant column keeps std 1).
        ``frames`` may be a sample of the training frames (N x C x 3 x H x W uint8)."""
        pixels = frames.float()
        self.pixel_mean.copy_(pixels.mean(dim=(0, 3, 4))[..., None, None])
        self.pixel_std.copy_(pixels.std(dim=(0, 3, 4)).clamp_min(1.0)[..., None, None])
        for tensor, mean, std in ((proprio, self.proprio_mean, self.proprio_std), (act, self.act_mean, self.act_std)):
            mean.copy_(tensor.mean(0))
            spread = tensor.std(0)
            std.copy_(torch.where(spread > 1e-8, spread, torch.ones_like(spread)))

    def load_tokenizer(self, tokenizer: VideoTokenizer) -> "VisionPolicyNet":
        """Copy a trained tokenizer's encoder weights into every camera's encoder."""
        if self.config.tokenizer != tokenizer.config:
            raise ValueError(f"tokenizer {tokenizer.config.name} is not the one this policy was built for "
                             f"({self.config.tokenizer.name if self.config.tokenizer else 'a CNN encoder'})")
        for enc in self.encoders:
            enc.encoder.load_state_dict(tokenizer.encoder.state_dict())
        return self

    def frozen(self, frames: torch.Tensor) -> torch.Tensor:
        """B x C x 3 x H x W uint8 -> what no gradient changes, per camera: the tokenizer
        encoder's ``B x C x width x H/s x W/s`` (training caches it once per frame), or for the
        CNN the frames standardised by the training set's statistics."""
        if self.config.encoder == "tokenizer":
            x = frames.float() / 127.5 - 1.0  # the tokenizer's own input range
            return torch.stack([enc.latents(x[:, i]) for i, enc in enumerate(self.encoders)], dim=1)
        return (frames.float() - self.pixel_mean) / self.pixel_std

    def features(self, frozen: torch.Tensor) -> torch.Tensor:
        """``frozen(frames)`` -> B x (C x 2 x keypoints) image coordinates."""
        if self.config.encoder == "tokenizer":
            return torch.cat([enc.softmax(enc.conv(frozen[:, i].float())) for i, enc in enumerate(self.encoders)], 1)
        return torch.cat([enc(frozen[:, i]) for i, enc in enumerate(self.encoders)], dim=1)

    def forward_normalised(self, frames: torch.Tensor, proprio: torch.Tensor, frozen: torch.Tensor | None = None
                           ) -> torch.Tensor:
        """Standardised action units (what the loss sees); ``frozen`` given, ``frames`` is not read."""
        p = (proprio - self.proprio_mean) / self.proprio_std
        return self.head(torch.cat([self.features(self.frozen(frames) if frozen is None else frozen), p], dim=1))

    def forward(self, frames: torch.Tensor, proprio: torch.Tensor, frozen: torch.Tensor | None = None) -> torch.Tensor:
        return self.forward_normalised(frames, proprio, frozen) * self.act_std + self.act_mean

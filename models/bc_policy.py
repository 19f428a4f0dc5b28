"""Behaviour-cloning policy: an MLP from privileged simulator state to the next end-effector move.

Tensor contract: ``obs`` is ``B x obs_size`` float32 (tasks/policy/features.py builds it, in
metres and sines/cosines); the output is ``B x 5`` float32 ``[dx, dy, dz (m), dyaw (rad),
grip in [0, 1]]``, the change of the commanded tcp pose for one control step. Inputs and
targets are standardised with statistics of the training set, kept as buffers so a
checkpoint carries them.
"""

from __future__ import annotations

import torch
from pydantic import BaseModel, ConfigDict, Field
from torch import nn

BC_SCHEMA_VERSION = 1
ACTION_SIZE = 5


class BCConfig(BaseModel):
    """Architecture; its JSON is saved beside every checkpoint."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    schema_version: int = BC_SCHEMA_VERSION
    name: str = "custom"
    obs_size: int = Field(ge=1)
    action_size: int = ACTION_SIZE
    hidden: int = Field(256, ge=8, le=4096)
    layers: int = Field(2, ge=1, le=8)


PRESETS = {"tiny": dict(hidden=128, layers=2), "small": dict(hidden=256, layers=3)}


def preset(name: str, obs_size: int) -> BCConfig:
    """A named size (``tiny`` trains in well under a minute on one CPU core)."""
    return BCConfig(name=name, obs_size=obs_size, **PRESETS[name])


class BCPolicyNet(nn.Module):
    def __init__(self, config: BCConfig):
        super().__init__()
        self.config = config
        width, layers = config.hidden, []
        size = config.obs_size
        for _ in range(config.layers):
            layers += [nn.Linear(size, width), nn.GELU()]
            size = width
        layers.append(nn.Linear(size, config.action_size))
        self.net = nn.Sequential(*layers)
        for name, n in (("obs_mean", config.obs_size), ("act_mean", config.action_size)):
            self.register_buffer(name, torch.zeros(n))
        for name, n in (("obs_std", config.obs_size), ("act_std", config.action_size)):
            self.register_buffer(name, torch.ones(n))

    def set_statistics(self, obs: torch.Tensor, act: torch.Tensor) -> None:
        """Standardise with the training set's mean and std (a constant column keeps std 1)."""
        for tensor, mean, std in ((obs, self.obs_mean, self.obs_std), (act, self.act_mean, self.act_std)):
            mean.copy_(tensor.mean(0))
            spread = tensor.std(0)
            std.copy_(torch.where(spread > 1e-8, spread, torch.ones_like(spread)))

    def forward_normalised(self, obs: torch.Tensor) -> torch.Tensor:
        """B x obs_size -> B x action_size in standardised action units (what the loss sees)."""
        return self.net((obs - self.obs_mean) / self.obs_std)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.forward_normalised(obs) * self.act_std + self.act_mean

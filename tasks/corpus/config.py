"""The corpus generator's frozen config and the label vocabulary of the ground truth."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

TRUTH_FORMAT = "worldline-corpus-truth/1"

# Defect labels, grouped by the curation filter that should reject them.
FILTER_GROUPS: dict[str, tuple[str, ...]] = {
    "motion": ("static", "shake"),
    "quality": ("blur", "overexposed", "underexposed", "noise"),
    "overlay_text": ("text_subtitle", "text_logo", "text_timestamp"),
    "video_type": ("nonphysical_animation", "nonphysical_slides", "nonphysical_test_pattern"),
}
DEFECT_LABELS: tuple[str, ...] = tuple(label for group in FILTER_GROUPS.values() for label in group)
NONPHYSICAL = FILTER_GROUPS["video_type"]
TRANSFORMS = ("exact", "reencode", "rescale", "crop", "brightness")

# Adjacent segments with these label pairs could meet at a cut that barely changes the picture
# (a white slide after a blown-out shot); the planner never puts them side by side.
LOOKALIKE_PAIRS = frozenset({
    frozenset({"overexposed", "nonphysical_slides"}),
})


class CorpusConfig(BaseModel):
    """How the raw corpus is planned, rendered and encoded. Times are seconds unless named frames."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    # Encoder: libx264, yuv420p, one thread so the bytes are reproducible.
    crf: int = Field(23, ge=0, le=51)
    preset: Literal["ultrafast", "superfast", "veryfast", "faster", "fast", "medium"] = "veryfast"
    # Segments: the truth format promises 2.5 s to 20 s.
    min_segment_s: float = Field(2.5, ge=2.5, le=20.0)
    max_segment_s: float = Field(20.0, ge=2.5, le=20.0)
    typical_segment_s: float = Field(12.0, ge=2.5, le=20.0, description="log-uniform up to here, 90% of the time")
    # Label mix: per block of 20 segments, this many are clean and one carries each defect label.
    clean_per_block: int = Field(9, ge=0, le=100)
    duplicate_fraction: float = Field(0.16, ge=0, le=1, description="share of clean segments that copy earlier ones")
    cross_video_fraction: float = Field(0.8, ge=0, le=1, description="share of duplicates copying another video")
    # Transitions between segments; lengths in frames at 30 fps, scaled to the video's fps.
    fade_probability: float = Field(0.08, ge=0, le=0.5)
    dissolve_probability: float = Field(0.08, ge=0, le=0.5)
    transition_frames: tuple[int, int] = (10, 30)
    # Simulator segments: rendered small, then scaled up, so memory stays bounded.
    sim_max_width: int = Field(480, ge=32, le=4096)
    sim_max_segment_s: float = Field(10.0, ge=2.5, le=20.0)
    sim_take_start_s: float = Field(
        30.0, ge=0.0, le=600.0,
        description="a take starts at a time drawn from [0, this) of its seed's run: two takes of one scene "
                    "show different stretches of the task, not the same opening seconds (which, with only the "
                    "controller noise differing, are the same footage)")
    sim_strip_stressors: tuple[str, ...] = Field(
        ("camera_jitter", "dim_light"),
        description="stressors removed (in a derived manifest): clean footage must neither shake nor be dark")
    # Duplicate transforms.
    reencode_crf_offset: tuple[int, int] = (8, 14)

    @model_validator(mode="after")
    def _ordered(self) -> "CorpusConfig":
        if not self.min_segment_s <= self.typical_segment_s <= self.max_segment_s:
            raise ValueError("need min_segment_s <= typical_segment_s <= max_segment_s")
        low, high = self.transition_frames
        if not 2 <= low <= high <= 120:
            raise ValueError(f"transition_frames {self.transition_frames} must satisfy 2 <= low <= high <= 120")
        if self.fade_probability + self.dissolve_probability > 0.9:
            raise ValueError("fade_probability + dissolve_probability must leave room for hard cuts")
        return self

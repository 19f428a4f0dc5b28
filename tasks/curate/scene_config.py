"""What the scene split is configured with (``SceneConfig``) and what it yields (``Scene`` spans)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

Span = tuple[int, int, str]  # (start, end exclusive, kind) in frame positions


class SceneConfig(BaseModel):
    """Detector choice and thresholds. Luma values are on 0..255; times in seconds."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    detector: Literal["adaptive", "content"] = "adaptive"
    content_threshold: float = Field(27.0, gt=0, description="ContentDetector threshold")
    adaptive_threshold: float = Field(3.0, gt=0, description="AdaptiveDetector ratio threshold")
    adaptive_window: int = Field(2, ge=1, le=10)
    min_content_val: float = Field(15.0, ge=0, description="AdaptiveDetector minimum content score")
    min_cut_gap_s: float = Field(0.3, ge=0, description="detector's own minimum gap between cuts")
    min_scene_s: float = Field(2.0, ge=0)
    max_scene_s: float = Field(60.0, gt=0)
    transitions: bool = Field(True, description="find fades and dissolves and exclude their frames")
    max_transition_s: float = Field(2.0, gt=0)
    fade_black: float = Field(24.0, ge=0, le=255, description="mean luma of a faded-out frame")
    fade_step: float = Field(0.6, ge=0, description="smallest luma change per frame on a fade ramp")
    fade_depth: float = Field(20.0, ge=0, description="luma rise from the darkest frame to the brighter end")
    dissolve_dip: float = Field(0.7, gt=0, le=1, description="sharpness / its envelope mid-dissolve")
    dissolve_edge: float = Field(0.9, gt=0, le=1, description="dip level that bounds the span")
    dissolve_min_change: float = Field(15.0, ge=0, description="mean grey change across the span")
    dissolve_max_step: float = Field(0.35, gt=0, le=1, description="largest blend-weight step (else a cut)")
    dissolve_residual: float = Field(0.2, gt=0, description="blend residual / change")
    dissolve_motion: float = Field(1.5, ge=0, description="the middle frame's motion residual / its blend residual")
    cut_left_view: float = Field(0.5, le=1, description="best-shift correlation across a cut below which the view left")
    cut_same_view: float = Field(0.9, le=1, description="best-shift correlation of the view come back after a cut")
    cut_return_s: float = Field(0.33, ge=0, description="how long after a cut the view before may come back")
    cut_enter_s: float = Field(0.125, ge=0, description="how long before a cut the view that comes back may be seen")
    dissolve_same_view: float = Field(0.5, le=1, description="correlation of the ends, best shift, of one view")
    cut_weak_ratio: float = Field(2.0, gt=0, description="adaptive ratio from which a peak may be confirmed as a cut")
    cut_unrelated: float = Field(0.35, le=1, description="picture correlation, best shift, that confirms a weak peak")
    cut_unrelated_edges: float = Field(0.5, le=1, description="edge-map correlation, best shift, that confirms a "
                                       "weak peak whose picture correlation is under cut_related")
    cut_related: float = Field(0.7, le=1, description="picture correlation from which a weak peak is one view")


SpanKind = Literal["scene", "too_short", "transition"]


@dataclass(frozen=True, slots=True)
class Scene:
    """A span of decoded frames [start_frame, end_frame) with its analysis frames.

    ``frames`` is T x h x w x 3 uint8 RGB, ``times`` T float64 seconds and ``indices`` their
    source frame numbers (T may be less than end_frame - start_frame when frames were left
    undecoded or lost); all three are None from ``detect_scenes``. ``start_frame`` is the span's first decoded frame and ``end_frame`` one
    past its last, so frames undecoded at a boundary belong to no span (but to one of two
    parts of a split shot). ``end_s`` is the time of frame ``end_frame``. ``cause``
    says what started the span: the video start, a cut, the end of a transition, or an
    equal split of a longer shot; ``detail`` is "fade"/"dissolve" for transitions.
    """

    kind: SpanKind
    start_frame: int
    end_frame: int
    start_s: float
    end_s: float
    cause: Literal["start", "cut", "transition", "split"] = "start"
    detail: str | None = None
    frames: np.ndarray | None = None
    times: np.ndarray | None = None
    indices: np.ndarray | None = None  # T int64 source frame numbers of ``frames``

    @property
    def duration(self) -> float:
        return self.end_s - self.start_s

    def summary(self) -> dict:
        """JSON-ready fields without the frames."""
        return {"kind": self.kind, "start_frame": self.start_frame, "end_frame": self.end_frame,
                "start_s": round(self.start_s, 6), "end_s": round(self.end_s, 6),
                "cause": self.cause, "detail": self.detail}

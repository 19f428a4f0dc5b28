"""Bounded flow parameters: Prefect puts the bounds in each deployment's parameter schema, so
`prefect deployment run` with an out-of-range value is refused before a run is created, and a
direct call is refused before the flow body runs. The CLI's options carry the same bounds."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

Episodes = Annotated[int, Field(ge=1, le=10_000, description="episodes or seeds")]
PanelEpisodes = Annotated[int, Field(ge=1, le=1000, description="seeds per stressor cell")]
Steps = Annotated[int, Field(ge=1, le=1_000_000, description="training steps")]
Seed = Annotated[int, Field(ge=0)]
Batch = Annotated[int, Field(ge=1, le=256)]
Weight = Annotated[float, Field(ge=0.0, le=100.0)]
Share = Annotated[float, Field(ge=0.0, le=1.0)]
Side = Annotated[int, Field(ge=8, le=1024, description="pixels")]

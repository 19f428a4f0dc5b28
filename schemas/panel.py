"""Panels: a manifest crossed with a stressor grid, and the contract that makes panels comparable.

A panel's variants share everything but their stressors (and the seeds, which every cell
shares): camera layout, horizon, embodiment, task and evaluation target. Those are the
**contract**; two panels may be compared (policies ranked on both, verdicts correlated) only
when their contract hashes are equal.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from schemas import SCHEMA_VERSION
from schemas.hashing import content_hash
from schemas.manifest import Camera, Embodiment, Frozen, ScenarioManifest, Stressor

StressorKind = Literal["dim_light", "forklift_crossing", "occluder", "camera_jitter", "distractors", "appearance"]
HASH = r"^[0-9a-f]{64}$"
MAX_CELLS = 64
MAX_EPISODES = 1000


class StressorCell(Frozen):
    """One variant: the parent's stressors, minus ``drop``, with ``stressors`` set (a stressor
    of a kind the parent has replaces the parent's). ``{name: nominal}`` is the parent as is."""

    name: str = Field(pattern=r"^[a-z0-9][a-z0-9_\-]{0,31}$")
    stressors: tuple[Stressor, ...] = Field(default=(), max_length=6)
    drop: tuple[StressorKind, ...] = Field(default=(), max_length=6)

    @field_validator("stressors", mode="after")
    @classmethod
    def _stressor_set(cls, value: tuple) -> tuple:
        kinds = [s.kind for s in value]
        if len(set(kinds)) != len(kinds):
            raise ValueError(f"stressor kinds repeat: {sorted(kinds)}")
        return tuple(sorted(value, key=lambda s: s.kind))

    @field_validator("drop", mode="after")
    @classmethod
    def _drop_set(cls, value: tuple) -> tuple:
        return tuple(sorted(set(value)))

    @model_validator(mode="after")
    def _not_both(self) -> "StressorCell":
        both = sorted({s.kind for s in self.stressors} & set(self.drop))
        if both:
            raise ValueError(f"cell {self.name!r} both sets and drops {both}")
        return self


class StressorGrid(Frozen):
    """The cells of a panel and the seeds every cell runs: seeds seed .. seed+episodes-1, the
    parent manifest's seed when ``seed`` is None. The same seeds in every cell make the panel
    matched: the same layouts, only the stressors differ."""

    schema_version: Literal[1] = SCHEMA_VERSION
    name: str = Field(pattern=r"^[a-z0-9][a-z0-9_\-]{0,31}$")
    description: str = Field("", max_length=2000)
    cells: tuple[StressorCell, ...] = Field(min_length=1, max_length=MAX_CELLS)
    episodes: int = Field(2, ge=1, le=MAX_EPISODES)
    seed: int | None = Field(None, ge=0, lt=2**31 - MAX_EPISODES)

    @model_validator(mode="after")
    def _unique_cells(self) -> "StressorGrid":
        names = [c.name for c in self.cells]
        if len(set(names)) != len(names):
            raise ValueError(f"cell names repeat: {sorted(names)}")
        return self


class PanelContract(Frozen):
    """What two panels must share to be compared. Left out on purpose: stressors and seed (what
    a panel varies), the controller noise (a property of the policy, not of the task) and the
    evaluation's min_success_rate (a pass bar; it changes no episode's verdict)."""

    embodiment: Embodiment
    task: str
    instruction: str
    objects: tuple[str, ...]
    cameras: tuple[Camera, ...]
    horizon_s: float
    target: str
    lift_height_m: float
    goal_tolerance_m: float


def panel_contract(manifest: ScenarioManifest) -> PanelContract:
    ev = manifest.evaluation
    return PanelContract(embodiment=manifest.embodiment, task=manifest.task.kind, instruction=manifest.task.instruction,
                         objects=manifest.task.objects, cameras=manifest.cameras, horizon_s=manifest.horizon_s,
                         target=ev.target, lift_height_m=ev.lift_height_m, goal_tolerance_m=ev.goal_tolerance_m)


def contract_hash(value: ScenarioManifest | PanelContract) -> str:
    contract = panel_contract(value) if isinstance(value, ScenarioManifest) else value
    return content_hash(contract.model_dump(mode="json"))


class PanelVariant(Frozen):
    cell: str
    manifest_hash: str = Field(pattern=HASH)
    seeds: tuple[int, ...] = Field(min_length=1, max_length=MAX_EPISODES)


class PanelSpec(Frozen):
    """A matched panel: the parent, the grid, the contract and each cell's variant manifest."""

    schema_version: Literal[1] = SCHEMA_VERSION
    name: str
    parent: str = Field(pattern=HASH)
    contract: PanelContract
    contract_hash: str = Field(pattern=HASH)
    grid: StressorGrid
    variants: tuple[PanelVariant, ...] = Field(min_length=1, max_length=MAX_CELLS)

    @model_validator(mode="after")
    def _consistent(self) -> "PanelSpec":
        if contract_hash(self.contract) != self.contract_hash:
            raise ValueError("contract_hash does not match the contract")
        if [v.cell for v in self.variants] != [c.name for c in self.grid.cells]:
            raise ValueError("variants must follow the grid's cells, in order")
        return self


VOLATILE_FIELDS = frozenset({"description"})


def grid_hash(grid: StressorGrid) -> str:
    return content_hash(grid.model_dump(mode="json", exclude=set(VOLATILE_FIELDS)))


def panel_hash(spec: PanelSpec) -> str:
    """sha256 of the canonical JSON of the panel (the grid's description left out)."""
    body = spec.model_dump(mode="json")
    body["grid"].pop("description", None)
    return content_hash(body)

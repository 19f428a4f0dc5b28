"""A manifest x a stressor grid -> the panel spec and one variant manifest per cell."""

from __future__ import annotations

from pathlib import Path

from schemas.manifest import CameraJitter, DimLight, Distractors, ForkliftCrossing, Occluder, ScenarioManifest
from schemas.panel import PanelSpec, PanelVariant, StressorCell, StressorGrid, contract_hash, panel_contract
from tasks.guard.text import GuardError, check_fields
# The one safe YAML path (no aliases, bounded size and depth) that manifests are read with.
from tasks.manifests import read_text, safe_mapping, validated

# A forklift lane that crosses each task's view without entering the workcell (x of the lane, m).
FORKLIFT_LANE = {"bin_pick": -0.9, "push": 1.2, "drive": 3.0}


class GridError(ValueError):
    """An unusable grid: one line naming the file or cell and the problem."""


def default_grid(parent: ScenarioManifest, episodes: int = 2) -> StressorGrid:
    """Nominal (the parent as is), clean (no stressors), then one stressor at a time: dim light,
    a forklift crossing, camera jitter, distractors and (arms) an occluder."""
    kinds = tuple(sorted({s.kind for s in parent.stressors}))
    cells = [StressorCell(name="nominal"), StressorCell(name="clean", drop=kinds),
             StressorCell(name="dim", stressors=(DimLight(lux=80),)),
             StressorCell(name="forklift", stressors=(ForkliftCrossing(speed_mps=1.5, lane_m=FORKLIFT_LANE[parent.task.kind],
                                                                       start_s=min(1.0, parent.horizon_s / 4)),)),
             StressorCell(name="jitter", stressors=(CameraJitter(amplitude_deg=2.0, frequency_hz=5.0),)),
             StressorCell(name="distractors", stressors=(Distractors(count=10),))]
    if parent.embodiment.kind == "arm":
        cells.append(StressorCell(name="occluder", stressors=(Occluder(coverage=0.5),)))
    return StressorGrid(name="default", description="one stressor at a time", cells=tuple(cells), episodes=episodes)


def parse_grid(text: str, where: str = "<grid>") -> StressorGrid:
    """A grid from YAML, read like a manifest (safe YAML only) and pre-guarded (its names)."""
    grid = validated(StressorGrid, safe_mapping(text, where, "grid", GridError), where, GridError)
    try:
        check_fields(grid)
    except GuardError as exc:
        raise GridError(f"{where}: {exc}") from None
    return grid


def load_grid(path: Path | str) -> StressorGrid:
    path = Path(path)
    return parse_grid(read_text(path, GridError), str(path))


def variant_manifest(parent: ScenarioManifest, grid: StressorGrid, cell: StressorCell) -> ScenarioManifest:
    """The parent with the cell's stressors (and the grid's seed): everything else unchanged."""
    replaced = {s.kind for s in cell.stressors} | set(cell.drop)
    stressors = [s for s in parent.stressors if s.kind not in replaced] + list(cell.stressors)
    body = parent.model_dump(mode="json")
    body.update(name=f"{parent.name[:62 - len(cell.name)]}--{cell.name}",
                description=f"panel variant {cell.name!r} ({grid.name}) of {parent.name}",
                stressors=[s.model_dump(mode="json") for s in stressors],
                seed=parent.seed if grid.seed is None else grid.seed, parent=parent.sha256)
    return validated(ScenarioManifest, body, f"cell {cell.name!r}: the variant is not a valid manifest", GridError)


def expand(parent: ScenarioManifest, grid: StressorGrid) -> tuple[PanelSpec, list[ScenarioManifest]]:
    """The panel spec and its variant manifests, in the grid's cell order."""
    variants = [variant_manifest(parent, grid, cell) for cell in grid.cells]
    contract = panel_contract(parent)
    for cell, variant in zip(grid.cells, variants):
        # By construction; a schema change that let a stressor move the contract would break panels.
        assert panel_contract(variant) == contract, f"cell {cell.name!r} changed the panel contract"
    seeds = tuple(variants[0].seed + i for i in range(grid.episodes))
    spec = PanelSpec(name=f"{parent.name}/{grid.name}", parent=parent.sha256, contract=contract,
                     contract_hash=contract_hash(contract), grid=grid,
                     variants=tuple(PanelVariant(cell=c.name, manifest_hash=v.sha256, seeds=seeds)
                                    for c, v in zip(grid.cells, variants)))
    return spec, variants


def resolve_grid(parent: ScenarioManifest, grid: str | None, episodes: int | None) -> StressorGrid:
    """The grid in YAML file ``grid`` (default: `default_grid`), with ``episodes`` seeds per cell when given."""
    chosen = load_grid(grid) if grid else default_grid(parent)
    if episodes is not None:
        chosen = StressorGrid.model_validate({**chosen.model_dump(mode="json"), "episodes": episodes})
    return chosen


def primary_camera(manifest: ScenarioManifest, camera: str | None) -> str:
    """``camera`` (it must be one of the manifest's), or its first world-mounted camera, or its first."""
    names = [c.name for c in manifest.cameras]
    if camera is not None and camera not in names:
        raise ValueError(f"camera {camera!r} is not in manifest {manifest.name} (it has {', '.join(names)})")
    return camera or next((c.name for c in manifest.cameras if c.mount == "world"), names[0])

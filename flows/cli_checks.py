"""What a command reads before it starts a flow, each refused in one line with exit 2: a
manifest, its robot files, a curate config, a video, a stressor grid, and checkpoints and
policies named by folder or id (looked up in lineage, read-only). The flow reads them again;
refusing here spares taking the lock and starting Prefect for nothing."""

from __future__ import annotations

from pathlib import Path

from flows.cli_shell import fail, refuse
from schemas.settings import Settings


def manifest(path: Path | str):
    from tasks.manifests import ManifestError, load

    try:
        return load(Path(path))
    except ManifestError as exc:
        fail(str(exc))


def simulable(path: Path | str):
    """A manifest whose robot files are all there (checked before any flow simulates it)."""
    from tasks.sim.scene import check_assets

    scenario = manifest(path)
    try:
        check_assets(scenario)
    except FileNotFoundError as exc:
        fail(f"{path}: {exc}")
    return scenario


def in_lineage(resolve):
    """``resolve(warehouse, data_root)`` with lineage open read-only (None before any flow has
    written it), or exit 2 with its one-line error: names are checked before a flow starts."""
    from tasks.checkpoint_files import CheckpointError
    from warehouse.store import Warehouse, WarehouseError

    settings = Settings()
    try:
        if not settings.warehouse_path.exists():
            return resolve(None, settings.data_root)
        with Warehouse(settings.warehouse_path, read_only=True) as warehouse:
            return resolve(warehouse, settings.data_root)
    except (FileNotFoundError, CheckpointError, WarehouseError) as exc:
        refuse(exc)


def world_model(name: str | None) -> str:
    from tasks.lookup import world_model_folder

    return str(in_lineage(lambda warehouse, root: world_model_folder(warehouse, root, name)))


def tokenizer(name: str, variant: str | None = "discrete") -> str:
    """The folder of a tokenizer checkpoint named by folder or id, its config checked (the flow
    loads the weights)."""
    from models.tokenizer import TokenizerConfig
    from tasks.checkpoint_files import CheckpointError, model_config, read_config
    from tasks.lookup import checkpoint_folder
    from warehouse.queries import tokenizer_condition

    what = f"{variant} tokenizer" if variant else "tokenizer"
    folder = in_lineage(lambda warehouse, root: checkpoint_folder(
        warehouse, root, name, tokenizer_condition(variant), what))
    try:
        config = model_config(TokenizerConfig, read_config(folder, "tokenizer", "tokenizer checkpoint"), "tokenizer",
                              folder)
    except CheckpointError as exc:
        fail(str(exc))
    if variant and config.variant != variant:
        fail(f"{name}: a {config.variant} tokenizer; a {variant} one is needed here")
    return str(folder)


def policies(names: list[str]) -> tuple[list[str], list]:
    """(names with ``bc:ID`` resolved to ``bc:FOLDER``, the policies they load)."""
    from tasks.lookup import policy_spec
    from tasks.policy.specs import PolicySpecError, load_policy

    specs = [in_lineage(lambda warehouse, root, name=name: policy_spec(warehouse, root, name)) for name in names]
    loaded = []
    for spec in specs:
        try:
            loaded.append(load_policy(spec))
        except PolicySpecError as exc:
            fail(str(exc))
    return specs, loaded


def curate_config(path: Path | str | None):
    from tasks.curate.config import ConfigError, load_config

    try:
        return load_config(Path(path) if path else None)
    except ConfigError as exc:
        fail(str(exc))


def grid(parent, path: str | None, episodes: int | None):
    from tasks.panels.grid import GridError, expand, resolve_grid

    try:
        return expand(parent, resolve_grid(parent, path, episodes))
    except GridError as exc:
        fail(str(exc))


def video(path: Path):
    from tasks.curate.decode import DecodeError, probe

    try:
        return probe(path)
    except DecodeError as exc:
        fail(str(exc))

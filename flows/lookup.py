"""Checkpoints named on the command line or in flow parameters: a folder, or the first 12 or
more hex digits of a checkpoint id in lineage (as reports and audits print them).

Each lookup takes an open warehouse (None before any flow has written one): a flow passes its
run's, the CLI a read-only one opened before the flow starts, so that a bad name is one line
rather than a failed flow run. Bad names raise FileNotFoundError, or CheckpointError (a
ValueError) for a folder whose config is unreadable or incomplete.
"""

from __future__ import annotations

from pathlib import Path

from tasks.checkpoint_files import CONFIG_FILE, CheckpointError
from warehouse.store import Warehouse

POSTTRAINED_WORLD_MODEL = "attrs->>'model' = 'world_model' AND attrs->>'phase' = 'posttrain'"
BC_POLICY = "attrs->>'model' = 'bc-policy'"


def tokenizer_condition(variant: str | None) -> str:
    """Tokenizer checkpoints of ``variant`` ("discrete", "continuous"), or of any when None."""
    return "attrs->>'preset' IS NOT NULL" if variant is None else f"attrs->>'variant' = '{variant}'"


def is_hex_id(text: str) -> bool:
    """12 or more lower-case hex digits: a prefix of an artifact id or a hash."""
    return len(text) >= 12 and all(ch in "0123456789abcdef" for ch in text)


def checkpoint_by_id(warehouse: Warehouse | None, prefix: str, condition: str, what: str) -> tuple[str, str]:
    """(artifact id, weights uri) of the one checkpoint matching the SQL ``condition`` whose id
    starts with ``prefix``; FileNotFoundError naming ``what`` when there is none or several
    (or no lineage yet: ``warehouse`` None)."""
    if warehouse is None:
        raise FileNotFoundError(f"{what} {prefix}: no lineage warehouse yet to look the id up in")
    _, rows = warehouse.query(f"SELECT artifact_id, uri FROM artifacts WHERE kind = 'checkpoint' AND {condition} "
                              "AND artifact_id LIKE $prefix || '%' ORDER BY artifact_id LIMIT 2", {"prefix": prefix})
    if len(rows) != 1:
        raise FileNotFoundError(f"{what} {prefix}: {'no' if not rows else 'more than one'} "
                                f"{what} checkpoint with that id in lineage")
    return rows[0]


def checkpoint_folder(warehouse: Warehouse | None, root: Path, name: str, condition: str, what: str) -> Path:
    """The folder ``name`` (it must hold a config.json), or the folder of the checkpoint whose
    id starts with ``name``."""
    if Path(name).is_dir():
        folder = Path(name).resolve()
        if not (folder / CONFIG_FILE).is_file():
            raise FileNotFoundError(f"{name}: not a {what} checkpoint folder (no {CONFIG_FILE})")
        return folder
    if not is_hex_id(name):
        raise FileNotFoundError(f"{name}: no such checkpoint folder, and not a checkpoint id")
    return (Path(root).resolve() / checkpoint_by_id(warehouse, name, condition, what)[1]).parent


def world_model_folder(warehouse: Warehouse | None, root: Path, name: str | None) -> Path:
    """A post-trained world model: a checkpoint folder, an id prefix, or None for the newest.
    Its config must name the tokenizer and frame size it was trained with."""
    from tasks.world import checkpoints

    if name:
        folder = checkpoint_folder(warehouse, root, name, POSTTRAINED_WORLD_MODEL, "world model")
    else:
        _, rows = warehouse.query("SELECT uri FROM artifacts WHERE kind = 'checkpoint' AND "
                                  f"{POSTTRAINED_WORLD_MODEL} ORDER BY recorded_at DESC, artifact_id LIMIT 1"
                                  ) if warehouse is not None else ([], [])
        if not rows:
            raise FileNotFoundError("no post-trained world model in lineage: run `worldline train` first")
        folder = (Path(root).resolve() / rows[0][0]).parent
    config = checkpoints.read_config(folder)
    if missing := [key for key in ("tokenizer", "size") if key not in config]:
        raise CheckpointError(f"{folder / CONFIG_FILE}: not a post-trained world model's config "
                              f"(no {', '.join(missing)})")
    return folder


def policy_spec(warehouse: Warehouse | None, root: Path, spec: str) -> str:
    """``bc:ID`` with ID a behaviour-cloning checkpoint's id prefix becomes ``bc:FOLDER``; every
    other policy name is returned as it is."""
    kind, _, arg = spec.partition(":")
    if kind != "bc" or not arg or Path(arg).exists() or not is_hex_id(arg):
        return spec
    return f"bc:{checkpoint_folder(warehouse, root, arg, BC_POLICY, 'behaviour-cloning policy')}"

"""`worldline export lerobot`: simulated episodes written in the layouts other tools read
(docs/export.md). No Prefect flow and no writer lock: it reads the data root and writes only
under --out."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from flows.cli_shell import app, held, out, say
from schemas.errors import EXIT_PARTIAL
from schemas.settings import Settings

export_app = typer.Typer(no_args_is_help=True, help="Export simulated episodes to the dataset layouts other tools read.")
app.add_typer(export_app, name="export")


def _from_lineage(manifest_hash: str) -> tuple[str | None, str | None]:
    """(instruction, robot) of a manifest lineage recorded, read-only; (None, None) when lineage
    does not have it (the episode's task kind is then its task text)."""
    from warehouse import queries
    from warehouse.store import Warehouse, WarehouseError

    path = Settings().warehouse_path
    if not path.exists():
        return None, None
    try:
        with Warehouse(path, read_only=True) as warehouse:
            body = queries.manifest_body(warehouse, manifest_hash)
    except WarehouseError:
        return None, None
    if body is None:
        return None, None
    scenario = json.loads(body)
    return scenario["task"]["instruction"], scenario["embodiment"]["robot"]


@export_app.command("lerobot")
def lerobot(
    sources: list[str] = typer.Argument(..., metavar="EPISODES_OR_MANIFEST...", help=(
        "manifest YAMLs (their episodes under the data root), manifest hashes, folders of episodes or episode "
        "folders")),
    dest: Path = typer.Option(..., "--out", help="the dataset folder to write (new or empty)"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace --out when it holds an earlier export"),
) -> None:
    """Write episodes as a LeRobot dataset (v3.0, what `lerobot` 0.4 reads): one row per video
    frame, float32 state and action, the MP4s per camera; exit 1 if damaged episodes were left out."""
    from flows import ephemeral
    from tasks.export.run import export_lerobot

    held.enter_context(ephemeral.interrupts_handled())  # SIGTERM as Ctrl-C: the staging folder is removed
    result = export_lerobot(sources, dest, Settings().data_root, overwrite=overwrite, instruction_of=_from_lineage,
                            on_damaged=lambda line: say(f"skipped {line}"))
    done = result.exported
    out.print(f"{done.episodes} episodes ({done.frames} frames, {len(done.tasks)} tasks) written to {done.out} as a "
              f"LeRobot v3.0 dataset; {len(result.skipped)} damaged episodes skipped", highlight=False, soft_wrap=True)
    if result.skipped:
        raise typer.Exit(EXIT_PARTIAL)

"""Before a writing command starts Prefect and its work: is the data root usable?

A folder the data root keeps (clips/, shards/, ...) that is a file or cannot be written, or a
warehouse file that is not a Worldline warehouse, was found only when the work reached it:
after every video was analysed and encoded (a traceback from the shard writer), or 15 s in,
once Prefect had started (two lines: Prefect's and the command's). Here each is one line,
exit 5, before anything runs. Readers never call this.
"""

from __future__ import annotations

import os
from pathlib import Path

import duckdb

from schemas import paths
from schemas.errors import EnvironmentFault
from warehouse import store
from warehouse.store import WarehouseUnusable, damaged


def check_folders(root: Path) -> None:
    """EnvironmentFault naming the first of the layout's folders that is not a folder, or that
    this user cannot write; a missing one is fine (it is made when needed)."""
    for name in paths.layout_folders():
        place = root / name
        if place.exists() and not place.is_dir():
            raise EnvironmentFault(f"{paths.escaped(str(place))}: a file where the data root keeps its "
                                   f"{name}/ folder; move it aside")
        if place.is_dir() and not os.access(place, os.W_OK | os.X_OK):
            raise EnvironmentFault(f"{paths.escaped(str(place))}: this user cannot write this folder of the data root")


def check_warehouse(path: Path) -> None:
    """WarehouseUnusable (or the damaged-warehouse fault) when the file at ``path`` is not a
    Worldline warehouse DuckDB can open; nothing when there is no file yet or another process
    holds it (the writer's own wait reports that) or this process has it open already."""
    if not path.exists() or store._OPEN.get(path.resolve()):
        return
    if path.is_dir():
        raise WarehouseUnusable(f"{paths.escaped(str(path))}: cannot open the warehouse: it is a folder")
    try:
        con = duckdb.connect(str(path), read_only=True)
    except duckdb.Error as exc:
        if store._is_damage(exc):
            raise damaged(path, store._first_line(exc)) from None
        if store._LOCKED in str(exc):
            return
        raise WarehouseUnusable(f"{paths.escaped(str(path))}: cannot open the warehouse: "
                                f"{store._first_line(exc)}") from None
    try:
        tables = {row[0] for row in con.execute(
            "SELECT table_name FROM information_schema.tables WHERE table_schema = 'main'").fetchall()}
    finally:
        con.close()
    if tables and "worldline_meta" not in tables:
        raise WarehouseUnusable(f"{paths.escaped(str(path))}: not a Worldline warehouse "
                                f"(tables {sorted(tables)[:5]} but no worldline_meta)")

"""`worldline sql` and `worldline report`: read lineage without holding up a flow that writes it."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from flows.cli_shell import FORMAT, app, check_format, out, print_rows, refuse
from schemas.errors import WorldlineError
from schemas.settings import Settings


@app.command()
def sql(
    statement: str = typer.Argument(..., help="one read-only SQL statement on the lineage tables (docs/lineage.md)"),
    fmt: str = FORMAT,
) -> None:
    """Run one read-only SQL statement on the lineage warehouse. While a flow writes, it reads
    the snapshot the writer publishes (<data_root>/lineage.snapshot.duckdb), so it never holds
    the flow up (docs/lineage.md)."""
    from warehouse.snapshot import query
    from warehouse.store import WarehouseError

    check_format(fmt)
    try:
        cols, rows = query(statement)
    except WarehouseError as exc:
        refuse(exc)
    print_rows(cols, rows, fmt, title=f"{len(rows)} rows")


@app.command()
def report(
    subject: str = typer.Argument(..., help="run id or artifact id, or the start of exactly one"),
    out_path: Optional[Path] = typer.Option(None, "--out", help="the HTML file; default <data_root>/reports/<id>.html"),
) -> None:
    """Write one self-contained HTML page about a run or an artifact: its tables, plots,
    contact sheets, lineage graph and links to its files (docs/report.md). Prints its path."""
    from tasks.report import write_report
    from warehouse.snapshot import open_snapshot
    from warehouse.store import WarehouseError

    settings = Settings()
    try:
        with open_snapshot(settings.warehouse_path) as wh:
            path = write_report(wh, subject, out_path, data_root=settings.data_root)
    except (WorldlineError, WarehouseError) as exc:
        refuse(exc)
    out.print(str(path), highlight=False, soft_wrap=True)

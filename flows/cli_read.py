"""`worldline sql` and `worldline report`: read lineage without holding up a flow that writes it."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from flows.cli_shell import FORMAT, app, check_format, out, print_rows, refuse, say
from schemas.errors import WorldlineError
from schemas.settings import Settings


@app.command()
def sql(
    statement: str = typer.Argument(..., help="one read-only SQL statement on the lineage tables (docs/lineage.md)"),
    fmt: str = FORMAT,
    limit: int = typer.Option(10_000, "--limit", min=0, help="print at most this many rows (0: every row)"),
) -> None:
    """Run one read-only SQL statement on the lineage warehouse. While a flow writes, it reads
    the snapshot the writer publishes (<data_root>/lineage.snapshot.duckdb), so it never holds
    the flow up (docs/lineage.md). It neither writes nor reads files (no COPY ... TO, EXPORT,
    read_csv)."""
    from warehouse.snapshot import query
    from warehouse.store import WarehouseError

    check_format(fmt)
    try:
        cols, rows, more = query(statement, limit=limit or None)
    except WarehouseError as exc:
        refuse(exc)
    print_rows(cols, rows, fmt, title=f"first {len(rows)} rows (more left: --limit)" if more else f"{len(rows)} rows")
    if more and fmt != "table":
        say(f"worldline sql: printed the first {len(rows)} rows; more are left (--limit N, 0 for every row)")


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

"""The terminal a `worldline` command writes to: ``out`` for results (stdout) and ``err`` for
everything else (stderr): messages, progress bars (flows/report.py) and Prefect's log lines,
all through one console, so a log line is printed above a live bar instead of tearing it.

Neither console wraps what it prints: a line longer than the terminal is the terminal's to
wrap, so a hash or a path copied out of it, or piped into a file, stays whole. Prefect's INFO
lines (flow and task runs starting and finishing, the temporary server) show only with
``worldline -v``; its warnings and errors always show. Prefect still sends every line to its
API, so the UI keeps them all.
"""

from __future__ import annotations

import logging

from rich.console import Console
from rich.text import Text

out = Console(soft_wrap=True)
err = Console(stderr=True, soft_wrap=True)
_verbose = False


def set_verbose(on: bool) -> None:
    global _verbose
    _verbose = on


def verbose() -> bool:
    return _verbose


class ConsoleLog(logging.Handler):
    """Prefect's console handler, printed through ``err`` (plain text: no markup, no
    highlighting); below WARNING only when verbose; never a flow run's error line that the CLI
    states again as it exits (``restated``, flows/cli.py)."""

    def __init__(self, formatter: logging.Formatter | None = None, level: int = logging.NOTSET):
        super().__init__(level)
        self.setFormatter(formatter)
        self.addFilter(lambda record: (_verbose or record.levelno >= logging.WARNING)
                       and not getattr(record, "restated", False))  # the CLI says it as it exits

    def emit(self, record: logging.LogRecord) -> None:
        try:
            err.print(Text(self.format(record)), soft_wrap=True)
        except Exception:
            self.handleError(record)


def route_prefect_logs() -> None:
    """Prefect's logging set up as always, then its console handler swapped for a
    ``ConsoleLog`` (idempotent). Called by a command before it starts a flow."""
    from prefect.logging.configuration import ensure_logging_setup
    from prefect.logging.handlers import PrefectConsoleHandler

    ensure_logging_setup()
    for logger in (logging.getLogger(), logging.getLogger("uvicorn"), logging.getLogger("fastapi")):
        for i, handler in enumerate(logger.handlers):
            if isinstance(handler, PrefectConsoleHandler):
                logger.handlers[i] = ConsoleLog(handler.formatter, handler.level)


FORMATS = ("table", "csv", "json")


def short_id(value):
    """An id (16 or more lower-case hex digits: an artifact id, a manifest hash, a sha256) or a
    run's UUID cut to its first 12 characters, as tables show them (the commands that take an
    id take its first 12 characters); anything else as it is."""
    if isinstance(value, str) and (len(value) >= 16 and _is_hex(value) or len(value) == 36 and _is_uuid(value)):
        return value[:12]
    return value


def _is_hex(text: str) -> bool:
    return all(c in "0123456789abcdef" for c in text)


def _is_uuid(text: str) -> bool:
    return [len(p) for p in text.split("-")] == [8, 4, 4, 4, 12] and _is_hex(text.replace("-", ""))


def _cell(value) -> str:
    """A value as a table shows it: an id cut to 12 characters, a time to the second."""
    from datetime import datetime

    if value is None:
        return ""
    if isinstance(value, datetime):
        return value.isoformat(sep=" ", timespec="seconds")
    return str(short_id(value))


def _atomic(value) -> bool:
    """Never wrapped in a table: an id or a number (a time, a path or a sentence may fold)."""
    return value is None or isinstance(value, (int, float)) or short_id(value) is not value


def print_rows(cols: list[str], rows: list[tuple], fmt: str, title: str | None = None) -> None:
    """Rows on stdout: ``json`` (a list of objects) and ``csv`` written as they are, never
    wrapped nor coloured, ids whole; ``table`` a rich table with ids cut to 12 characters and
    kept on one line (other text folds to fit the terminal)."""
    import csv
    import json
    import sys

    if fmt == "json":
        sys.stdout.write(json.dumps([dict(zip(cols, r)) for r in rows], default=str, indent=2) + "\n")
    elif fmt == "csv":
        writer = csv.writer(sys.stdout, lineterminator="\n")
        writer.writerow(cols)
        writer.writerows(rows)
    else:
        from rich.table import Table

        from rich import box

        table = Table(title=title, box=box.SIMPLE_HEAD, show_edge=False, padding=(0, 1, 0, 0))  # room for the cells
        cells = [[_cell(v) for v in r] for r in rows]
        need = 2 * len(cols)
        for i, c in enumerate(cols):
            widest = max((len(r[i]) for r in cells), default=0)
            whole = bool(rows) and all(_atomic(r[i]) for r in rows)  # ids and numbers whole; text folds
            table.add_column(c, overflow="fold", no_wrap=whole, min_width=widest if whole else min(widest, 10))
            need += widest if whole else min(widest, 10)
        for r in cells:
            table.add_row(*map(Text, r))
        out.print(table, width=max(out.width, need))  # wider than the terminal rather than an id cut

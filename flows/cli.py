"""The `worldline` command: subcommands map to flows; each takes a manifest and a few overrides.

Exit codes (schemas/errors.py): 0 done, 1 partial (some inputs failed), 2 invalid input,
3 not built (run an earlier step first), 4 busy (another process writes to the data root),
5 environment (disk full, a damaged warehouse, a file changed behind lineage's back),
130 interrupted by Ctrl-C (SIGINT), 143 interrupted by SIGTERM.
"""

from __future__ import annotations

import logging

from flows import cli_controls, cli_data, cli_export, cli_lineage, cli_policy, cli_read, cli_transfer, cli_world  # noqa: F401  (they register the commands)
from flows.cli_shell import app, evaluate_app, manifest_app
from schemas.errors import WorldlineError

# The command modules register by topic; `worldline --help` lists them in this order.
ORDER = ["audit", "summary", "sql", "report", "register", "simulate", "corpus", "demo", "server", "curate", "scenes", "inspect",
         "controls", "train-transfer", "transfer", "tokenize", "train", "panels", "train-policy", "loop", "verify", "export"]

app.info.help = __doc__
app.registered_commands.sort(key=lambda c: ORDER.index(c.name or c.callback.__name__))
evaluate_app.registered_commands.sort(key=lambda c: c.name)  # camera, physics, policies, rig
app.add_typer(manifest_app, name="manifest")
app.add_typer(evaluate_app, name="evaluate")


class _InputErrorsInOneLine(logging.Filter):
    """Prefect logs a failed flow or task run's exception with its traceback; from the CLI an
    input error (FileNotFoundError, ValueError: a missing file, a refused manifest or contract),
    a WorldlineError, an interrupt, a full disk or a place that cannot be written is then stated
    in one line, as the CLI states it again on exit. A flow run's own line for a WorldlineError or
    an interrupt (which DuckDB reports as "Query interrupted"), and a flow or task run's for such
    an OSError, which the CLI states as it exits, is marked ``restated``:
    the terminal leaves it out (flows/console.py), Prefect's API keeps it. Other errors keep their
    traceback, and so does every run a worker executes."""

    def filter(self, record: logging.LogRecord) -> bool:
        from flows.ephemeral import signal_name

        from tasks.faults import DISK_FULL, UNWRITABLE

        exc = record.exc_info[1] if record.exc_info else None
        machine = isinstance(exc, OSError) and exc.errno in DISK_FULL | UNWRITABLE
        if exc is not None and (isinstance(exc, (FileNotFoundError, ValueError, WorldlineError)) or signal_name(exc)
                                or machine):
            record.exc_info = record.exc_text = None
            record.restated = machine or record.name == "prefect.flow_runs" and (
                isinstance(exc, WorldlineError) or bool(signal_name(exc)))
        return True


def main() -> None:
    for name in ("prefect.flow_runs", "prefect.task_runs"):
        logging.getLogger(name).addFilter(_InputErrorsInOneLine())
    try:
        app()
    except SystemExit as exc:
        from flows.ephemeral import leave_after_signal

        leave_after_signal(exc.code)
        raise


if __name__ == "__main__":
    main()

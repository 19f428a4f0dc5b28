"""The shell every `worldline` command runs in: its exit codes on errors a user can act on, the
writer lock it holds and the checks it makes before Prefect starts, and how it prints. Commands
declared from a flow's parameter model are built in flows/cli_command.py."""

from __future__ import annotations

import os
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Optional

import typer
from typer.core import TyperGroup

import flows  # sets PREFECT_HOME before anything imports prefect
from flows.console import FORMATS, err, out, print_rows, set_verbose  # noqa: F401  (print_rows: the commands)
from flows.params import FlowParams, Refused
from flows.server_found import find_running_server
from schemas.errors import EXIT_ENVIRONMENT, EXIT_INVALID, WorldlineError
from schemas.settings import Settings, SettingsError


class Commands(TyperGroup):
    """Every command ends with one line and its exit code, never a traceback, for the errors a
    user can act on: a WorldlineError (raised anywhere, a flow included), a full disk, SIGTERM."""

    def invoke(self, ctx):
        from flows.ephemeral import exit_code, signal_name

        try:
            with held:
                return super().invoke(ctx)
        except BaseException as exc:
            code = exit_code(exc)  # after SIGINT or SIGTERM, whatever the interrupt surfaced as
            if code is not None and not isinstance(exc, typer.Exit):
                say(f"interrupted by {signal_name(exc)}")  # Prefect's line named what it surfaced as
            if code is None and isinstance(exc, WorldlineError):
                say(str(exc))
                code = exc.exit_code
            elif code is None and (fault := _machine(exc)) is not None:
                say(fault)
                code = EXIT_ENVIRONMENT
            if code is None:
                raise
            raise typer.Exit(code) from None


def _machine(exc: BaseException) -> str | None:
    """The line for an OSError that is the machine's: a full disk, or a place under the data root
    that cannot be written (a read-only folder, a file where a folder belongs)."""
    from tasks import faults

    if isinstance(exc, OSError) and exc.errno in faults.DISK_FULL:
        return f"disk full: {exc.filename or exc.strerror}"
    try:
        fault = faults.unwritable(exc, Settings().data_root, "writing")
    except SettingsError:
        return None
    return None if fault is None else str(fault)


held = ExitStack()  # what a command holds until it ends (writing), released before its exit code is set
app = typer.Typer(cls=Commands, add_completion=False, no_args_is_help=True)  # its help: flows/cli.py
FORMAT = typer.Option("table", "--format", help="table (ids cut to 12 characters) | csv | json (never wrapped, ids whole)")
manifest_app = typer.Typer(no_args_is_help=True, help="Validate, hash and show scenario manifests.")
evaluate_app = typer.Typer(no_args_is_help=True, help="Evaluate world models against the simulator, and policies.")


def say(message: str) -> None:
    err.print(message, markup=False, highlight=False, soft_wrap=True)


def fail(message: str, code: int = EXIT_INVALID) -> None:
    say(message)
    raise typer.Exit(code)


def refuse(exc: Exception) -> None:
    """``fail`` with an error's message and its exit code (2 unless it is a WorldlineError)."""
    fail(str(exc), exc.exit_code if isinstance(exc, WorldlineError) else EXIT_INVALID)


@contextmanager
def checked(model: type[FlowParams]):
    """A model's check on data (a manifest, episodes) refused in one line, naming options."""
    try:
        yield
    except Refused as exc:
        fail(exc.named(model.labels(cli=True)))


def writing() -> None:
    """For the rest of this command: the data root's writer lock (taken now, before Prefect
    starts; exit 4 after WORLDLINE_LOCK_TIMEOUT seconds of waiting), a running Prefect server
    used when there is one (flows/server_found.py), else a temporary one stopped on the way out,
    Prefect's log lines through the shared console (flows/console.py), and Ctrl-C or SIGTERM
    ending the command within seconds (flows/ephemeral.py)."""
    from flows import ephemeral
    from flows.console import route_prefect_logs, verbose
    from flows.server_found import use_running_server
    from warehouse import lock, preflight, store

    settings = Settings()
    held.enter_context(ephemeral.interrupts_handled())
    held.enter_context(lock.writer(settings.data_root, settings.lock_timeout, on_wait=lambda holder: say(
        f"{settings.data_root}: another worldline process ({holder}) is writing; waiting up to "
        f"{settings.lock_timeout:g} s")))
    preflight.check_folders(settings.data_root)  # one line now, not a traceback when the work reaches it
    preflight.check_warehouse(settings.warehouse_path)
    store.on_wait = lambda holder: say(f"{holder}; waiting up to {settings.lock_timeout:g} s")
    if (api_url := use_running_server()) and verbose():
        say(f"Prefect API: {api_url}")
    ephemeral.guard_prefect()
    route_prefect_logs()
    held.enter_context(ephemeral.servers_stopped_on_exit())


def check_format(fmt: str) -> None:
    if fmt not in FORMATS:
        fail(f"--format {fmt!r}: one of {', '.join(FORMATS)}")


def _version(shown: bool) -> None:
    if shown:
        from importlib.metadata import version

        out.print(f"worldline {version('worldline')}", highlight=False)
        raise typer.Exit()


@app.callback()
def options(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="print the version and exit"),
    data_root: Optional[Path] = typer.Option(None, "--data-root", help="the same as WORLDLINE_DATA_ROOT, which it overrides"),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="show Prefect's log lines (warnings and errors "
                                 "show anyway)"),
) -> None:
    set_verbose(verbose)
    os.environ.setdefault("DO_NOT_TRACK", "1")  # Prefect's SDK telemetry off (no network here), and its notice
    if data_root is not None:
        ours = str(Settings().prefect_home_path.resolve())  # PREFECT_HOME as flows/__init__.py set it
        os.environ["WORLDLINE_DATA_ROOT"] = str(data_root)
        if os.environ.get("PREFECT_HOME") == ours:  # not the user's own: it follows the data root
            del os.environ["PREFECT_HOME"]
        try:
            flows.configure_prefect()
        except SettingsError as exc:  # a data root that is a file, or cannot be made: one line, not a traceback
            fail(f"--data-root {data_root}: {exc}")
    find_running_server()  # before Prefect is imported: it reads PREFECT_API_URL once

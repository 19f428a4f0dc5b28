"""`worldline manifest ...`, `audit`, `summary` and `verify`: manifests and lineage, read-only."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import typer

from flows import cli_checks as need
from flows.cli_shell import FORMAT, app, check_format, err, fail, manifest_app, out, print_rows, refuse
from schemas.errors import EXIT_ENVIRONMENT, EXIT_INVALID
from schemas.settings import Settings



@manifest_app.command("validate")
def manifest_validate(paths: list[Path]) -> None:
    """Validate manifests: one line per invalid file (file, field, problem); exit 2 if any."""
    from tasks.manifests import ManifestError, load
    from tasks.sim.mjcf import RobotFileError
    from tasks.sim.scene import check_assets

    bad = 0
    for path in paths:
        try:
            manifest = load(path)
            try:  # robot files present here must stay inside the robots root; a missing one is
                check_assets(manifest)  # the machine's matter, said when a command simulates
            except RobotFileError as exc:
                raise ManifestError(f"{path}: {exc}") from None
            except FileNotFoundError:
                pass
            out.print(f"ok {path}", highlight=False)
        except ManifestError as exc:
            bad += 1
            err.print(str(exc), markup=False, highlight=False, soft_wrap=True)
    if bad:
        raise typer.Exit(EXIT_INVALID)


@manifest_app.command("hash")
def manifest_hash_cmd(path: Path) -> None:
    """Print the manifest hash (sha256 of its canonical JSON)."""
    sys.stdout.write(need.manifest(path).sha256 + "\n")


@manifest_app.command("show")
def manifest_show(path: Path) -> None:
    """Print the manifest with every default filled in, and its hash."""
    from tasks.manifests import dump_yaml

    manifest = need.manifest(path)  # plain text, never wrapped: valid YAML in a file or a pipe
    sys.stdout.write(f"# manifest_hash: {manifest.sha256}\n{dump_yaml(manifest).rstrip()}\n")


@app.command()
def audit(
    name: Optional[str] = typer.Argument(None, help="audit to run; omit to list them"),
    manifest: Optional[str] = typer.Option(None, help="manifest hash"),
    artifact: Optional[str] = typer.Option(None, help="artifact id"),
    fmt: str = FORMAT,
) -> None:
    """Run a shipped audit query (warehouse/audits/NAME.sql) with bound parameters. A manifest
    hash or artifact id may be given by its first 12 or more hex digits."""
    from warehouse import audit as audits
    from warehouse.store import Warehouse, WarehouseError

    if name is None or name not in audits.available():
        if name is not None:
            err.print(f"unknown audit {name!r}", highlight=False)
        lines = [f"  {n}: {audits.describe(n)}  (--{' --'.join(audits.parameters(audits.load(n)))})"
                 for n in audits.available()]
        (err if name else out).print("available audits:\n" + "\n".join(lines), highlight=False, markup=False)
        raise typer.Exit(EXIT_INVALID if name else 0)
    check_format(fmt)
    try:
        sql, params = audits.bind(name, {"manifest": manifest, "artifact": artifact})
    except ValueError as exc:
        fail(str(exc))
    try:
        with Warehouse(Settings().warehouse_path, read_only=True) as wh:
            ids = (("manifest", "manifests", "manifest_hash"), ("artifact", "artifacts", "artifact_id"))
            for key, table, column in ids:
                if key in params:
                    params[key] = _full_id(wh, table, column, params[key], key)
            cols, rows = wh.query(sql, params)
    except WarehouseError as exc:
        refuse(exc)
    print_rows(cols, rows, fmt, title=f"{name} ({len(rows)} rows)")


def _full_id(warehouse, table: str, column: str, given: str, what: str) -> str:
    """The one full id in ``table`` that starts with ``given`` (12+ hex digits), or ``given``
    itself when it is a full id or is not hex; one line, exit 2, when lineage has no such id
    (an audit of a mistyped hash printed 0 rows and exit 0)."""
    from tasks.lookup import is_hex_id
    from warehouse.queries import ids_starting, knows

    found = ids_starting(warehouse, table, column, given) if is_hex_id(given) and len(given) < 64 else []
    if len(found) > 1:
        fail(f"--{what} {given}: more than one {what} starts with it ({found[0]}, {found[1]}, ...)")
    full = found[0] if found else given
    if not knows(warehouse, what, full):
        fail(f"--{what} {given}: no such {what} in lineage")
    return full


@app.command()
def summary(fmt: str = FORMAT) -> None:
    """Counts of every lineage table, artifacts by kind, and runs per flow and status. As csv
    one table: section (tables, artifacts, runs), name, status, count, bytes, last_ended."""
    from warehouse import queries
    from warehouse.store import Warehouse, WarehouseError

    check_format(fmt)
    try:
        with Warehouse(Settings().warehouse_path, read_only=True) as wh:
            counts = wh.counts()
            cols, rows = queries.runs_by_flow(wh)
            kcols, krows = queries.artifacts_by_kind(wh)
    except WarehouseError as exc:
        refuse(exc)
    if fmt == "json":
        sys.stdout.write(json.dumps({"tables": counts, "artifacts_by_kind": [dict(zip(kcols, r)) for r in krows],
                                    "runs": [dict(zip(cols, r)) for r in rows]}, default=str, indent=2) + "\n")
    elif fmt == "csv":
        print_rows(["section", "name", "status", "count", "bytes", "last_ended"],
                   [("tables", t, None, n, None, None) for t, n in counts.items()]
                   + [("artifacts", k, None, n, b, None) for k, n, b in krows]
                   + [("runs", f, st, n, None, last) for f, st, n, last in rows], "csv")
    else:
        print_rows(["table", "rows"], list(counts.items()), "table", title=f"lineage {Settings().warehouse_path}")
        print_rows(kcols, krows, "table", title="artifacts by kind")
        print_rows(cols, rows, "table", title="runs")


@app.command()
def verify(
    manifest: Optional[str] = typer.Option(None, help="only this manifest's artifacts (hash, or its first 12+ hex digits)"),
    fmt: str = FORMAT,
) -> None:
    """Check every file lineage recorded (or one manifest's) against its sha256: list the
    missing, the changed, and paths two rows claim with different sha256s; exit 5 when any
    differ. Reads the warehouse only (tasks/integrity.py `audit`: manifests are not files)."""
    from tasks import integrity
    from warehouse import integrity as claims
    from warehouse.store import Warehouse, WarehouseError

    check_format(fmt)
    settings = Settings()
    try:
        with Warehouse(settings.warehouse_path, read_only=True) as wh:
            if manifest is not None:
                manifest = _full_id(wh, "manifests", "manifest_hash", manifest, "manifest")
            rows = [integrity.Recorded(*r) for r in claims.files(wh, manifest)]
    except WarehouseError as exc:
        refuse(exc)
    findings, checked, hashed = integrity.audit(rows, settings.data_root)
    print_rows(["problem", "kind", "artifact_id", "uri", "lineage_sha256", "file_sha256"],
               [(f.problem, f.kind, f.artifact_id, f.uri, f.lineage_sha256, f.file_sha256)
                for f in findings], fmt, title=f"files that differ from lineage ({len(findings)})")
    problems = [f for f in findings if f.problem in integrity.PROBLEMS]
    counts = ", ".join(f"{sum(f.problem == p for f in findings)} {p}" for p in integrity.PROBLEMS)
    notes = len(findings) - len(problems)
    line = (f"{checked} artifacts checked, {hashed} files hashed: "
            + (f"{len(problems)} differ from lineage ({counts})" if problems else "all match lineage")
            + (f"; {notes} superseded (inputs rewritten in place and curated again)" if notes else ""))
    (out if fmt == "table" else err).print(line, highlight=False, markup=False, soft_wrap=True)  # csv, json parseable
    if problems:
        raise typer.Exit(EXIT_ENVIRONMENT)

"""The `worldline` command: subcommands map to flows; each takes a manifest and a few overrides."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

import flows  # noqa: F401  (sets PREFECT_HOME before anything imports prefect)
from schemas.settings import Settings

app = typer.Typer(add_completion=False, no_args_is_help=True, help=__doc__)
manifest_app = typer.Typer(no_args_is_help=True, help="Validate, hash and show scenario manifests.")
app.add_typer(manifest_app, name="manifest")
out = Console()
err = Console(stderr=True)

EXIT_INVALID = 2
EXIT_NOT_BUILT = 3


def _fail(message: str, code: int = EXIT_INVALID) -> None:
    err.print(message, markup=False, highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def _load_or_exit(path: Path):
    from tasks.manifests import ManifestError, load

    try:
        return load(path)
    except ManifestError as exc:
        _fail(str(exc))


def _print_rows(cols: list[str], rows: list[tuple], fmt: str, title: str | None = None) -> None:
    if fmt == "json":
        out.print_json(json.dumps([dict(zip(cols, r)) for r in rows], default=str))
    elif fmt == "csv":
        writer = csv.writer(sys.stdout)
        writer.writerow(cols)
        writer.writerows(rows)
    else:
        table = Table(title=title)
        for c in cols:
            table.add_column(c, overflow="fold")
        for r in rows:
            table.add_row(*("" if v is None else str(v) for v in r))
        out.print(table)


# -- manifests ----------------------------------------------------------------------------
@manifest_app.command("validate")
def manifest_validate(paths: list[Path]) -> None:
    """Validate manifests: one line per invalid file (file, field, problem); exit 2 if any."""
    from tasks.manifests import ManifestError, load

    bad = 0
    for path in paths:
        try:
            load(path)
            out.print(f"ok {path}", highlight=False)
        except ManifestError as exc:
            bad += 1
            err.print(str(exc), markup=False, highlight=False, soft_wrap=True)
    if bad:
        raise typer.Exit(EXIT_INVALID)


@manifest_app.command("hash")
def manifest_hash_cmd(path: Path) -> None:
    """Print the manifest hash (sha256 of its canonical JSON)."""
    from schemas.manifest import manifest_hash

    out.print(manifest_hash(_load_or_exit(path)), highlight=False)


@manifest_app.command("show")
def manifest_show(path: Path) -> None:
    """Print the manifest with every default filled in, and its hash."""
    from schemas.manifest import manifest_hash
    from tasks.manifests import dump_yaml

    manifest = _load_or_exit(path)
    out.print(f"# manifest_hash: {manifest_hash(manifest)}", highlight=False)
    out.print(dump_yaml(manifest), highlight=False, markup=False)


# -- lineage ------------------------------------------------------------------------------
@app.command()
def audit(
    name: Optional[str] = typer.Argument(None, help="audit to run; omit to list them"),
    manifest: Optional[str] = typer.Option(None, help="manifest hash"),
    artifact: Optional[str] = typer.Option(None, help="artifact id"),
    fmt: str = typer.Option("table", "--format", help="table | csv | json"),
) -> None:
    """Run a shipped audit query (warehouse/audits/NAME.sql) with bound parameters."""
    from warehouse import audit as audits
    from warehouse.store import Warehouse, WarehouseError

    if name is None or name not in audits.available():
        if name is not None:
            err.print(f"unknown audit {name!r}", highlight=False)
        lines = [f"  {n}: {audits.describe(n)}  (--{' --'.join(audits.parameters(audits.load(n)))})"
                 for n in audits.available()]
        (err if name else out).print("available audits:\n" + "\n".join(lines), highlight=False, markup=False)
        raise typer.Exit(EXIT_INVALID if name else 0)
    try:
        sql, params = audits.bind(name, {"manifest": manifest, "artifact": artifact})
    except ValueError as exc:
        _fail(str(exc))
    try:
        with Warehouse(Settings().warehouse_path, read_only=True) as wh:
            cols, rows = wh.query(sql, params)
    except WarehouseError as exc:
        _fail(str(exc))
    _print_rows(cols, rows, fmt, title=f"{name} ({len(rows)} rows)")


@app.command()
def summary() -> None:
    """Counts of every lineage table and the latest runs."""
    from warehouse.store import Warehouse, WarehouseError

    try:
        with Warehouse(Settings().warehouse_path, read_only=True) as wh:
            counts = wh.counts()
            cols, rows = wh.query(
                "SELECT flow, status, count(*) AS runs, max(ended_at) AS last_ended FROM runs GROUP BY ALL ORDER BY flow")
            kcols, krows = wh.query("SELECT kind, count(*) AS n, sum(bytes) AS bytes FROM artifacts GROUP BY kind ORDER BY kind")
    except WarehouseError as exc:
        _fail(str(exc))
    _print_rows(["table", "rows"], list(counts.items()), "table", title=f"lineage {Settings().warehouse_path}")
    _print_rows(kcols, krows, "table", title="artifacts by kind")
    _print_rows(cols, rows, "table", title="runs")


# -- flows --------------------------------------------------------------------------------
@app.command()
def register(paths: list[Path]) -> None:
    """Validate manifests and record them in lineage (nothing is written if one is invalid)."""
    for path in paths:
        _load_or_exit(path)
    from flows.register import register as register_flow

    for path in paths:
        register_flow(str(path))


@app.command()
def simulate(manifest: Path, episodes: int = typer.Option(2, min=1, max=10_000, help="episodes (seeds seed..seed+N-1)")) -> None:
    """Simulate a manifest's task in MuJoCo and write episodes (Prefect flow `simulate`)."""
    _load_or_exit(manifest)
    from flows.simulate import simulate as simulate_flow

    result = simulate_flow(str(manifest), episodes)
    out.print(f"{result['new']} new episodes ({result['successes']} successes) under {result['manifest_hash'][:12]}",
              highlight=False)


@app.command()
def corpus(minutes: float = typer.Option(1.0, min=0.05, max=600, help="minutes of footage"),
           seed: int = typer.Option(0, min=0, help="same seed, same videos and truth"),
           width: int = typer.Option(640, min=32, max=3840), height: int = typer.Option(360, min=32, max=2160),
           fps: float = typer.Option(30.0, min=1, max=120)) -> None:
    """Generate a labelled raw-footage corpus with ground truth (Prefect flow `corpus`)."""
    from flows.corpus import corpus as corpus_flow

    result = corpus_flow(minutes=minutes, seed=seed, width=width, height=height, fps=fps)
    out.print(f"{len(result['videos'])} videos with ground truth under corpus/seed_{seed:06d}", highlight=False)


@app.command()
def demo() -> None:
    """Run the whole loop on built-in generated data, then print a lineage summary."""
    from flows.demo import demo as demo_flow

    demo_flow()
    summary()


@app.command()
def server(port: Optional[int] = typer.Option(None, help="API port on 127.0.0.1; a free one when omitted"),
           pool: str = typer.Option("worldline-local", help="process work pool the worker polls"),
           deploy: bool = typer.Option(True, "--deploy/--no-deploy", help="apply prefect.yaml (prefect deploy --all)")) -> None:
    """Start a local Prefect server (with UI) and a process worker on 127.0.0.1 until Ctrl-C."""
    from flows.server import StackError, serve

    try:
        serve(port=port, pool=pool, deploy=deploy)
    except StackError as exc:
        _fail(str(exc), 1)


def _not_built(step: str, issue: int) -> None:
    _fail(f"worldline {step}: not built yet (tracked in issue {issue})", EXIT_NOT_BUILT)


@app.command()
def curate(
    inputs: list[Path] = typer.Argument(..., help="video files or folders of videos"),
    manifest: Optional[Path] = typer.Option(None, help="scenario manifest the footage belongs to"),
    config: Optional[Path] = typer.Option(None, help="YAML overrides of CurateConfig"),
) -> None:
    """Curate raw videos into Parquet shards (Prefect flow `curate`); exit 1 if inputs were quarantined."""
    if manifest is not None:
        _load_or_exit(manifest)
    from flows.curate import curate as curate_flow

    result = curate_flow([str(p) for p in inputs], str(manifest) if manifest else None, str(config) if config else None)
    out.print(f"{result['status']}: {result['clips']} clips in {len(result['shards'])} shards, "
              f"{result['failed']} of {result['inputs']} inputs quarantined", highlight=False)
    if result["failed"]:
        raise typer.Exit(1)


def _video_or_exit(video: Path):
    from tasks.curate.decode import DecodeError, probe

    try:
        return probe(video)
    except DecodeError as exc:
        _fail(str(exc))


@app.command()
def scenes(video: Path, as_json: bool = typer.Option(False, "--json", help="print JSON"),
           config: Optional[Path] = typer.Option(None, help="YAML overrides of CurateConfig")) -> None:
    """Print the scenes the curate flow detects (start and end frame and time), with its own code."""
    from tasks.curate.config import load_config
    from tasks.curate.scenes import detect_scenes

    _video_or_exit(video)
    cfg = load_config(config)
    found = [s.summary() for s in detect_scenes(video, cfg.scenes, cfg.analysis, include_rejected=True)]
    if as_json:
        out.print_json(json.dumps({"video": str(video), "scenes": found}))
    else:
        _print_rows(list(found[0]) if found else ["kind"], [tuple(s.values()) for s in found], "table", str(video))


@app.command()
def inspect(video: Path, as_json: bool = typer.Option(False, "--json", help="print JSON"),
            config: Optional[Path] = typer.Option(None, help="YAML overrides of CurateConfig"),
            manifest: Optional[Path] = typer.Option(None, help="scenario manifest for captions")) -> None:
    """Each scene's scores, tags, caption and verdict, exactly as the curate flow decides them."""
    from schemas.hashing import sha256_file
    from tasks.curate.analyse import analyse_video
    from tasks.curate.config import load_config

    _video_or_exit(video)
    scenario = _load_or_exit(manifest) if manifest else None
    result = analyse_video(video, sha256_file(str(video)), load_config(config), scenario)
    rows = [{"clip_id": c.clip_id, "start_frame": c.start_frame, "end_frame": c.end_frame,
             "start_s": round(c.start_s, 3), "end_s": round(c.end_s, 3), "kept": c.kept,
             "stage": c.reject_stage, "reason": c.reject_reason, "tags": list(c.tags),
             "scores": {k: round(v, 4) for k, v in c.scores.items()}, "caption": c.caption} for c in result.clips]
    if as_json:
        out.print_json(json.dumps({"video": str(video), "clips": rows, "decode": result.decode}))
    else:
        cols = ["start_frame", "end_frame", "kept", "stage", "reason", "tags", "caption"]
        _print_rows(cols, [tuple(r[c] for c in cols) for r in rows], "table", str(video))


@app.command()
def tokenize(
    shards: str = typer.Argument(..., help="a folder of curated shards, or a manifest hash (12+ hex digits)"),
    preset: str = typer.Option("tiny-dv4x8x8", help="tokenizer preset (models/tokenizer.py PRESETS)"),
    steps: int = typer.Option(200, min=1, max=1_000_000, help="training steps"),
    size: int = typer.Option(64, min=8, max=1024, help="frames are centre-cropped and resized to size x size"),
) -> None:
    """Train a video tokenizer on curated shards and write token shards (Prefect flow `tokenize`)."""
    from models.tokenizer import PRESETS

    if preset not in PRESETS:
        _fail(f"--preset: unknown tokenizer preset {preset!r}; known: {', '.join(sorted(PRESETS))}")
    if size % PRESETS[preset].spatial_compression:
        _fail(f"--size: {size} is not a multiple of {preset}'s spatial compression {PRESETS[preset].spatial_compression}")
    from flows.tokenize import shard_files
    from flows.tokenize import tokenize as tokenize_flow

    try:
        shard_files(shards, Settings().data_root.resolve())
    except FileNotFoundError as exc:
        _fail(str(exc))
    result = tokenize_flow(shards, preset, steps, size)
    psnr = f", train PSNR {result['final_psnr']:.2f} dB" if result["final_psnr"] is not None else " (already trained)"
    out.print(f"checkpoint {result['checkpoint_id']}{psnr}; {len(result['token_shards'])} new token shards "
              f"from {result['clips']} clips", highlight=False)


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
def train() -> None:
    """Pre-train and post-train world models (not built yet)."""
    _not_built("train", 8)


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
def panels() -> None:
    """Generate matched scenario panels (not built yet)."""
    _not_built("panels", 9)


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
def evaluate() -> None:
    """Evaluate policies on panels (not built yet)."""
    _not_built("evaluate", 9)


def main() -> None:
    app()


if __name__ == "__main__":
    main()

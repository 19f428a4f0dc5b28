"""The `worldline` command: subcommands map to flows; each takes a manifest and a few overrides.

Exit codes (schemas/errors.py): 0 done, 1 partial (some inputs failed), 2 invalid input,
3 not built (run an earlier step first), 4 busy (another process writes to the data root),
5 environment (disk full, a damaged warehouse, a file changed behind lineage's back),
130 interrupted by Ctrl-C (SIGINT), 143 interrupted by SIGTERM.
"""

from __future__ import annotations

import csv
import errno
import json
import logging
import sys
from contextlib import ExitStack
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table
from typer.core import TyperGroup

import flows  # noqa: F401  (sets PREFECT_HOME before anything imports prefect)
from schemas.errors import EXIT_ENVIRONMENT, EXIT_INVALID, EXIT_PARTIAL, WorldlineError
from schemas.settings import Settings


class _Commands(TyperGroup):
    """Every command ends with one line and its exit code, never a traceback, for the errors a
    user can act on: a WorldlineError (raised anywhere, a flow included), a full disk, SIGTERM."""

    def invoke(self, ctx):
        from flows.ephemeral import exit_code

        try:
            with _held:
                return super().invoke(ctx)
        except BaseException as exc:
            code = exit_code(exc)  # after SIGINT or SIGTERM, whatever the interrupt surfaced as
            if code is None and isinstance(exc, WorldlineError):
                _say(str(exc))
                code = exc.exit_code
            elif code is None and isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
                _say(f"disk full: {exc.filename or exc.strerror}")
                code = EXIT_ENVIRONMENT
            if code is None:
                raise
            raise typer.Exit(code) from None


_held = ExitStack()  # what a command holds until it ends (_writing), released before its exit code is set
app = typer.Typer(cls=_Commands, add_completion=False, no_args_is_help=True, help=__doc__)
manifest_app = typer.Typer(no_args_is_help=True, help="Validate, hash and show scenario manifests.")
app.add_typer(manifest_app, name="manifest")
out = Console()
err = Console(stderr=True)


def _say(message: str) -> None:
    err.print(message, markup=False, highlight=False, soft_wrap=True)


def _fail(message: str, code: int = EXIT_INVALID) -> None:
    _say(message)
    raise typer.Exit(code)


def _refuse(exc: Exception) -> None:
    """``_fail`` with an error's message and its exit code (2 unless it is a WorldlineError)."""
    _fail(str(exc), exc.exit_code if isinstance(exc, WorldlineError) else EXIT_INVALID)


def _writing() -> None:
    """For the rest of this command: the data root's writer lock (taken now, before Prefect
    starts; exit 4 after WORLDLINE_LOCK_TIMEOUT seconds of waiting), the temporary Prefect server
    stopped on the way out, and Ctrl-C or SIGTERM ending the command within seconds
    (flows/ephemeral.py)."""
    from flows import ephemeral
    from warehouse import lock

    settings = Settings()
    _held.enter_context(ephemeral.interrupts_handled())
    _held.enter_context(lock.writer(settings.data_root, settings.lock_timeout, on_wait=lambda holder: _say(
        f"{settings.data_root}: another worldline process ({holder}) is writing; waiting up to "
        f"{settings.lock_timeout:g} s")))
    ephemeral.guard_prefect()
    _held.enter_context(ephemeral.servers_stopped_on_exit())


def _load_or_exit(path: Path):
    from tasks.manifests import ManifestError, load

    try:
        return load(path)
    except ManifestError as exc:
        _fail(str(exc))


def _simulable_or_exit(path: Path):
    """A manifest whose robot files are all there (checked before any flow simulates it)."""
    from tasks.sim.scene import check_assets

    manifest = _load_or_exit(path)
    try:
        check_assets(manifest)
    except FileNotFoundError as exc:
        _fail(f"{path}: {exc}")
    return manifest


def _checkpoint_or_exit(resolve):
    """``resolve(warehouse, data_root)`` with lineage open read-only (None before any flow has
    written it), or exit 2 with its one-line error: names are checked before a flow starts."""
    from tasks.checkpoint_files import CheckpointError
    from warehouse.store import Warehouse, WarehouseError

    settings = Settings()
    try:
        if not settings.warehouse_path.exists():
            return resolve(None, settings.data_root)
        with Warehouse(settings.warehouse_path, read_only=True) as warehouse:
            return resolve(warehouse, settings.data_root)
    except (FileNotFoundError, CheckpointError, WarehouseError) as exc:
        _refuse(exc)


def _world_model_or_exit(name: str | None) -> str:
    from tasks.lookup import world_model_folder

    return str(_checkpoint_or_exit(lambda warehouse, root: world_model_folder(warehouse, root, name)))


def _tokenizer_or_exit(name: str, variant: str | None = "discrete") -> str:
    """The folder of a tokenizer checkpoint named by folder or id, its config checked (the flow
    loads the weights)."""
    from tasks.lookup import checkpoint_folder
    from models.tokenizer import TokenizerConfig
    from tasks.checkpoint_files import CheckpointError, model_config, read_config
    from warehouse.queries import tokenizer_condition

    what = f"{variant} tokenizer" if variant else "tokenizer"
    folder = _checkpoint_or_exit(lambda warehouse, root: checkpoint_folder(
        warehouse, root, name, tokenizer_condition(variant), what))
    try:
        config = model_config(TokenizerConfig, read_config(folder, "tokenizer", "tokenizer checkpoint"), "tokenizer",
                              folder)
    except CheckpointError as exc:
        _fail(str(exc))
    if variant and config.variant != variant:
        _fail(f"{name}: a {config.variant} tokenizer; a {variant} one is needed here")
    return str(folder)


def _policies_or_exit(names: list[str], behaviour_cloning: bool = False) -> tuple[list[str], list]:
    """(names with ``bc:ID`` resolved to ``bc:FOLDER``, the policies they load)."""
    from tasks.lookup import policy_spec
    from tasks.policy.specs import PolicySpecError, load_policy

    specs = [_checkpoint_or_exit(lambda warehouse, root, name=name: policy_spec(warehouse, root, name))
             for name in names]
    loaded = []
    for spec in specs:
        if behaviour_cloning and not spec.startswith("bc:"):
            _fail(f"policy {spec!r}: the loop post-trains behaviour-cloning policies (bc:PATH or bc:ID)")
        try:
            loaded.append(load_policy(spec))
        except PolicySpecError as exc:
            _fail(str(exc))
    return specs, loaded


def _config_or_exit(path: Path | None):
    from tasks.curate.config import ConfigError, load_config

    try:
        return load_config(path)
    except ConfigError as exc:
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
    if fmt not in ("table", "csv", "json"):
        _fail(f"--format {fmt!r}: one of table, csv, json")
    try:
        sql, params = audits.bind(name, {"manifest": manifest, "artifact": artifact})
    except ValueError as exc:
        _fail(str(exc))
    try:
        with Warehouse(Settings().warehouse_path, read_only=True) as wh:
            ids = (("manifest", "manifests", "manifest_hash"), ("artifact", "artifacts", "artifact_id"))
            for key, table, column in ids:
                if key in params:
                    params[key] = _full_id(wh, table, column, params[key], key)
            cols, rows = wh.query(sql, params)
    except WarehouseError as exc:
        _refuse(exc)
    _print_rows(cols, rows, fmt, title=f"{name} ({len(rows)} rows)")


def _full_id(warehouse, table: str, column: str, given: str, what: str) -> str:
    """The one full id in ``table`` that starts with ``given`` (12+ hex digits), or ``given``
    itself when it is a full id, is not hex, or nothing starts with it (the audit then finds nothing)."""
    from tasks.lookup import is_hex_id
    from warehouse.queries import ids_starting

    if not is_hex_id(given) or len(given) >= 64:
        return given
    found = ids_starting(warehouse, table, column, given)
    if len(found) > 1:
        _fail(f"--{what} {given}: more than one {what} starts with it ({found[0]}, {found[1]}, ...)")
    return found[0] if found else given


@app.command()
def summary() -> None:
    """Counts of every lineage table and the latest runs."""
    from warehouse import queries
    from warehouse.store import Warehouse, WarehouseError

    try:
        with Warehouse(Settings().warehouse_path, read_only=True) as wh:
            counts = wh.counts()
            cols, rows = queries.runs_by_flow(wh)
            kcols, krows = queries.artifacts_by_kind(wh)
    except WarehouseError as exc:
        _refuse(exc)
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

    _writing()
    for path in paths:
        register_flow(str(path))


@app.command()
def simulate(manifest: Path, episodes: int = typer.Option(2, min=1, max=10_000, help="episodes (seeds seed..seed+N-1)")) -> None:
    """Simulate a manifest's task in MuJoCo and write episodes (Prefect flow `simulate`)."""
    _simulable_or_exit(manifest)
    from flows.simulate import simulate as simulate_flow

    _writing()
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

    _writing()
    result = corpus_flow(minutes=minutes, seed=seed, width=width, height=height, fps=fps)
    out.print(f"{len(result['videos'])} videos with ground truth under corpus/seed_{seed:06d}", highlight=False)


@app.command()
def demo() -> None:
    """Run the whole loop on built-in generated data, then print a lineage summary."""
    from flows.demo import demo as demo_flow

    _writing()
    result = demo_flow()
    summary()
    cols = ["cell", "episodes", "before", "after", "targeted"]
    _print_rows(cols, [tuple(r[c] for c in cols) for r in result["loop"]["table"]], "table",
                title="the loop: simulator success per stressor cell before and after post-training")
    # What lies behind a failed evaluation (the world-model one: through the world model's
    # checkpoints to its token shards, clips, raw videos and manifests).
    audit("failure", manifest=None, artifact=result["audit_evaluation"], fmt="table")


@app.command()
def server(port: Optional[int] = typer.Option(None, min=1, max=65535,
                                             help="API port on 127.0.0.1; a free one when omitted"),
           pool: str = typer.Option("worldline-local", help="process work pool the worker polls"),
           deploy: bool = typer.Option(True, "--deploy/--no-deploy", help="apply prefect.yaml (prefect deploy --all)")) -> None:
    """Start a local Prefect server (with UI) and a process worker on 127.0.0.1 until Ctrl-C."""
    from flows.server import StackError, serve

    try:
        serve(port=port, pool=pool, deploy=deploy)
    except StackError as exc:
        _fail(str(exc), EXIT_ENVIRONMENT)


@app.command()
def curate(
    inputs: list[Path] = typer.Argument(..., help="video files or folders of videos"),
    manifest: Optional[Path] = typer.Option(None, help="scenario manifest the footage belongs to"),
    config: Optional[Path] = typer.Option(None, help="YAML overrides of CurateConfig"),
) -> None:
    """Curate raw videos into Parquet shards (Prefect flow `curate`); exit 1 if inputs were quarantined."""
    if manifest is not None:
        _load_or_exit(manifest)
    _config_or_exit(config)
    from tasks.curate.config import VIDEO_SUFFIXES
    from tasks.curate.inputs import discover

    if not discover(inputs):
        _fail(f"{', '.join(map(str, inputs))}: no videos there ({' '.join(VIDEO_SUFFIXES)} in folders, or files given "
              "by name)")
    from flows.curate import curate as curate_flow

    _writing()
    result = curate_flow([str(p) for p in inputs], str(manifest) if manifest else None, str(config) if config else None)
    out.print(f"{result['status']}: {result['clips']} clips in {len(result['shards'])} shards, "
              f"{result['failed']} of {result['inputs']} inputs quarantined", highlight=False)
    if result["failed"]:
        raise typer.Exit(EXIT_PARTIAL)


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
    from tasks.curate.scenes import detect_scenes

    _video_or_exit(video)
    cfg = _config_or_exit(config)
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

    _video_or_exit(video)
    scenario = _load_or_exit(manifest) if manifest else None
    result = analyse_video(video, sha256_file(str(video)), _config_or_exit(config), scenario)
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
    crop: Optional[int] = typer.Option(None, min=8, max=1024, help="train on random crops of this side "
                                                                   "(default: whole frames)"),
    batch: int = typer.Option(4, min=1, max=256, help="clips per training step"),
    motion_weight: float = typer.Option(0.0, min=0.0, max=100.0, help="extra L1 weight on pixels that change "
                                                                      "between frames (up to 1 + this)"),
    focus_crops: int = typer.Option(1, min=1, max=64, help="candidate crops per window; the one that changes "
                                                           "most is trained on"),
    init: Optional[str] = typer.Option(None, help="continue from this tokenizer checkpoint (folder or id; "
                                                  "same preset)"),
) -> None:
    """Train a video tokenizer on curated shards and write token shards (Prefect flow `tokenize`)."""
    from models.tokenizer import PRESETS

    if preset not in PRESETS:
        _fail(f"--preset: unknown tokenizer preset {preset!r}; known: {', '.join(sorted(PRESETS))}")
    for name, side in (("--size", size), ("--crop", crop)):
        if side is not None and side % PRESETS[preset].spatial_compression:
            _fail(f"{name}: {side} is not a multiple of {preset}'s spatial compression "
                  f"{PRESETS[preset].spatial_compression}")
    if crop is not None and crop > size:
        _fail(f"--crop: {crop} is larger than --size {size}")
    if init:
        _tokenizer_or_exit(init, variant=None)
    from flows.tokenize import shard_files
    from flows.tokenize import tokenize as tokenize_flow

    try:
        shard_files(shards, Settings().data_root.resolve())
    except FileNotFoundError as exc:
        _fail(str(exc))
    _writing()
    try:
        result = tokenize_flow(shards, preset, steps, size, batch_size=batch, crop=crop, motion_weight=motion_weight,
                               focus_crops=focus_crops, init=init)
    except (FileNotFoundError, ValueError) as exc:
        _refuse(exc)
    psnr = f", train PSNR {result['final_psnr']:.2f} dB" if result["final_psnr"] is not None else " (already trained)"
    out.print(f"checkpoint {result['checkpoint_id']}{psnr}; {len(result['token_shards'])} new token shards "
              f"from {result['clips']} clips", highlight=False)


@app.command()
def train(
    manifest: str = typer.Argument(..., help="manifest YAML whose simulated episodes post-train the model "
                                             "(or an episode folder, or a manifest hash)"),
    tokenizer: Optional[str] = typer.Option(None, help="tokenizer checkpoint folder or id; default the newest "
                                                       "discrete one with token shards"),
    tokens: Optional[str] = typer.Option(None, help="token shard folder; default the tokenizer's token shards"),
    preset: str = typer.Option("tiny-wm", help="world model preset (models/world_model.py PRESETS)"),
    steps: int = typer.Option(200, min=1, max=1_000_000, help="pre-training steps"),
    post_steps: int = typer.Option(100, min=1, max=1_000_000, help="post-training steps"),
    camera: Optional[str] = typer.Option(None, help="post-train on this camera only (default: every camera)"),
    window: Optional[int] = typer.Option(None, min=2, max=64, help="latent frames per training window "
                                                                   "(default: the preset's max_frames)"),
    patch: Optional[int] = typer.Option(None, min=1, max=16, help="codes per token side (default: the smallest "
                                                                  "that keeps a latent frame at 64 tokens or fewer)"),
    batch: int = typer.Option(8, min=1, max=256, help="windows per training step"),
    change_weight: float = typer.Option(0.0, min=0.0, max=100.0, help="extra loss weight on codes that change "
                                                                      "from one latent frame to the next"),
    self_condition: float = typer.Option(0.0, min=0.0, max=1.0, help="share of post-training windows whose input "
                                         "frames after the first are the model's own rollout (open-loop robustness)"),
    action_totals: int = typer.Option(0, min=0, max=8, help="post-training: the first N action values also enter as "
                                      "running totals since the episode's start (3 for ee_delta actions: the "
                                      "commanded hand's offset, which a few-frame window cannot add up)"),
    also: Optional[list[str]] = typer.Option(None, "--also", help="another manifest (YAML, episode folder or hash) "
                                             "whose episodes join post-training; repeatable"),
) -> None:
    """Pre-train a world model on token shards, post-train it with actions on episodes (Prefect flow `train`)."""
    from models.world_model import PRESETS

    if preset not in PRESETS:
        _fail(f"--preset: unknown world model preset {preset!r}; known: {', '.join(sorted(PRESETS))}")
    if Path(manifest).suffix in (".yaml", ".yml"):
        _load_or_exit(Path(manifest))
    if tokenizer:
        _tokenizer_or_exit(tokenizer)
    from flows.train import episode_folders
    from flows.train import train as train_flow
    from tasks.world.data import read_meta

    for extra in also or []:
        if Path(extra).suffix in (".yaml", ".yml"):
            _load_or_exit(Path(extra))
    try:
        folders, _ = episode_folders(manifest, Settings().data_root.resolve())
        for extra in also or []:
            episode_folders(extra, Settings().data_root.resolve())
    except FileNotFoundError as exc:
        _refuse(exc)
    cameras = read_meta(folders[0]).get("cameras", [])
    if camera is not None and camera not in cameras:
        _fail(f"--camera {camera!r}: the episodes of {manifest} have cameras {', '.join(cameras)}")
    if action_totals:
        from tasks.world.data import read_steps

        width, room = read_steps(folders[0])[1].shape[1], PRESETS[preset].action_dim
        if action_totals > width or width + action_totals > room:
            _fail(f"--action-totals {action_totals}: the episodes of {manifest} have {width} action values a step "
                  f"and preset {preset} takes {room} values in all")
    _writing()
    try:
        result = train_flow(manifest, tokenizer, tokens, preset, steps, post_steps, batch_size=batch, window=window,
                            camera=camera, patch=patch, change_weight=change_weight,
                            self_condition=self_condition, action_totals=action_totals, also=also)
    except (FileNotFoundError, ValueError) as exc:
        _refuse(exc)
    done = {True: "trained", False: "already trained"}
    out.print(f"pre-trained {result['pretrain_checkpoint_id']} ({done[result['pretrained']]}), post-trained "
              f"{result['posttrain_checkpoint_id']} ({done[result['posttrained']]}) on {result['episodes']} episodes",
              highlight=False)


@app.command()
def panels(
    manifest: Path,
    grid: Optional[Path] = typer.Option(None, help="stressor grid YAML (schemas/panel.py StressorGrid); "
                                                   "default: nominal, clean, then one stressor at a time"),
    episodes: Optional[int] = typer.Option(None, min=1, max=1000, help="seeds per cell (default: the grid's)"),
    world_model: Optional[str] = typer.Option(None, help="post-trained world-model checkpoint folder or id, "
                                                        "for side-by-side rollouts"),
    camera: Optional[str] = typer.Option(None, help="camera shown (default: the first world-mounted one)"),
    guard: bool = typer.Option(True, "--guard/--no-guard", help="text pre-guard and face post-guard"),
) -> None:
    """A matched panel: variants differing only in stressors, simulated, contact sheet + MP4 (Prefect flow `panels`)."""
    parent = _simulable_or_exit(manifest)
    _grid_or_exit(parent, grid, episodes)
    folder = _world_model_or_exit(world_model) if world_model else None
    from flows.panels import panels as panels_flow
    from flows.panels import primary_camera

    try:
        primary_camera(parent, camera)
    except ValueError as exc:
        _fail(f"--camera: {exc}")

    _writing()
    try:
        result = panels_flow(str(manifest), str(grid) if grid else None, episodes, folder, camera, guard)
    except ValueError as exc:
        _fail(str(exc))
    cells = ", ".join(f"{v['cell']} {sum(e['success'] for e in v['episodes'])}/{len(v['episodes'])}"
                      for v in result["variants"])
    out.print(f"panel {result['panel_id']}: {cells}; sheet {result['contact_sheet']}, video {result['video']}",
              highlight=False)


def _grid_or_exit(parent, grid: Optional[Path], episodes: Optional[int]):
    from tasks.panels.grid import GridError, expand
    from flows.panels import resolve_grid

    try:
        return expand(parent, resolve_grid(parent, str(grid) if grid else None, episodes))
    except GridError as exc:
        _fail(str(exc))


def evaluate_policies_cmd(
    manifest: Path,
    policy: Optional[list[str]] = typer.Option(None, help="scripted | scripted:NOISE | bc:CHECKPOINT_FOLDER | "
                                                           "bc:CHECKPOINT_ID (repeat; default: scripted and "
                                                           "scripted:0.8)"),
    grid: Optional[Path] = typer.Option(None, help="stressor grid YAML (default: one stressor at a time)"),
    episodes: Optional[int] = typer.Option(None, min=1, max=1000, help="seeds per cell (default: the grid's)"),
    compare: Optional[list[Path]] = typer.Option(None, help="another manifest whose panel is evaluated too "
                                                            "(its contract must match; repeat)"),
    world_model: Optional[str] = typer.Option(None, help="post-trained world-model checkpoint folder or id: "
                                                        "verdicts on generated frames"),
    detector: bool = typer.Option(True, "--detector/--no-detector", help="also judge the simulator's renders "
                                                                         "with the frame detector"),
) -> None:
    """Policies on a panel: simulator and frame-detector success per stressor cell, their rank
    correlation (Prefect flow `evaluate`); exit 2 when panel contracts differ."""
    parent = _simulable_or_exit(manifest)
    for other in compare or []:
        _simulable_or_exit(other)
    _grid_or_exit(parent, grid, episodes)
    from tasks.panels.contract import PanelContractError

    from flows.evaluate import DEFAULT_POLICIES, agreement_line, plan
    from flows.evaluate import evaluate as evaluate_flow

    specs, loaded = _policies_or_exit(policy or [])
    folder = _world_model_or_exit(world_model) if world_model else None
    try:  # the flow plans again; refusing here spares starting Prefect for nothing
        plan([str(manifest), *map(str, compare or [])], str(grid) if grid else None, episodes,
             loaded or _policies_or_exit(list(DEFAULT_POLICIES))[1])
    except PanelContractError as exc:
        _fail(str(exc))

    _writing()
    try:
        result = evaluate_flow(str(manifest), str(grid) if grid else None, episodes, specs or None,
                               [str(p) for p in compare or []], folder, detector)
    except PanelContractError as exc:
        _fail(str(exc))
    rows = [(e["panel"], e["policy"], r["cell"], r["episodes"], *("-" if r[k] is None else f"{r[k]:.2f}"
                                                                  for k in ("sim", "detector", "world")))
            for e in result["evaluations"] for r in e["table"]]
    _print_rows(["panel", "policy", "cell", "episodes", "simulator", "detector on sim", "world model"], rows, "table",
                title="success rate per stressor cell")
    out.print("Spearman (simulator vs): " + ", ".join(f"{k} {'-' if v is None else f'{v:.2f}'}"
                                                       for k, v in result["spearman"].items()), highlight=False)
    for column, a in result["agreement"].items():
        out.print(agreement_line(f"{column} vs simulator, per episode", a), highlight=False)


@app.command("train-policy")
def train_policy_cmd(
    manifest: Path,
    episodes: int = typer.Option(30, min=1, max=10_000, help="scripted demonstrations (seeds seed+1000...)"),
    steps: int = typer.Option(3000, min=1, max=1_000_000, help="training steps"),
    preset: str = typer.Option("tiny", help="policy network preset (models/bc_policy.py PRESETS)"),
    holdout: int = typer.Option(10, min=0, max=10_000, help="held-out seeds to measure success on (seed+2000...)"),
) -> None:
    """Behaviour-clone the scripted controller into a small MLP policy (Prefect flow `train-policy`)."""
    from models.bc_policy import PRESETS

    scenario = _simulable_or_exit(manifest)
    if preset not in PRESETS:
        _fail(f"--preset: unknown policy preset {preset!r}; known: {', '.join(sorted(PRESETS))}")
    if scenario.embodiment.kind != "arm":
        _fail(f"{manifest}: behaviour cloning drives arms; this manifest's embodiment is {scenario.embodiment.kind!r}")
    from flows.policy import train_policy as train_flow

    _writing()
    result = train_flow(str(manifest), episodes, steps, preset, 0, holdout)
    rate = result["held_out_success_rate"]
    out.print(f"checkpoint {result['folder']}" + ("" if rate is None else f"; held-out success {rate:.2f}"),
              highlight=False)


evaluate_app = typer.Typer(no_args_is_help=True, help="Evaluate world models against the simulator, and policies.")
app.add_typer(evaluate_app, name="evaluate")


@evaluate_app.command("physics")
def evaluate_physics_cmd(
    manifest: Path,
    world_model: Optional[str] = typer.Option(None, help="post-trained world-model checkpoint folder or id "
                                                         "(default: the newest post-trained one in lineage)"),
    tokenizer: Optional[str] = typer.Option(None, help="its tokenizer's checkpoint folder or id (default: the one "
                                                       "it was trained with)"),
    episodes: int = typer.Option(10, min=1, max=1000, help="held-out episodes"),
    first_seed: int = typer.Option(10_000, min=0, help="seeds first_seed.. (never those the model trained on)"),
    camera: Optional[str] = typer.Option(None, help="world-mounted camera (default: the first)"),
    horizon: int = typer.Option(4, min=1, max=64, help="latent frames predicted per window"),
) -> None:
    """A world model against MuJoCo on held-out seeds: per-horizon PSNR, SSIM, package position
    error and IoU beside copy-last-frame and the tokenizer's reconstruction, true against
    shuffled actions (Prefect flow `evaluate-physics`)."""
    _simulable_or_exit(manifest)
    folder = _world_model_or_exit(world_model)
    tokenizer_folder = _tokenizer_or_exit(tokenizer) if tokenizer else None
    from flows.physics import evaluate_physics

    _writing()
    try:
        result = evaluate_physics(str(manifest), folder, tokenizer_folder, episodes,
                                  first_seed, camera, horizon)
    except (FileNotFoundError, ValueError) as exc:
        _refuse(exc)
    checks = ", ".join(f"{k} {'passed' if v else 'failed'}" for k, v in result["checks"].items())
    out.print(f"evaluation {result['evaluation_id']} ({result['windows']} windows, {result['moving']} with the "
              f"package moving): {checks}; table and plots under {result['folder']}", highlight=False)

@app.command("loop")
def loop_cmd(
    manifest: Path,
    policy: Optional[str] = typer.Option(None, help="bc:CHECKPOINT_FOLDER or bc:CHECKPOINT_ID (default: a weak "
                                                    "policy trained in-flow)"),
    grid: Optional[Path] = typer.Option(None, help="stressor grid YAML (default: one stressor at a time)"),
    episodes: Optional[int] = typer.Option(None, min=1, max=1000, help="seeds per cell (default: the grid's)"),
    worst: int = typer.Option(1, min=1, max=8, help="how many of the lowest-success cells to derive manifests from"),
    new_episodes: int = typer.Option(12, min=1, max=10_000, help="new episodes in all, weighted by failure rate"),
    post_steps: int = typer.Option(2000, min=1, max=1_000_000, help="post-training steps"),
) -> None:
    """Failures back into data: the worst stressor cells become derived manifests, simulated,
    curated and post-trained on; success per cell before and after (Prefect flow `loop`)."""
    parent = _simulable_or_exit(manifest)
    if parent.embodiment.kind != "arm":
        _fail(f"{manifest}: the loop post-trains behaviour cloning, which drives arms; "
              f"this manifest's embodiment is {parent.embodiment.kind!r}")
    _grid_or_exit(parent, grid, episodes)
    if policy is not None:
        policy = _policies_or_exit([policy], behaviour_cloning=True)[0][0]
    from flows.loop import loop as loop_flow

    _writing()
    result = loop_flow(str(manifest), policy, str(grid) if grid else None, episodes, worst, new_episodes, post_steps)
    fmt = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
    _print_rows(["cell", "episodes", "before", "after", "targeted"],
                [(r["cell"], r["episodes"], fmt(r["before"]), fmt(r["after"]), "yes" if r["targeted"] else "")
                 for r in result["table"]], "table", title="success rate per stressor cell, before and after")
    out.print(f"checkpoint {result['checkpoint']}", highlight=False)


# `worldline evaluate policies` (flows/evaluate.py), defined above with the panels.
evaluate_app.command("policies")(evaluate_policies_cmd)


@app.command()
def verify(
    manifest: Optional[str] = typer.Option(None, help="only this manifest's artifacts (hash, or its first 12+ hex digits)"),
    fmt: str = typer.Option("table", "--format", help="table | csv | json"),
) -> None:
    """Check every file lineage recorded (or one manifest's) against its sha256: list the
    missing, the changed, and paths two rows claim with different sha256s; exit 5 when any
    differ. Reads the warehouse only (tasks/integrity.py `audit`: manifests are not files)."""
    from schemas.errors import EXIT_ENVIRONMENT
    from tasks import integrity
    from warehouse import integrity as claims
    from warehouse.queries import has_manifest
    from warehouse.store import Warehouse, WarehouseError

    if fmt not in ("table", "csv", "json"):
        _fail(f"--format {fmt!r}: one of table, csv, json")
    settings = Settings()
    try:
        with Warehouse(settings.warehouse_path, read_only=True) as wh:
            if manifest is not None:
                manifest = _full_id(wh, "manifests", "manifest_hash", manifest, "manifest")
                if not has_manifest(wh, manifest):
                    _fail(f"--manifest {manifest}: no such manifest in lineage")
            rows = [integrity.Recorded(*r) for r in claims.files(wh, manifest)]
    except WarehouseError as exc:
        _refuse(exc)
    findings, checked, hashed = integrity.audit(rows, settings.data_root)
    short = (lambda v: v and v[:12]) if fmt == "table" else (lambda v: v)  # noqa: E731
    _print_rows(["problem", "kind", "artifact_id", "uri", "lineage_sha256", "file_sha256"],
                [(f.problem, f.kind, short(f.artifact_id), f.uri, short(f.lineage_sha256), short(f.file_sha256))
                 for f in findings], fmt, title=f"files that differ from lineage ({len(findings)})")
    counts = ", ".join(f"{sum(f.problem == p for f in findings)} {p}" for p in integrity.PROBLEMS)
    line = (f"{checked} artifacts checked, {hashed} files hashed: "
            + (f"{len(findings)} differ from lineage ({counts})" if findings else "all match lineage"))
    (out if fmt == "table" else err).print(line, highlight=False, markup=False, soft_wrap=True)  # csv, json parseable
    if findings:
        raise typer.Exit(EXIT_ENVIRONMENT)


class _InputErrorsInOneLine(logging.Filter):
    """Prefect logs a failed flow or task run's exception with its traceback; from the CLI an
    input error (FileNotFoundError, ValueError: a missing file, a refused manifest or contract),
    a WorldlineError or an interrupt is then stated in one line, as the CLI states it again on
    exit. Other errors keep their traceback, and so does every run a worker executes."""

    def filter(self, record: logging.LogRecord) -> bool:
        from flows.ephemeral import signal_name

        exc = record.exc_info[1] if record.exc_info else None
        if exc is not None and (isinstance(exc, (FileNotFoundError, ValueError, WorldlineError))
                                or signal_name(exc)):
            record.exc_info = record.exc_text = None
        return True


def main() -> None:
    for name in ("prefect.flow_runs", "prefect.task_runs"):
        logging.getLogger(name).addFilter(_InputErrorsInOneLine())
    app()


if __name__ == "__main__":
    main()

"""`worldline register`, `simulate`, `corpus`, `curate`, `scenes`, `inspect`, `demo` and
`server`: data in, and the stack."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import typer

from flows import cli_checks as need
from flows.cli_command import command
from flows.cli_shell import FORMAT, app, check_format, fail, out, print_rows, writing
from flows.params_data import CorpusParams, CurateParams, SimulateParams
from schemas.errors import EXIT_ENVIRONMENT, EXIT_PARTIAL, WorldlineError
from schemas.paths import output_folders
from schemas.settings import Settings

JSON = typer.Option(False, "--json", hidden=True, help="the same as --format json")
CONFIG = typer.Option(None, help="YAML overrides of CurateConfig")


@app.command()
def register(paths: list[Path]) -> None:
    """Validate manifests and record them in lineage (nothing is written if one is invalid)."""
    for path in paths:
        need.manifest(path)
    from flows.register import register as register_flow

    writing()
    for path in paths:
        out.print(f"registered {path}: {register_flow(str(path))}", highlight=False)


@command(app, SimulateParams)
def simulate(params: SimulateParams) -> None:
    """Simulate a manifest's task in MuJoCo and write episodes (Prefect flow `simulate`)."""
    scenario = need.simulable(params.manifest)
    from flows.params import ParamsError
    from flows.simulate import drive_with, simulate as simulate_flow

    if params.policy:
        params = params.model_copy(update={"policy": need.policies([params.policy])[0][0]})
        try:
            drive_with(params.policy, scenario)  # a vision policy's cameras against the manifest's
        except ParamsError as exc:
            fail(str(exc))

    writing()
    result = simulate_flow(**params.model_dump())
    where = result["folder"] if params.policy else result["manifest_hash"][:12]
    out.print(f"{result['new']} new episodes ({result['successes']} successes) under {where}", highlight=False)


@command(app, CorpusParams)
def corpus(params: CorpusParams) -> None:
    """Generate a labelled raw-footage corpus with ground truth (Prefect flow `corpus`)."""
    from flows.corpus import corpus as corpus_flow

    writing()
    result = corpus_flow(**params.model_dump())
    out.print(f"{len(result['videos'])} videos with ground truth under corpus/seed_{params.seed:06d}", highlight=False)


@app.command()
def demo() -> None:
    """Run the whole loop on built-in generated data, then print a lineage summary."""
    from flows.cli_lineage import audit, summary
    from flows.demo import demo as demo_flow

    writing()
    result = demo_flow()
    summary("table")
    rate = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
    print_rows(["cell", "episodes", "before", "targeted", "untargeted", "new data"],
               [(r["cell"], r["episodes"], rate(r["before"]), rate(r["after"]), rate(r.get("untargeted")),
                 "yes" if r["targeted"] else "") for r in result["loop"]["table"]], "table",
               title="the loop for a vision policy: success per stressor cell before, and after post-training on "
                     "new episodes of its worst cells (targeted) or as many of the manifest as it is (untargeted)")
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
        fail(str(exc), EXIT_ENVIRONMENT)


@command(app, CurateParams)
def curate(params: CurateParams) -> None:
    """Curate raw videos into Parquet shards (Prefect flow `curate`); exit 1 if inputs were quarantined."""
    if params.manifest is not None:
        need.manifest(params.manifest)
    need.curate_config(params.config)
    from tasks.curate.config import VIDEO_SUFFIXES
    from tasks.curate.inputs import find

    if not find([Path(p) for p in params.inputs], output_folders(Settings().data_root)):  # paths only, not hashed
        fail(f"{', '.join(params.inputs)}: no videos there ({' '.join(VIDEO_SUFFIXES)} in folders, or files given "
             "by name)")
    from flows.curate import curate as curate_flow

    writing()
    result = curate_flow(**params.model_dump())
    out.print(f"{result['status']}: {result['clips']} clips in {len(result['shards'])} shards, "
              f"{result['failed']} of {result['inputs']} inputs quarantined", highlight=False)
    if result["failed"]:
        raise typer.Exit(EXIT_PARTIAL)


@app.command()
def scenes(video: Path, fmt: str = FORMAT, as_json: bool = JSON, config: Optional[Path] = CONFIG) -> None:
    """Print the scenes the curate flow detects (start and end frame and time), with its own code."""
    from tasks.curate.scenes import detect_scenes

    check_format(fmt := "json" if as_json else fmt)
    need.video(video)
    cfg = need.curate_config(config)
    found = [s.summary() for s in detect_scenes(video, cfg.scenes, cfg.analysis, include_rejected=True)]
    if fmt == "json":
        sys.stdout.write(json.dumps({"video": str(video), "scenes": found}, indent=2) + "\n")
    else:
        print_rows(list(found[0]) if found else ["kind"], [tuple(s.values()) for s in found], fmt, str(video))


@app.command()
def inspect(video: Path, fmt: str = FORMAT, as_json: bool = JSON, config: Optional[Path] = CONFIG,
            manifest: Optional[Path] = typer.Option(None, help="scenario manifest for captions")) -> None:
    """Each scene's scores, tags, caption and verdict, exactly as the curate flow decides them
    (csv: tags and scores as JSON text; json: the decode report too)."""
    from schemas.hashing import sha256_file
    from tasks.curate.analyse import analyse_video
    from tasks.curate.decode import DecodeError

    check_format(fmt := "json" if as_json else fmt)
    need.video(video)
    scenario = need.manifest(manifest) if manifest else None
    cfg = need.curate_config(config)
    try:
        result = analyse_video(video, sha256_file(str(video)), cfg, scenario)
    except WorldlineError:
        raise  # its own line and exit code (Commands)
    except DecodeError as exc:  # names the file already
        fail(str(exc))
    except ValueError as exc:  # a video the filters cannot judge (frames under 16x16 px): curate quarantines it
        fail(f"{video}: {exc}")
    rows = [{"clip_id": c.clip_id, "start_frame": c.start_frame, "end_frame": c.end_frame,
             "start_s": round(c.start_s, 3), "end_s": round(c.end_s, 3), "kept": c.kept,
             "stage": c.reject_stage, "reason": c.reject_reason, "tags": list(c.tags),
             "scores": {k: round(v, 4) for k, v in c.scores.items()}, "caption": c.caption} for c in result.clips]
    if fmt == "json":
        sys.stdout.write(json.dumps({"video": str(video), "clips": rows, "decode": result.decode}, indent=2) + "\n")
    elif fmt == "csv":
        cols = list(rows[0]) if rows else ["clip_id"]
        print_rows(cols, [tuple(json.dumps(v) if isinstance(v, (list, dict)) else v for v in r.values()) for r in rows],
                   "csv")
    else:
        cols = ["start_frame", "end_frame", "kept", "stage", "reason", "tags", "caption"]
        print_rows(cols, [tuple(r[c] for c in cols) for r in rows], "table", str(video))

"""controls: edge and blur controls (tasks/controls/video.py) of a video, an episode's camera
videos or a folder of videos, each recorded with a `control_of` edge from its video."""

from __future__ import annotations

from pathlib import Path

from prefect import flow, task

from flows.params_data import ControlsParams
from flows.recording import recorded_run
from flows.report import publish
from schemas import paths
from schemas.hashing import sha256_file, stable_id
from schemas.settings import Settings
from tasks.controls import files, sources
from tasks.controls.video import CONTROLS_VERSION, VIDEO_CONTROLS, write_video_controls
from tasks.lookup import recorded_files, verified_file
from tasks.video import DecodeError

make_controls = task(write_video_controls, name="video-controls", retries=1)


@flow(name="controls", log_prints=True)
def controls(source: str, out: str | None = None) -> dict:
    """Edges and blur of every video ``source`` names, written beside it (or under ``out``);
    a video whose controls are there from an earlier run is skipped."""
    ControlsParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    problems: list[str] = []  # a folder's videos that are not readable: named, and the rest go on
    found = sources.find_sources(Path(source), Path(out) if out else None, problems)
    written, new, already = [], 0, 0
    with recorded_run("controls", settings, params={"source": source, "out": out}) as run:
        for problem in problems:
            run.fail_input(problem)
        for item in found:
            sha = sha256_file(str(item.video))
            outputs = [paths.control_file(item.folder, item.name, c) for c in VIDEO_CONTROLS]
            key = stable_id("controls", sha, str(CONTROLS_VERSION), *map(str, outputs))
            stage = run.stage("controls", key, outputs=outputs, manifest_hash=item.manifest_hash)
            if stage.done:  # its files must still be the ones lineage recorded (else exit 5)
                for output in outputs:
                    verified_file(run.warehouse, settings.data_root, output, "control", "control")
                already += 1
                continue
            taken = [p for p in outputs if p.exists()]  # a file there lineage does not hold is the user's
            if theirs := sorted(set(taken) - recorded_files(run.warehouse, settings.data_root, taken)):
                run.fail_input(f"{theirs[0]}: a file lineage did not record is there; move it aside (not overwritten)")
                continue
            try:
                made = make_controls(item.video, item.folder, item.name)
            except (DecodeError, ValueError) as exc:  # probed, but it breaks off while decoding
                run.fail_input(f"{item.video}: {exc}")
                continue
            stage.finish(1, len(made), files.source_lineage(item, sha, made, stage.id, settings.data_root),
                         attrs={"video": paths.escaped(str(item.video))})
            written.extend(made.values())
            new += 1
        summary = (f"{len(found)} videos: {new} given edge and blur controls, "
                   f"{already} had them already"
                   + (f"; {len(run.failures)} not readable, left out" if run.failures else ""))
        publish("controls", summary, "\n".join(f"- `{paths.escaped(str(p))}`" for p in written),
                "edge and blur controls written")
        print(summary)
        return {"videos": len(found), "new": new, "written": [str(p) for p in written], "failed": list(run.failures)}

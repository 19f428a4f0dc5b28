"""simulate: a scenario manifest -> N MuJoCo episodes (videos per camera, steps, metadata)."""

from __future__ import annotations

from contextlib import suppress
from pathlib import Path

from prefect import flow, task
from prefect.futures import as_completed

from flows.params import Episodes
from flows.params_data import SimulateParams
from flows.recording import recorded_run
from flows.report import markdown_table, progress, publish
from flows.runners import task_runner
from schemas.hashing import stable_id
from schemas.settings import Settings
from tasks import manifests
from tasks.controls import files as control_files
from tasks.controls.render import Recorder
from tasks.sim import episode, files

load_manifest = task(manifests.load, name="load-manifest")


@task(name="simulate-episode", retries=1)
def simulate_episode(manifest, manifest_hash: str, index: int, root: Path, controls: bool = False):
    """Roll out one seed and write its files; returns the files, the episode outcome and the
    control files per camera ({} without controls)."""
    if not controls:
        result = episode.rollout(manifest, manifest.seed + index)
        return files.write_episode(result, root, manifest_hash, index), result.success, result.reason, {}
    recorder = Recorder()
    result = episode.rollout(manifest, manifest.seed + index, on_frame=recorder)
    written = files.write_episode(result, root, manifest_hash, index)
    made = control_files.write_rendered(recorder.rendered(), written.directory,
                                        {c.name: c.fps for c in manifest.cameras})
    return written, result.success, result.reason, made


@flow(name="simulate", log_prints=True, task_runner=task_runner())
def simulate(manifest: str, episodes: Episodes = 2, controls: bool = False) -> dict:
    """Episodes 0..N-1 of a manifest use seeds seed..seed+N-1; finished episodes are skipped.
    controls: also depth and segmentation per camera (an episode without them is done again)."""
    SimulateParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    scenario = load_manifest(Path(manifest))
    with recorded_run("simulate", settings, scenario, source_uri=manifest,
                      params={"manifest": manifest, "episodes": episodes, **({"controls": True} if controls else {})}
                      ) as run:
        # With controls a stage has another key: episodes simulated without them are done again
        # (the same seed renders the same videos) and get them; without, keys are as they were.
        keys = {stable_id("episode", run.manifest_hash, str(i), *(["controls"] if controls else [])): i
                for i in range(episodes)}
        by_future = {simulate_episode.submit(scenario, run.manifest_hash, keys[key], settings.data_root, controls): stage
                     for key, stage in run.stages("simulate", keys).items() if not stage.done}
        outcomes = {}

        def record(future) -> None:
            """One finished episode's lineage, written as soon as it is done: an interrupted run
            keeps every episode it finished (issue 26)."""
            stage = by_future.pop(future)
            written, success, reason, made = future.result()
            batch = files.episode_lineage(written, run.manifest_hash, stage.id, settings.data_root)
            batch.extend(control_files.episode_controls_lineage(batch, made, run.manifest_hash, stage.id,
                                                                settings.data_root))
            stage.finish(1, 1, batch, attrs={"index": keys[stage.key], "success": success, "reason": reason})
            outcomes[keys[stage.key]] = (success, reason)

        with progress(len(by_future), f"simulate {scenario.name}") as bar:
            try:
                for future in as_completed(list(by_future)):
                    record(future)
                    bar.advance()
            except BaseException:  # an interrupt, or a failed episode: start no more, keep those finished
                for future in by_future:
                    future.wrapped_future.cancel()
                for future in [f for f in by_future if f.wrapped_future.done() and not f.wrapped_future.cancelled()]:
                    with suppress(Exception):
                        record(future)
                raise
        done = sorted(outcomes.items())
        publish("simulate", f"{scenario.name}: {len(done)} new episodes, {episodes - len(done)} already done",
                markdown_table(("episode", "seed", "outcome", "reason"),
                               [(i, scenario.seed + i, "success" if ok else "failure", why) for i, (ok, why) in done]),
                "episodes rolled out and their outcome")
        print(f"{scenario.name}: {len(done)} new episodes, {episodes - len(done)} already done; "
              + ", ".join(f"#{i} {'success' if ok else 'failure'} ({why})" for i, (ok, why) in done))
        return {"manifest_hash": run.manifest_hash, "new": len(done),
                "successes": sum(ok for ok, _ in outcomes.values())}

"""simulate: a scenario manifest -> N MuJoCo episodes (videos per camera, steps, metadata)."""

from __future__ import annotations

from contextlib import suppress
from pathlib import Path

from prefect import flow, task
from prefect.cache_policies import NO_CACHE
from prefect.futures import as_completed

from flows.params import Episodes, ParamsError
from flows.params_data import SimulateParams
from flows.recording import recorded_run
from flows.report import markdown_table, progress, publish
from flows.runners import task_runner
from schemas import paths
from schemas.hashing import stable_id
from schemas.records import EdgeRecord
from schemas.settings import Settings
from tasks import manifests
from tasks.controls import files as control_files
from tasks.controls.render import Recorder
from tasks.lookup import verified_policy
from tasks.policy.base import Policy
from tasks.policy.results import checkpoint_record
from tasks.policy.specs import PolicySpecError, load_policy
from tasks.policy.vision import VisionPolicy
from tasks.sim import episode, files

load_manifest = task(manifests.load, name="load-manifest")


# Inputs may hold a policy (a network): nothing to gain from hashing them for a cache key.
@task(name="simulate-episode", retries=1, cache_policy=NO_CACHE)
def simulate_episode(manifest, manifest_hash: str, index: int, root: Path, controls: bool = False,
                     policy: Policy | None = None):
    """Roll out one seed (driven by ``policy``, else the manifest's scripted controller) and
    write its files; returns the files, the episode outcome and the control files per camera
    ({} without controls)."""
    drive = {} if policy is None else {"controller": policy.controller}
    described = None if policy is None else policy.describe()
    if not controls:
        result = episode.rollout(manifest, manifest.seed + index, **drive)
        return (files.write_episode(result, root, manifest_hash, index, policy=described), result.success,
                result.reason, {})
    recorder = Recorder()
    result = episode.rollout(manifest, manifest.seed + index, on_frame=recorder, **drive)
    written = files.write_episode(result, root, manifest_hash, index, policy=described)
    made = control_files.write_rendered(recorder.rendered(), written.directory,
                                        {c.name: c.fps for c in manifest.cameras})
    return written, result.success, result.reason, made


@flow(name="simulate", log_prints=True, task_runner=task_runner())
def simulate(manifest: str, episodes: Episodes = 2, controls: bool = False, policy: str | None = None) -> dict:
    """Episodes 0..N-1 of a manifest use seeds seed..seed+N-1; finished episodes are skipped.
    controls: also depth and segmentation per camera (an episode without them is done again).
    policy: drive the robot with it (scripted:NOISE, bc:PATH, vision:PATH); its episodes go in
    a folder of their own (POLICY_EPISODES), with an edge from its checkpoint."""
    SimulateParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    scenario = load_manifest(Path(manifest))
    driver = drive_with(policy, scenario)
    extra = {**({"controls": True} if controls else {}), **({"policy": driver.describe()} if driver else {})}
    with recorded_run("simulate", settings, scenario, source_uri=manifest,
                      params={"manifest": manifest, "episodes": episodes, **extra}) as run:
        # With controls a stage has another key: episodes simulated without them are done again
        # (the same seed renders the same videos) and get them; without, keys are as they were.
        tags = [*(["controls"] if controls else []), *([files.policy_id(extra["policy"])] if driver else [])]
        keys = {stable_id("episode", run.manifest_hash, str(i), *tags): i for i in range(episodes)}
        if driver:  # weights changed behind lineage's back: one line, exit 5, before any episode
            verified_policy(run.warehouse, settings.data_root, driver)
        checkpoint = checkpoint_record(driver, settings.data_root, by="simulate") if driver else None
        folder = paths.resolve(settings.data_root, paths.POLICY_EPISODES if driver else paths.EPISODES_OF_MANIFEST,
                               manifest_hash=run.manifest_hash, policy_id=tags[-1] if driver else "")
        by_future = {simulate_episode.submit(scenario, run.manifest_hash, keys[key], settings.data_root, controls,
                                             driver): stage  # done, but its files deleted since: made again
                     for key, stage in run.stages("simulate", keys).items()
                     if not stage.done or not files.finished(folder / paths.EPISODE_FOLDER.format(index=keys[key]))}
        outcomes = {}

        def record(future) -> None:
            """One finished episode's lineage, written as soon as it is done: an interrupted run
            keeps every episode it finished (issue 26)."""
            stage = by_future.pop(future)
            written, success, reason, made = future.result()
            batch = files.episode_lineage(written, run.manifest_hash, stage.id, settings.data_root)
            batch.extend(control_files.episode_controls_lineage(batch, made, run.manifest_hash, stage.id,
                                                                settings.data_root))
            if checkpoint is not None:  # the policy that drove it
                batch.edges.append(EdgeRecord(parent_id=checkpoint.artifact_id, child_id=batch.artifacts[0].artifact_id,
                                              relation="policy"))
                batch.artifacts.insert(0, checkpoint)
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
        by = f" driven by {driver.name}" if driver else ""
        publish("simulate", f"{scenario.name}{by}: {len(done)} new episodes, {episodes - len(done)} already done",
                markdown_table(("episode", "seed", "outcome", "reason"),
                               [(i, scenario.seed + i, "success" if ok else "failure", why) for i, (ok, why) in done]),
                "episodes rolled out and their outcome")
        print(f"{scenario.name}: {len(done)} new episodes, {episodes - len(done)} already done; "
              + ", ".join(f"#{i} {'success' if ok else 'failure'} ({why})" for i, (ok, why) in done))
        return {"manifest_hash": run.manifest_hash, "new": len(done),
                "successes": sum(ok for ok, _ in outcomes.values()), "folder": str(folder)}


def drive_with(spec: str | None, scenario) -> Policy | None:
    """The policy named by ``spec`` (None: the manifest's scripted controller); ParamsError in
    one line if it cannot load or a vision policy's cameras are not the manifest's."""
    if spec is None:
        return None
    try:
        policy = load_policy(spec)
    except PolicySpecError as exc:
        raise ParamsError(str(exc)) from None
    problem = policy.spec.mismatch(scenario) if isinstance(policy, VisionPolicy) else None
    if problem:
        raise ParamsError(f"policy {spec!r}: {problem}")
    return policy

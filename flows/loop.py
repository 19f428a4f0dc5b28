"""loop: a policy on a panel (before) -> its worst stressor cells become manifests derived from
the parent, weighted by failure -> simulate and curate them -> post-train the policy on their
demonstrations -> the new policy on the same panel (after). Success per cell before and after.

Lineage: each derived manifest (parent_hash and a 'derived_from_failure' edge from the parent),
its episodes and shards, and the new checkpoint ('posttrained_from' the old one, 'trained_on'
the derived manifests' episodes)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

from prefect import flow, task
from prefect.cache_policies import NO_CACHE
from pydantic import Field

from flows.curate import curate
from flows.evaluate import evaluate
from flows.lookup import verified_policy
from flows.panels import resolve_grid
from flows.params import Episodes, PanelEpisodes, Steps
from flows.policy import train_policy
from flows.recording import RunContext, recorded_run
from flows.report import markdown_table, publish
from flows.simulate import simulate
from schemas import paths
from schemas.hashing import content_hash, sha256_file, stable_id
from schemas.manifest import ScenarioManifest, manifest_hash
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, MetricRecord, StageRunRecord
from schemas.settings import Settings
from tasks import loop as steps
from tasks import manifests
from tasks.policy import bc
from tasks.policy.features import FEATURES_VERSION
from tasks.policy.specs import load_policy

STAGE = "post_train_policy"
# A policy made in-flow when none is given: weak on purpose, so the loop has failures to fix.
FRESH_DEMOS, FRESH_STEPS = 3, 400

load_manifest = task(manifests.load, name="load-manifest")
collect = task(bc.collect, name="collect-demonstrations", retries=1, cache_policy=NO_CACHE)


@task(name="write-derived-manifests")
def write_derived(derived: list[ScenarioManifest], root: Path) -> list[Path]:
    out = []
    for m in derived:
        target = paths.resolve(root, paths.DERIVED_MANIFEST_FILE, manifest_hash=manifest_hash(m))
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(manifests.dump_yaml(m))
        out.append(target)
    return out


@task(name="post-train-bc", cache_policy=NO_CACHE)
def tune(policy: bc.BCPolicy, demos: bc.Demonstrations, config: bc.TrainConfig, folder: Path,
         parent: ScenarioManifest, extra: dict) -> list[dict]:
    model, history = bc.train_bc(demos, config, start=policy.model)
    bc.save_checkpoint(model, folder, parent, config, extra)
    return history


def demonstrations(parent: ScenarioManifest, policy: bc.BCPolicy, derived: list[ScenarioManifest],
                   counts: list[int]) -> bc.Demonstrations:
    """Scripted demonstrations on the derived manifests' new seeds, plus the policy's own
    training seeds when it was trained on this parent; a manifest the scripted controller
    never solves adds nothing."""
    parts = []
    if policy.meta.get("manifest_hash") == manifest_hash(parent) and policy.meta.get("train_seeds"):
        parts.append(collect(parent, policy.meta["train_seeds"]))
    for m, n in zip(derived, counts):
        try:
            parts.append(collect(m, [m.seed + i for i in range(n)]))
        except ValueError as exc:  # no successful demonstration on these seeds
            print(f"{m.name}: {exc}")
    if not parts:
        raise ValueError("no successful demonstrations on the derived manifests to post-train on")
    return steps.merge(parts)


def record_derived(run: RunContext, parent_hash: str, derived: list[ScenarioManifest], files: list[Path],
                   picked: list[tuple[str, float]], counts: list[int]) -> None:
    batch = LineageBatch()
    for m, path, (cell, rate), n in zip(derived, files, picked, counts):
        batch.extend(manifests.lineage(m, str(path)))
        batch.edges.append(EdgeRecord(parent_id=parent_hash, child_id=manifest_hash(m), relation=steps.RELATION_DERIVED))
        batch.metrics.append(MetricRecord(subject_id=manifest_hash(m), name="loop_source_success_rate", value=rate,
                                          manifest_hash=parent_hash, attrs={"cell": cell, "new_episodes": n}))
    run.write(batch)


def episode_ids(run: RunContext, digests: list[str]) -> list[str]:
    _, rows = run.warehouse.query("SELECT artifact_id FROM artifacts WHERE kind = 'episode' AND list_contains($d, "
                                  "manifest_hash) ORDER BY artifact_id", {"d": digests})
    return [r[0] for r in rows]


def checkpoint_lineage(run: RunContext, checkpoint_id: str, old_id: str, folder: Path, root: Path, key: str,
                       episodes: list[str], history: list[dict], seconds: float, attrs: dict) -> LineageBatch:
    weights = folder / bc.WEIGHTS_FILE
    stage = StageRunRecord(stage_run_id=run.stage_run_id(STAGE, key), run_id=run.run_id, stage=STAGE, input_key=key,
                           manifest_hash=run.manifest_hash, n_in=len(episodes), n_out=1, seconds=round(seconds, 3),
                           attrs={"checkpoint_id": checkpoint_id, "from": old_id})
    return LineageBatch(
        stage_runs=[stage],
        artifacts=[ArtifactRecord(artifact_id=checkpoint_id, kind="checkpoint", uri=weights.relative_to(root).as_posix(),
                                  sha256=sha256_file(str(weights)), bytes=weights.stat().st_size,
                                  manifest_hash=run.manifest_hash, stage_run_id=stage.stage_run_id,
                                  attrs={"model": "bc-policy", **attrs})],
        edges=[EdgeRecord(parent_id=old_id, child_id=checkpoint_id, relation=steps.RELATION_POSTTRAINED),
               *(EdgeRecord(parent_id=e, child_id=checkpoint_id, relation="trained_on") for e in episodes)],
        metrics=[MetricRecord(subject_id=checkpoint_id, name="post_train_loss", step=h["step"], value=h["loss"],
                              stage_run_id=stage.stage_run_id, manifest_hash=run.manifest_hash) for h in history])


def generate(derived: ScenarioManifest, path: Path, n: int, root: Path) -> dict:
    """New episodes of a derived manifest (the simulate flow), their camera videos curated."""
    simulated = simulate(str(path), episodes=n)
    videos = [str(paths.resolve(root, paths.EPISODE_VIDEO, manifest_hash=simulated["manifest_hash"], index=i,
                                camera=c.name)) for i in range(n) for c in derived.cameras]
    return {**simulated, "shards": curate(videos, str(path))["shards"]}


def post_train_policy(run: RunContext, parent: ScenarioManifest, old: bc.BCPolicy, old_id: str,
                      derived: list[ScenarioManifest], counts: list[int], post_steps: int, root: Path) -> tuple[str, Path]:
    """The old policy fine-tuned on the derived manifests' demonstrations; a finished one is reused."""
    config = bc.TrainConfig(steps=post_steps)
    digests = [manifest_hash(m) for m in derived]
    key = stable_id(STAGE, old_id, content_hash(config), str(FEATURES_VERSION),
                    *(f"{d}:{n}" for d, n in zip(digests, counts)))
    checkpoint_id = stable_id("checkpoint", key)
    folder = paths.resolve(root, paths.CHECKPOINT_DIR, model="bc-policy", checkpoint_id=checkpoint_id)
    if run.pending(STAGE, [key]) or not (folder / bc.WEIGHTS_FILE).exists():
        t0 = time.perf_counter()
        demos = demonstrations(parent, old, derived, counts)
        seeds = {d: [m.seed + i for i in range(n)] for d, m, n in zip(digests, derived, counts)}
        history = tune(old, demos, config, folder, parent,
                       {"checkpoint_id": checkpoint_id, "posttrained_from": old_id, "derived_seeds": seeds,
                        "demonstrations": int(len(demos.obs))})
        run.write(checkpoint_lineage(run, checkpoint_id, old_id, folder, root, key, episode_ids(run, digests),
                                     history, time.perf_counter() - t0,
                                     {"steps": post_steps, "posttrained_from": old_id, "derived": digests}))
    return checkpoint_id, folder


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def summarise(table: list[dict], derived: list[ScenarioManifest], counts: list[int], picked: list[tuple[str, float]],
              title: str) -> str:
    """The `loop-summary` artifact: success per cell before and after, and the derived manifests."""
    text = markdown_table(("cell", "episodes", "before", "after", "targeted"),
                          [(r["cell"], r["episodes"], _fmt(r["before"]), _fmt(r["after"]), "yes" if r["targeted"] else "")
                           for r in table])
    made = "\n".join(f"- {m.name} ({manifest_hash(m)[:12]}): {n} new episodes, from cell {cell} at {_fmt(rate)}"
                     for m, n, (cell, rate) in zip(derived, counts, picked))
    publish("loop", title, f"{text}\n\nDerived manifests:\n{made}", "success per stressor cell before and after")
    return text


@flow(name="loop", log_prints=True)
def loop(manifest: str, policy: str | None = None, grid: str | None = None, episodes: PanelEpisodes | None = None,
         worst: Annotated[int, Field(ge=1, le=8)] = 1, new_episodes: Episodes = 12, post_steps: Steps = 2000) -> dict:
    """Close the loop once for ``policy`` (``bc:PATH``; default: a weak policy trained here on
    a few demonstrations) on the panel of ``manifest`` over ``grid``: the ``worst`` cells get
    ``new_episodes`` in all, in proportion to their failure rate."""
    settings = Settings()
    root = settings.data_root.resolve()
    parent = load_manifest(Path(manifest))
    bc.require_arm(parent)
    chosen = resolve_grid(parent, grid, episodes)
    params = {"manifest": manifest, "policy": policy, "grid": grid, "episodes": episodes, "worst": worst,
              "new_episodes": new_episodes, "post_steps": post_steps}
    with recorded_run("loop", settings, parent, source_uri=manifest, params=params) as run:
        if policy is None:
            policy = "bc:" + train_policy(manifest, episodes=FRESH_DEMOS, steps=FRESH_STEPS, holdout=0)["folder"]
        old = load_policy(policy)
        if not isinstance(old, bc.BCPolicy):
            raise ValueError(f"policy {policy!r}: the loop post-trains behaviour-cloning policies (bc:PATH)")
        verified_policy(run.warehouse, root, old)  # the weights it fine-tunes, as lineage recorded them
        old_id = old.meta.get("checkpoint_id") or stable_id("checkpoint", "bc", old.meta["weights_sha256"])

        before = evaluate(manifest, grid, episodes, [policy], detector=False)["evaluations"][0]
        picked = steps.worst_cells(before["table"], worst)
        counts = steps.episode_counts([rate for _, rate in picked], new_episodes)
        derived = steps.derive_manifests(parent, chosen, [cell for cell, _ in picked])
        files = write_derived(derived, root)
        record_derived(run, run.manifest_hash, derived, files, picked, counts)

        made = [generate(m, path, n, root) for m, path, n in zip(derived, files, counts)]
        checkpoint_id, folder = post_train_policy(run, parent, old, old_id, derived, counts, post_steps, root)

        after = evaluate(manifest, grid, episodes, [f"bc:{folder}"], detector=False)["evaluations"][0]
        table = steps.before_after(before["table"], after["table"], [cell for cell, _ in picked])
        run.write(LineageBatch(metrics=[MetricRecord(
            subject_id=checkpoint_id, name="loop_success_rate" + ("" if r["cell"] == "all" else f"/{r['cell']}"),
            value=r["after"], manifest_hash=run.manifest_hash,
            attrs={"before": r["before"], "before_evaluation": before["evaluation_id"]})
            for r in table if r["after"] is not None]))
        text = summarise(table, derived, counts, picked, f"{old.name} -> bc:{checkpoint_id[:12]} on {before['panel']}")
        print(text)
        return {"before_evaluation_id": before["evaluation_id"], "after_evaluation_id": after["evaluation_id"],
                "table": table, "derived": [{"manifest_hash": d, "path": str(p), "cell": c, "episodes": n,
                                             "source_success_rate": rate}
                                            for d, p, (c, rate), n in zip(map(manifest_hash, derived), files, picked,
                                                                          counts)],
                "shards": [u for g in made for u in g["shards"]], "old_checkpoint_id": old_id, "checkpoint_id": checkpoint_id,
                "checkpoint": str(folder), "simulated": made}

"""loop: a policy on a panel (before) -> its worst stressor cells become manifests derived from
the parent, weighted by failure -> simulate and curate them -> post-train the policy on their
demonstrations -> the new policy on the same panel (after). Success per cell before and after.

Lineage: each derived manifest (parent_hash and a 'derived_from_failure' edge from the parent),
its episodes and shards, and the new checkpoint ('posttrained_from' the old one, 'trained_on'
the derived manifests' episodes)."""

from __future__ import annotations

from pathlib import Path

from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.curate import curate
from flows.evaluate import evaluate
from flows.params import Episodes, PanelEpisodes, Steps, Worst
from flows.params_policy import LoopParams
from flows.policy import train_policy
from flows.recording import RunContext, recorded_run
from flows.report import publish
from flows.simulate import simulate
from schemas import paths
from schemas.hashing import content_hash, stable_id
from schemas.manifest import ScenarioManifest
from schemas.records import EdgeRecord, LineageBatch, MetricRecord
from schemas.settings import Settings
from tasks import loop as steps
from tasks import manifests
from tasks.lookup import verified_policy
from tasks.panels.grid import resolve_grid
from tasks.policy import bc, posttrain
from tasks.policy.features import FEATURES_VERSION
from tasks.policy.lineage import checkpoint_lineage
from tasks.policy.specs import load_policy
from tasks.policy.vision import VisionPolicy
from warehouse import queries

STAGE = "post_train_policy"
# A policy made in-flow when none is given: weak on purpose, so the loop has failures to fix.
FRESH_DEMOS, FRESH_STEPS = 3, 400

load_manifest = task(manifests.load, name="load-manifest")


@task(name="write-derived-manifests")
def write_derived(derived: list[ScenarioManifest], root: Path) -> list[Path]:
    out = []
    for m in derived:
        target = paths.resolve(root, paths.DERIVED_MANIFEST_FILE, manifest_hash=m.sha256)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(manifests.dump_yaml(m))
        out.append(target)
    return out


collect_demonstrations = task(posttrain.demonstrations, name="collect-demonstrations", retries=1, cache_policy=NO_CACHE)
tune = task(posttrain.post_train, name="post-train-policy", cache_policy=NO_CACHE)


def generate(derived: ScenarioManifest, path: Path, n: int, root: Path) -> dict:
    """New episodes of a derived manifest (the simulate flow), their camera videos curated."""
    simulated = simulate(str(path), episodes=n)
    videos = [str(paths.resolve(root, paths.EPISODE_VIDEO, manifest_hash=simulated["manifest_hash"], index=i,
                                camera=c.name)) for i in range(n) for c in derived.cameras]
    return {**simulated, "shards": curate(videos, str(path))["shards"]}


def post_train_policy(run: RunContext, parent: ScenarioManifest, old: posttrain.Learned, old_id: str,
                      derived: list[ScenarioManifest], counts: list[int], post_steps: int, root: Path) -> tuple[str, Path]:
    """The old policy fine-tuned on the derived manifests' demonstrations; a finished one is reused."""
    # A vision policy trained with random shifts keeps them (its checkpoint's train config).
    config = bc.TrainConfig(steps=post_steps, shift=old.meta.get("train", {}).get("shift", 0)
                            if isinstance(old, VisionPolicy) else 0)
    digests = [m.sha256 for m in derived]
    key = stable_id(STAGE, old_id, content_hash(config), str(FEATURES_VERSION),
                    *(f"{d}:{n}" for d, n in zip(digests, counts)))
    checkpoint_id = stable_id("checkpoint", key)
    folder = paths.resolve(root, paths.CHECKPOINT_DIR, model=posttrain.model_name(old), checkpoint_id=checkpoint_id)
    stage = run.stage(STAGE, key, [folder / bc.WEIGHTS_FILE])
    if not stage.done:
        demos = collect_demonstrations(parent, old, derived, counts)
        seeds = {d: [m.seed + i for i in range(n)] for d, m, n in zip(digests, derived, counts)}
        history = tune(old, demos, config, folder, parent,
                       {"checkpoint_id": checkpoint_id, "posttrained_from": old_id, "derived_seeds": seeds,
                        "demonstrations": posttrain.samples(demos)})
        episodes = queries.episode_ids(run.warehouse, digests)
        stage.finish(len(episodes), 1, checkpoint_lineage(
            checkpoint_id, folder / bc.WEIGHTS_FILE, root, stage.id, run.manifest_hash,
            {"model": posttrain.model_name(old), "steps": post_steps, "posttrained_from": old_id, "derived": digests},
            [(old_id, steps.RELATION_POSTTRAINED), *((e, "trained_on") for e in episodes)], "post_train_loss",
            history), attrs={"checkpoint_id": checkpoint_id, "from": old_id})
    return checkpoint_id, folder


def untargeted_control(run: RunContext, parent: ScenarioManifest, grid, old: posttrain.Learned, old_id: str,
                       budget: int, post_steps: int, root: Path) -> tuple[str, Path]:
    """The control arm: the old policy post-trained on ``budget`` new episodes of the parent
    as it is (its own derived manifest, an 'untargeted_control' edge from the parent)."""
    nominal = steps.control_manifest(parent, grid)
    (path,) = write_derived([nominal], root)
    batch = manifests.lineage(nominal, str(path))
    batch.edges.append(EdgeRecord(parent_id=run.manifest_hash, child_id=nominal.sha256, relation=steps.RELATION_CONTROL))
    run.write(batch)
    generate(nominal, path, budget, root)
    return post_train_policy(run, parent, old, old_id, [nominal], [budget], post_steps, root)


def summarise(table: list[dict], derived: list[ScenarioManifest], counts: list[int], picked: list[tuple[str, float]],
              title: str) -> str:
    """The `loop-summary` artifact: success per cell before and after, and the derived manifests."""
    text, made = steps.summary_text(table, derived, counts, picked)
    publish("loop", title, f"{text}\n\nDerived manifests:\n{made}", "success per stressor cell before and after")
    return text


@flow(name="loop", log_prints=True)
def loop(manifest: str, policy: str | None = None, grid: str | None = None, episodes: PanelEpisodes | None = None,
         worst: Worst = 1, new_episodes: Episodes = 12, post_steps: Steps = 2000, control: bool = False) -> dict:
    """Close the loop once for ``policy`` (``bc:PATH`` or ``vision:PATH``; default: a weak state policy trained here on
    a few demonstrations) on the panel of ``manifest`` over ``grid``: the ``worst`` cells get
    ``new_episodes`` in all, in proportion to their failure rate. With ``control``, the same
    policy is also post-trained on as many new episodes of the manifest as it is (untargeted)
    and evaluated on the same panel, beside the targeted one."""
    checks = LoopParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    root = settings.data_root.resolve()
    parent = load_manifest(Path(manifest))
    checks.check_scenario(parent)
    chosen = resolve_grid(parent, grid, episodes)
    params = {"manifest": manifest, "policy": policy, "grid": grid, "episodes": episodes, "worst": worst,
              "new_episodes": new_episodes, "post_steps": post_steps, "control": control}
    with recorded_run("loop", settings, parent, source_uri=manifest, params=params) as run:
        if policy is None:
            policy = "bc:" + train_policy(manifest, episodes=FRESH_DEMOS, steps=FRESH_STEPS, holdout=0)["folder"]
        old = load_policy(policy)
        kind = posttrain.kind_of(old)  # ValueError unless a learned policy
        verified_policy(run.warehouse, root, old)  # the weights it fine-tunes, as lineage recorded them
        old_id = old.meta.get("checkpoint_id") or stable_id("checkpoint", kind, old.meta["weights_sha256"])

        before = evaluate(manifest, grid, episodes, [policy], detector=False)["evaluations"][0]
        picked = steps.worst_cells(before["table"], worst)
        counts = steps.episode_counts([rate for _, rate in picked], new_episodes)
        derived = steps.derive_manifests(parent, chosen, [cell for cell, _ in picked])
        files = write_derived(derived, root)
        run.write(steps.derived_lineage(run.manifest_hash, derived, files, picked, counts, before["evaluation_id"]))

        made = [generate(m, path, n, root) for m, path, n in zip(derived, files, counts)]
        checkpoint_id, folder = post_train_policy(run, parent, old, old_id, derived, counts, post_steps, root)

        after = evaluate(manifest, grid, episodes, [f"{kind}:{folder}"], detector=False)["evaluations"][0]
        untargeted = untargeted_control(run, parent, chosen, old, old_id, sum(counts), post_steps, root) if control else None
        versus = evaluate(manifest, grid, episodes, [f"{kind}:{untargeted[1]}"], detector=False)["evaluations"][0] \
            if untargeted else None
        table = steps.before_after(before["table"], after["table"], [cell for cell, _ in picked],
                                   versus["table"] if versus else None)
        run.write(LineageBatch(metrics=[MetricRecord(
            subject_id=checkpoint_id, name="loop_success_rate" + ("" if r["cell"] == "all" else f"/{r['cell']}"),
            value=r["after"], manifest_hash=run.manifest_hash,
            attrs={"before": r["before"], "before_evaluation": before["evaluation_id"]})
            for r in table if r["after"] is not None]))
        text = summarise(table, derived, counts, picked, f"{old.name} -> {kind}:{checkpoint_id[:12]} on {before['panel']}")
        print(text)
        return {"before_evaluation_id": before["evaluation_id"], "after_evaluation_id": after["evaluation_id"],
                "table": table, "derived": [{"manifest_hash": d, "path": str(p), "cell": c, "episodes": n,
                                             "source_success_rate": rate}
                                            for d, p, (c, rate), n in zip((m.sha256 for m in derived), files, picked,
                                                                          counts)],
                "shards": [u for g in made for u in g["shards"]], "old_checkpoint_id": old_id, "checkpoint_id": checkpoint_id,
                "checkpoint": str(folder), "simulated": made,
                "control": None if not versus else {"checkpoint_id": untargeted[0], "checkpoint": str(untargeted[1]),
                                                    "evaluation_id": versus["evaluation_id"]}}

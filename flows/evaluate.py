"""evaluate: policies x a matched panel -> simulator verdicts (ground truth), frame-
detector verdicts (on the simulator's renders, and on world-model rollouts when a world model
is given: its replay of the episode's actions, and with ``in_world_model`` the policy driving
it closed loop) -> success per stressor cell, rank correlation between the verdict sets, lineage.

Panels whose contracts differ (camera layout, horizon, embodiment, task, evaluation target)
are refused before any work, as is a learned policy trained under another contract."""

from __future__ import annotations

import json
from pathlib import Path

from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.panels import panels as panels_flow
from flows.params import PanelEpisodes, WorldSamples
from flows.params_policy import EvaluateParams
from flows.recording import RunContext, recorded_run
from flows.report import markdown_table, progress, publish, write_json
from flows.runners import task_runner
from schemas import paths
from schemas.hashing import content_hash, stable_id
from schemas.manifest import ScenarioManifest
from schemas.panel import PanelSpec
from schemas.records import EdgeRecord
from schemas.settings import Settings
from tasks import manifests
from tasks.lookup import verified_artifact, verified_policy, verified_world_model
from tasks.panels.contract import PanelContractError, check_same_contract
from tasks.panels.detect import DETECTOR_VERSION
from tasks.panels.grid import expand, primary_camera, resolve_grid
from tasks.policy.base import Policy
from tasks.policy.bc import BCPolicy
from tasks.policy.evaluate import EpisodeOutcome, Rollout, run_episode, success_table, world_outcome
from tasks.policy.results import JUDGES, agreement_line, comparison, comparison_lineage, evaluation_lineage, fmt
from tasks.policy.specs import load_policy
from tasks.policy.vision import VisionPolicy
from tasks.policy.world_env import TWIN_VERSION

STAGE = "evaluate_policy"
DEFAULT_POLICIES = ("scripted", "scripted:0.8")
# Inputs hold a policy (a network): nothing to gain from hashing them for a cache key.
episode_task = task(run_episode, name="evaluate-episode", retries=1, cache_policy=NO_CACHE)


def plan(manifest_paths: list[str], grid: str | None, episodes: int | None,
         policies: list[Policy]) -> list[tuple[str, ScenarioManifest, PanelSpec, list[ScenarioManifest]]]:
    """Each manifest's panel over the same grid; PanelContractError unless every panel, and
    every learned policy's training contract, is the same."""
    out = []
    for path in manifest_paths:
        parent = manifests.load(Path(path))
        spec, variants = expand(parent, resolve_grid(parent, grid, episodes))
        out.append((path, parent, spec, variants))
    named = {f"panel {spec.name} ({path})": spec.contract for path, _, spec, _ in out}
    named.update({f"policy {p.name} (trained on {p.meta.get('manifest_hash', '?')[:12]})": p.contract
                  for p in policies if isinstance(p, (BCPolicy, VisionPolicy)) and p.contract is not None})
    check_same_contract(named)
    for policy in policies:  # a vision policy must see through cameras the panel has, as it was trained
        problems = [policy.spec.mismatch(parent) for _, parent, *_ in out] if isinstance(policy, VisionPolicy) else []
        if any(problems):
            raise PanelContractError(f"policy {policy.name}: {next(p for p in problems if p)}")
    return out


def evaluate_one(run: RunContext, spec: PanelSpec, variants: list[ScenarioManifest], policy: Policy,
                 camera: str | None, world_model: str | None, samples: int = 1,
                 device: str | None = None, closed: bool = False) -> list[EpisodeOutcome]:
    """Every variant x seed of the panel under one policy; the world model judges each from
    ``samples`` rollouts (one greedy, or that many sampled: ``world_judgement``) and, with
    ``closed``, from the policy's closed loop in it."""
    futures = [(variant, pv.cell, seed, episode_task.submit(variant, pv.cell, seed, policy, camera))
               for pv, variant in zip(spec.variants, variants) for seed in pv.seeds]
    outcomes = []
    with progress(len(futures), f"{policy.name} on {spec.name}") as bar:
        for variant, cell, seed, future in futures:
            done: Rollout = future.result()
            outcomes.append(world_outcome(done, variant, policy, camera, world_model, run.settings.data_root, samples,
                                          closed, device) if world_model else done.outcome)
            bar.advance()
    return outcomes


def evaluate_policy(run: RunContext, panel: dict, spec: PanelSpec, variants: list[ScenarioManifest], policy: Policy,
                    camera: str | None, world_model: str | None, wm_sha: str | None,
                    world_ids: list[str], samples: int = 1, device: str | None = None,
                    closed: bool = False) -> tuple[str, dict]:
    """(evaluation id, result body) of one policy on one panel; a finished one is read back."""
    root = run.settings.data_root
    key = stable_id(STAGE, panel["panel_id"], content_hash(policy.describe()), wm_sha or "",
                    f"{camera}/detector-{DETECTOR_VERSION}" if camera else "",
                    *([f"world-samples-{samples}"] if world_model and samples > 1 else []),
                    *([f"closed-loop/twin-{TWIN_VERSION}"] if closed else []))
    evaluation_id = stable_id("evaluation", key)
    result_file = paths.resolve(root, paths.EVALUATION_FILE, evaluation_id=evaluation_id)
    stage = run.stage(STAGE, key, [result_file], manifest_hash=panel["manifest_hash"])
    if stage.done:  # its table is read back, so it must be the file lineage recorded
        verified_artifact(run.warehouse, result_file, evaluation_id)
        return evaluation_id, json.loads(result_file.read_text())
    outcomes = evaluate_one(run, spec, variants, policy, camera, world_model, samples, device, closed)
    table = success_table(outcomes, [v.cell for v in spec.variants])
    body = {"format": "worldline-evaluation/1", "evaluation_id": evaluation_id, "panel_id": panel["panel_id"],
            "panel": spec.name, "contract_hash": spec.contract_hash, "policy": policy.describe(),
            "camera": camera, "world_model": world_model, **({"closed_loop": True} if closed else {}),
            "table": table, "episodes": [o.as_dict() for o in outcomes]}
    write_json(result_file, body)
    batch = evaluation_lineage(evaluation_id, result_file, root, body, panel["panel_id"], policy, stage.id,
                               panel["manifest_hash"])
    batch.edges += [EdgeRecord(parent_id=c, child_id=evaluation_id, relation="world_model") for c in world_ids]
    stage.finish(len(outcomes), 1, batch, attrs={"policy": policy.name, "panel_id": panel["panel_id"]})
    return evaluation_id, json.loads(result_file.read_text())


def compare_verdicts(run: RunContext, results: list[tuple[str, str, str, list[dict]]], episodes: list[dict],
                     root: Path) -> dict:
    """The simulator's verdicts against the frame detector's and the world model's, across
    policies and cells; one 'evaluation' artifact (role comparison) over the policy evaluations."""
    comparison_id, body = comparison(results, episodes)
    target = paths.resolve(root, paths.EVALUATION_FILE, evaluation_id=comparison_id)
    write_json(target, body)
    run.write(comparison_lineage(comparison_id, target, root, body, run.manifest_hash))
    return {"comparison_id": comparison_id, "spearman": body["spearman"], "agreement": body["agreement"]}


def world_checkpoints(run: RunContext, world_model: str | None) -> list[str]:
    """Lineage ids of the world-model checkpoint a folder holds, its weights (and its tokenizer's)
    checked against lineage (TamperedArtifact), so an evaluation traces back through it to its
    token shards, clips and raw videos; none for a checkpoint lineage does not know."""
    found = verified_world_model(run.warehouse, run.settings.data_root, world_model)
    return [found] if found else []


@flow(name="evaluate", log_prints=True, task_runner=task_runner())
def evaluate(manifest: str, grid: str | None = None, episodes: PanelEpisodes | None = None,
             policies: list[str] | None = None, compare: list[str] | None = None,
             world_model: str | None = None, detector: bool = True, guard: bool = True,
             world_samples: WorldSamples = 1, device: str | None = None, in_world_model: bool = False) -> dict:
    """Evaluate ``policies`` (default: the scripted controller at the manifest's noise and at
    0.8) on the panel of ``manifest`` over ``grid``, and on the panels of the ``compare``
    manifests over the same grid (their contracts must match). ``in_world_model``: each (vision)
    policy also drives the world model closed loop (``tasks.policy.world_env``). ``device``: where
    the world model rolls out (``tasks.device``; it changes no id)."""
    checks = EvaluateParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    root = settings.data_root
    loaded = [load_policy(p) for p in (policies or DEFAULT_POLICIES)]
    planned = plan([manifest, *(compare or [])], grid, episodes, loaded)
    checks.check_world(planned[0][1], loaded, world_model, root, flow=True)  # before any panel rolls it out
    made = {path: panels_flow(path, grid, episodes, world_model, None, guard, device) for path, *_ in planned}
    parent = planned[0][1]
    camera = primary_camera(parent, None) if detector or world_model else None
    wm_sha = content_hash({"checkpoint": str(Path(world_model).resolve())}) if world_model else None
    params = {"manifest": manifest, "grid": grid, "episodes": episodes, "policies": [p.name for p in loaded],
              "compare": compare or [], "world_model": world_model, "detector": detector,
              "world_samples": world_samples, **({"in_world_model": True} if in_world_model else {})}
    with recorded_run("evaluate", settings, parent, source_uri=manifest, params=params) as run:
        for policy in loaded:  # a learned policy's weights, as read, must be the ones lineage recorded
            verified_policy(run.warehouse, root, policy)
        world_ids = world_checkpoints(run, world_model)  # checked once, before any rollout
        results = []  # (panel name, policy, evaluation id, table)
        episodes = []  # every evaluation's episodes, for per-episode agreement
        for path, _, spec, variants in planned:
            for policy in loaded:
                evaluation_id, body = evaluate_policy(run, made[path], spec, variants, policy, camera, world_model,
                                                      wm_sha, world_ids, world_samples, device, in_world_model)
                results.append((spec.name, policy.name, evaluation_id, body["table"]))
                episodes += body["episodes"]
        summary = compare_verdicts(run, results, episodes, root)
        closed = [JUDGES["closed"]] if in_world_model else []
        rows = [(panel, name, r["cell"], r["episodes"], fmt(r["sim"]), fmt(r["detector"]), fmt(r["world"]),
                 *([fmt(r.get("closed"))] if closed else []), fmt(r.get("world_sure")))
                for panel, name, _, table in results for r in table]
        text = markdown_table(("panel", "policy", "cell", "episodes", "simulator", "detector on sim", "world model",
                               *closed, "world sure"), rows)
        corr = "; ".join(f"{k} {fmt(v)}" for k, v in summary["spearman"].items())
        agree = "\n".join(agreement_line(f"{JUDGES.get(k, k)} vs simulator", a)
                          for k, a in summary["agreement"].items())
        publish("evaluate", f"{len(loaded)} policies on {len(planned)} panel(s)",
                text + f"\n\nSpearman across policies: {corr}\n\n{agree}", "success per stressor cell and policy")
        print(text + f"\nSpearman: {corr}\n{agree}")
        return {"evaluations": [{"panel": p, "policy": n, "evaluation_id": e, "table": t} for p, n, e, t in results],
                "contract_hash": planned[0][2].contract_hash, **summary}



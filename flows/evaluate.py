"""evaluate: policies x a matched panel -> simulator verdicts (ground truth), frame-
detector verdicts (on the simulator's renders, and on world-model rollouts when a world model
is given) -> success per stressor cell, rank correlation between the verdict sets, lineage.

Panels whose contracts differ (camera layout, horizon, embodiment, task, evaluation target)
are refused before any work, as is a learned policy trained under another contract."""

from __future__ import annotations

import json
import time
from pathlib import Path

from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.lookup import verified_artifact, verified_policy, verified_world_model
from flows.panels import panels as panels_flow
from flows.panels import primary_camera, resolve_grid, world_text
from flows.params import PanelEpisodes
from flows.recording import RunContext, recorded_run
from flows.report import markdown_table, progress, publish, write_json
from flows.runners import task_runner
from schemas import paths
from schemas.hashing import content_hash, sha256_file, stable_id
from schemas.manifest import ScenarioManifest
from schemas.panel import PanelSpec
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, MetricRecord, StageRunRecord
from schemas.settings import Settings
from tasks import manifests
from tasks.panels.contract import check_same_contract
from tasks.panels.detect import DETECTOR_VERSION, judge_frames
from tasks.panels.grid import expand
from tasks.panels.world import WorldModelRequest, world_model_rollout
from tasks.policy.base import Policy
from tasks.policy.bc import BCPolicy
from tasks.policy.evaluate import EpisodeOutcome, Rollout, agreement, run_episode, spearman, success_table
from tasks.policy.specs import load_policy

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
                  for p in policies if isinstance(p, BCPolicy) and p.contract is not None})
    check_same_contract(named)
    return out


def world_verdict(world_model: str, variant: ScenarioManifest, camera: str, done: Rollout,
                  root: Path) -> tuple[bool | None, str]:
    """The world model rolls the policy's actions out from the episode's first frame; the
    frame detector judges what it generates (nothing generated here is written, so the face
    guard has nothing to guard)."""
    cam = next(c for c in variant.cameras if c.name == camera)
    n_frames = int(variant.horizon_s * cam.fps + 1e-9)
    request = WorldModelRequest(camera=camera, context=done.context, actions=done.actions,
                                control_hz=done.control_hz, fps=cam.fps, frames=n_frames, text=world_text(variant))
    generated = world_model_rollout(world_model, request, root)
    verdict = judge_frames(generated, cam, variant.evaluation, done.package_start, reference=done.context[0])
    return verdict.success, verdict.reason


def evaluate_one(run: RunContext, spec: PanelSpec, variants: list[ScenarioManifest], policy: Policy,
                 camera: str | None, world_model: str | None) -> list[EpisodeOutcome]:
    """Every variant x seed of the panel under one policy."""
    futures = [(variant, pv.cell, seed, episode_task.submit(variant, pv.cell, seed, policy, camera))
               for pv, variant in zip(spec.variants, variants) for seed in pv.seeds]
    outcomes = []
    with progress(len(futures), f"{policy.name} on {spec.name}") as bar:
        for variant, cell, seed, future in futures:
            done: Rollout = future.result()
            outcome = done.outcome
            if world_model:
                world, why = world_verdict(world_model, variant, camera, done, run.settings.data_root)
                outcome = EpisodeOutcome(**{**outcome.as_dict(), "world": world, "world_reason": why})
            outcomes.append(outcome)
            bar.advance()
    return outcomes


def world_checkpoints(run: RunContext, world_model: str | None) -> list[str]:
    """Lineage ids of the world-model checkpoint a folder holds, its weights (and its tokenizer's)
    checked against lineage (TamperedArtifact), so an evaluation traces back through it to its
    token shards, clips and raw videos; none for a checkpoint lineage does not know."""
    found = verified_world_model(run.warehouse, run.settings.data_root, world_model)
    return [found] if found else []


def evaluation_lineage(evaluation_id: str, result_file: Path, root: Path, body: dict, panel_id: str,
                       policy: Policy, stage_run_id: str, digest: str) -> LineageBatch:
    attrs = {"policy": policy.describe(), "panel_id": panel_id, "contract_hash": body["contract_hash"],
             "table": body["table"]}
    batch = LineageBatch(artifacts=[ArtifactRecord(
        artifact_id=evaluation_id, kind="evaluation", uri=result_file.relative_to(root).as_posix(),
        sha256=sha256_file(str(result_file)), bytes=result_file.stat().st_size, manifest_hash=digest,
        stage_run_id=stage_run_id, attrs=attrs)],
        edges=[EdgeRecord(parent_id=panel_id, child_id=evaluation_id, relation="evaluated_on")])
    if isinstance(policy, BCPolicy):
        checkpoint_id = policy.meta.get("checkpoint_id") or stable_id("checkpoint", "bc", policy.meta["weights_sha256"])
        weights = Path(policy.source) / "model.safetensors"
        uri = weights.resolve().relative_to(root.resolve()).as_posix() if weights.resolve().is_relative_to(root.resolve()) \
            else str(weights)
        # The checkpoint as the train-policy flow records it (ignored if already there).
        batch.artifacts.insert(0, ArtifactRecord(artifact_id=checkpoint_id, kind="checkpoint", uri=uri,
                                                 sha256=policy.meta["weights_sha256"], bytes=weights.stat().st_size,
                                                 manifest_hash=policy.meta.get("manifest_hash"),
                                                 attrs={"model": "bc-policy", "registered_by": "evaluate"}))
        batch.edges.append(EdgeRecord(parent_id=checkpoint_id, child_id=evaluation_id, relation="policy"))
    for row in body["table"]:
        suffix = "" if row["cell"] == "all" else f"/{row['cell']}"
        for column in ("sim", "detector", "world"):
            if row[column] is not None:
                batch.metrics.append(MetricRecord(subject_id=evaluation_id, name=f"{column}_success_rate{suffix}",
                                                  value=row[column], stage_run_id=stage_run_id, manifest_hash=digest,
                                                  attrs={"cell": row["cell"], "episodes": row["episodes"]}))
    return batch


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


@flow(name="evaluate", log_prints=True, task_runner=task_runner())
def evaluate(manifest: str, grid: str | None = None, episodes: PanelEpisodes | None = None,
             policies: list[str] | None = None, compare: list[str] | None = None,
             world_model: str | None = None, detector: bool = True, guard: bool = True) -> dict:
    """Evaluate ``policies`` (default: the scripted controller at the manifest's noise and at
    0.8) on the panel of ``manifest`` over ``grid``, and on the panels of the ``compare``
    manifests over the same grid (their contracts must match)."""
    settings = Settings()
    root = settings.data_root
    loaded = [load_policy(p) for p in (policies or DEFAULT_POLICIES)]
    planned = plan([manifest, *(compare or [])], grid, episodes, loaded)
    made = {path: panels_flow(path, grid, episodes, world_model, None, guard) for path, *_ in planned}
    parent = planned[0][1]
    camera = primary_camera(parent, None) if detector or world_model else None
    wm_sha = content_hash({"checkpoint": str(Path(world_model).resolve())}) if world_model else None
    params = {"manifest": manifest, "grid": grid, "episodes": episodes, "policies": [p.name for p in loaded],
              "compare": compare or [], "world_model": world_model, "detector": detector}
    with recorded_run("evaluate", settings, parent, source_uri=manifest, params=params) as run:
        for policy in loaded:  # a learned policy's weights, as read, must be the ones lineage recorded
            verified_policy(run.warehouse, root, policy)
        world_ids = world_checkpoints(run, world_model)  # checked once, before any rollout
        results = []  # (panel name, policy, evaluation id, table)
        episodes = []  # every evaluation's episodes, for per-episode agreement
        for path, panel_parent, spec, variants in planned:
            panel_id = made[path]["panel_id"]
            for policy in loaded:
                t0 = time.perf_counter()
                key = stable_id(STAGE, panel_id, content_hash(policy.describe()), wm_sha or "",
                                f"{camera}/detector-{DETECTOR_VERSION}" if camera else "")
                evaluation_id = stable_id("evaluation", key)
                result_file = paths.resolve(root, paths.EVALUATION_FILE, evaluation_id=evaluation_id)
                if run.pending(STAGE, [key]) or not result_file.is_file():
                    outcomes = evaluate_one(run, spec, variants, policy, camera, world_model)
                    table = success_table(outcomes, [v.cell for v in spec.variants])
                    body = {"format": "worldline-evaluation/1", "evaluation_id": evaluation_id, "panel_id": panel_id,
                            "panel": spec.name, "contract_hash": spec.contract_hash, "policy": policy.describe(),
                            "camera": camera, "world_model": world_model, "table": table,
                            "episodes": [o.as_dict() for o in outcomes]}
                    write_json(result_file, body)
                    stage = StageRunRecord(stage_run_id=run.stage_run_id(STAGE, key), run_id=run.run_id, stage=STAGE,
                                           input_key=key, manifest_hash=made[path]["manifest_hash"],
                                           n_in=len(outcomes), n_out=1, seconds=round(time.perf_counter() - t0, 3),
                                           attrs={"policy": policy.name, "panel_id": panel_id})
                    batch = evaluation_lineage(evaluation_id, result_file, root, body, panel_id, policy,
                                               stage.stage_run_id, made[path]["manifest_hash"])
                    batch.edges += [EdgeRecord(parent_id=c, child_id=evaluation_id, relation="world_model")
                                    for c in world_ids]
                    run.write(LineageBatch(stage_runs=[stage]).extend(batch))
                else:  # done before: its table is read back, so it must be the file lineage recorded
                    verified_artifact(run.warehouse, result_file, evaluation_id)
                body = json.loads(result_file.read_text())
                results.append((spec.name, policy.name, evaluation_id, body["table"]))
                episodes += body["episodes"]
        summary = compare_verdicts(run, results, episodes, root)
        rows = [(panel, name, r["cell"], r["episodes"], _fmt(r["sim"]), _fmt(r["detector"]), _fmt(r["world"]))
                for panel, name, _, table in results for r in table]
        text = markdown_table(("panel", "policy", "cell", "episodes", "simulator", "detector on sim", "world model"), rows)
        corr = "; ".join(f"{k} {_fmt(v)}" for k, v in summary["spearman"].items())
        agree = "\n".join(agreement_line(f"{k} vs simulator", a) for k, a in summary["agreement"].items())
        publish("evaluate", f"{len(loaded)} policies on {len(planned)} panel(s)",
                text + f"\n\nSpearman across policies: {corr}\n\n{agree}", "success per stressor cell and policy")
        print(text + f"\nSpearman: {corr}\n{agree}")
        return {"evaluations": [{"panel": p, "policy": n, "evaluation_id": e, "table": t} for p, n, e, t in results],
                "contract_hash": planned[0][2].contract_hash, **summary}


def compare_verdicts(run: RunContext, results: list[tuple[str, str, str, list[dict]]], episodes: list[dict],
                     root: Path) -> dict:
    """Rank correlation of the simulator's verdicts with the frame detector's and the world
    model's, across policies (overall rates) and across policy x cell rates; one 'evaluation'
    artifact (role comparison) over the policy evaluations."""
    overall = [next(r for r in t if r["cell"] == "all") for *_, t in results]
    cells = [r for *_, t in results for r in t if r["cell"] != "all"]
    corr = {
        "sim_vs_world": spearman([r["sim"] for r in overall], [r["world"] for r in overall]),
        "sim_vs_detector": spearman([r["sim"] for r in overall], [r["detector"] for r in overall]),
        "sim_vs_world_cells": spearman([r["sim"] for r in cells], [r["world"] for r in cells]),
        "sim_vs_detector_cells": spearman([r["sim"] for r in cells], [r["detector"] for r in cells]),
    }
    agree = {column: agreement(episodes, column) for column in ("detector", "world")}
    ids = sorted(e for _, _, e, _ in results)
    comparison_id = stable_id("evaluation_comparison", *ids)
    target = paths.resolve(root, paths.EVALUATION_FILE, evaluation_id=comparison_id)
    body = {"format": "worldline-evaluation-comparison/1", "evaluations": ids, "spearman": corr, "agreement": agree,
            "overall": [{"panel": p, "policy": n, **next(r for r in t if r["cell"] == "all")} for p, n, _, t in results]}
    write_json(target, body)
    batch = LineageBatch(artifacts=[ArtifactRecord(
        artifact_id=comparison_id, kind="evaluation", uri=target.relative_to(root).as_posix(),
        sha256=sha256_file(str(target)), bytes=target.stat().st_size, manifest_hash=run.manifest_hash,
        attrs={"role": "comparison", "spearman": corr, "agreement": agree})],
        edges=[EdgeRecord(parent_id=e, child_id=comparison_id, relation="compared") for e in ids],
        metrics=[MetricRecord(subject_id=comparison_id, name=f"spearman_{k}", value=v, manifest_hash=run.manifest_hash)
                 for k, v in corr.items() if v is not None])
    batch.metrics += [MetricRecord(subject_id=comparison_id, name=f"agreement_{column}_{k}", value=v,
                                   manifest_hash=run.manifest_hash)
                      for column, a in agree.items() if a["decided"]
                      for k, v in (("decided", a["decided"] / a["episodes"]), ("rate", a["agree"] / a["decided"]),
                                   ("balanced", a["balanced"])) if v is not None]
    run.write(batch)
    return {"comparison_id": comparison_id, "spearman": corr, "agreement": agree}


def agreement_line(name: str, a: dict) -> str:
    """One line: how a judge's verdicts match the simulator's, episode by episode."""
    if not a["decided"]:
        return f"{name}: no episode decided"
    balanced = "-" if a["balanced"] is None else f"{a['balanced']:.2f}"
    return (f"{name}: decided {a['decided']} of {a['episodes']}, agree on {a['agree']}; on the simulator's "
            f"successes {a['successes_agree']}/{a['successes']}, on its failures {a['failures_agree']}/{a['failures']} "
            f"(balanced {balanced})")

"""What the evaluate flow records and prints of its results: each policy evaluation's lineage,
the comparison of the simulator's verdicts with the frame detector's and the world model's
(rank correlation and per-episode agreement) and its lineage, and the lines it prints."""

from __future__ import annotations

from pathlib import Path

from schemas.hashing import sha256_file, stable_id
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, MetricRecord
from tasks.policy.base import Policy
from tasks.policy.bc import BCPolicy
from tasks.policy.vision import VisionPolicy
from tasks.policy.evaluate import agreement, spearman

JUDGES = {"closed": "world model closed loop"}  # judges' names in printed lines, where the key says too little


def fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def checkpoint_record(policy: Policy, root: Path, by: str = "evaluate") -> ArtifactRecord | None:
    """A learned policy's checkpoint as the train-policy flow records it (a warehouse ignores
    it if already there); None for the scripted policy."""
    if not isinstance(policy, (BCPolicy, VisionPolicy)):
        return None
    kind = "bc" if isinstance(policy, BCPolicy) else "vision"
    checkpoint_id = policy.meta.get("checkpoint_id") or stable_id("checkpoint", kind, policy.meta["weights_sha256"])
    weights = Path(policy.source) / "model.safetensors"
    uri = weights.resolve().relative_to(root.resolve()).as_posix() if weights.resolve().is_relative_to(root.resolve()) \
        else str(weights)
    return ArtifactRecord(artifact_id=checkpoint_id, kind="checkpoint", uri=uri, sha256=policy.meta["weights_sha256"],
                          bytes=weights.stat().st_size, manifest_hash=policy.meta.get("manifest_hash"),
                          attrs={"model": f"{kind}-policy", "registered_by": by})


def evaluation_lineage(evaluation_id: str, result_file: Path, root: Path, body: dict, panel_id: str,
                       policy: Policy, stage_run_id: str, digest: str) -> LineageBatch:
    attrs = {"policy": policy.describe(), "panel_id": panel_id, "contract_hash": body["contract_hash"],
             "table": body["table"]}
    batch = LineageBatch(artifacts=[ArtifactRecord(
        artifact_id=evaluation_id, kind="evaluation", uri=result_file.relative_to(root).as_posix(),
        sha256=sha256_file(str(result_file)), bytes=result_file.stat().st_size, manifest_hash=digest,
        stage_run_id=stage_run_id, attrs=attrs)],
        edges=[EdgeRecord(parent_id=panel_id, child_id=evaluation_id, relation="evaluated_on")])
    checkpoint = checkpoint_record(policy, root)
    if checkpoint is not None:
        batch.artifacts.insert(0, checkpoint)
        batch.edges.append(EdgeRecord(parent_id=checkpoint.artifact_id, child_id=evaluation_id, relation="policy"))
    for row in body["table"]:
        suffix = "" if row["cell"] == "all" else f"/{row['cell']}"
        for column in ("sim", "detector", "world", "closed"):  # closed: only when closed loops were run
            if row.get(column) is not None:
                batch.metrics.append(MetricRecord(subject_id=evaluation_id, name=f"{column}_success_rate{suffix}",
                                                  value=row[column], stage_run_id=stage_run_id, manifest_hash=digest,
                                                  attrs={"cell": row["cell"], "episodes": row["episodes"]}))
    return batch


def comparison(results: list[tuple[str, str, str, list[dict]]], episodes: list[dict]) -> tuple[str, dict]:
    """(comparison id, body): rank correlation of the simulator's verdicts with the frame
    detector's and the world model's (open loop, and closed loop when it was run), across
    policies (overall rates) and across policy x cell rates, and their agreement episode by episode."""
    overall = [next(r for r in t if r["cell"] == "all") for *_, t in results]
    cells = [r for *_, t in results for r in t if r["cell"] != "all"]
    closed = ["closed"] if any("closed" in r for r in overall) else []
    corr = {f"sim_vs_{judge}{suffix}": spearman([r["sim"] for r in rows], [r.get(judge) for r in rows])
            for suffix, rows in (("", overall), ("_cells", cells)) for judge in ("world", "detector", *closed)}
    agree = {column: agreement(episodes, column) for column in ("detector", "world", *closed)}
    ids = sorted(e for _, _, e, _ in results)
    body = {"format": "worldline-evaluation-comparison/1", "evaluations": ids, "spearman": corr, "agreement": agree,
            "overall": [{"panel": p, "policy": n, **next(r for r in t if r["cell"] == "all")} for p, n, _, t in results]}
    return stable_id("evaluation_comparison", *ids), body


def comparison_lineage(comparison_id: str, target: Path, root: Path, body: dict, digest: str | None) -> LineageBatch:
    """One 'evaluation' artifact (role comparison) over the policy evaluations, and its metrics."""
    corr, agree = body["spearman"], body["agreement"]
    batch = LineageBatch(artifacts=[ArtifactRecord(
        artifact_id=comparison_id, kind="evaluation", uri=target.relative_to(root).as_posix(),
        sha256=sha256_file(str(target)), bytes=target.stat().st_size, manifest_hash=digest,
        attrs={"role": "comparison", "spearman": corr, "agreement": agree})],
        edges=[EdgeRecord(parent_id=e, child_id=comparison_id, relation="compared") for e in body["evaluations"]],
        metrics=[MetricRecord(subject_id=comparison_id, name=f"spearman_{k}", value=v, manifest_hash=digest)
                 for k, v in corr.items() if v is not None])
    batch.metrics += [MetricRecord(subject_id=comparison_id, name=f"agreement_{column}_{k}", value=v,
                                   manifest_hash=digest)
                      for column, a in agree.items() if a["decided"]
                      for k, v in (("decided", a["decided"] / a["episodes"]), ("rate", a["agree"] / a["decided"]),
                                   ("balanced", a["balanced"])) if v is not None]
    return batch


def agreement_line(name: str, a: dict) -> str:
    """One line: how a judge's verdicts match the simulator's, episode by episode."""
    if not a["decided"]:
        return f"{name}: no episode decided"
    balanced = "-" if a["balanced"] is None else f"{a['balanced']:.2f}"
    return (f"{name}: decided {a['decided']} of {a['episodes']}, agree on {a['agree']}; on the simulator's "
            f"successes {a['successes_agree']}/{a['successes']}, on its failures {a['failures_agree']}/{a['failures']} "
            f"(balanced {balanced})")

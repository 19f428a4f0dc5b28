"""The loop's pure half: the worst stressor cells of an evaluation, how many new episodes each
gets, the manifests derived from them, fine-tuning a behaviour-cloning policy, and the derived
manifests' lineage and the loop's summary text.

No Prefect here: `flows/loop.py` wires these into the DAG."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from schemas.manifest import ScenarioManifest
from schemas.panel import StressorCell, StressorGrid
from schemas.records import EdgeRecord, LineageBatch, MetricRecord
from tasks import manifests
from tasks.panels.grid import variant_manifest
from tasks.policy.bc import Demonstrations
from tasks.tables import markdown_table

# New data must not replay the panel's seeds (seed, seed+1, ...), the demonstrations of
# train-policy (seed+1000..) or its held-out check (seed+2000..).
SEED_OFFSET = 3000
CONTROL_SEED_OFFSET = 4000  # the untargeted control's new episodes: seeds no other arm uses
RELATION_CONTROL = "untargeted_control"
RELATION_DERIVED = "derived_from_failure"
RELATION_POSTTRAINED = "posttrained_from"


def worst_cells(table: Sequence[dict], worst: int = 1, column: str = "sim") -> list[tuple[str, float]]:
    """The ``worst`` cells with the lowest ``column`` success rate, as (cell, rate); ties keep
    the table's (the grid's) order. Cells without a rate and the 'all' row are skipped."""
    rated = [(r["cell"], float(r[column])) for r in table if r["cell"] != "all" and r.get(column) is not None]
    return sorted(rated, key=lambda pair: pair[1])[:max(0, worst)]  # sorted is stable


def episode_counts(success: Sequence[float], total: int) -> list[int]:
    """``total`` new episodes shared in proportion to each cell's failure rate (1 - success),
    each cell at least 1 (so the sum is max(total, len(success))). Largest remainders get
    the leftovers; all-successful cells share equally."""
    n = len(success)
    if n == 0:
        return []
    failure = [max(0.0, 1.0 - s) for s in success]
    if sum(failure) == 0:
        failure = [1.0] * n
    spare = max(0, total - n)
    shares = [spare * f / sum(failure) for f in failure]
    counts = [1 + int(s) for s in shares]
    order = sorted(range(n), key=lambda i: (-(shares[i] - int(shares[i])), i))
    for i in order[:spare - sum(int(s) for s in shares)]:
        counts[i] += 1
    return counts


def derive_manifests(parent: ScenarioManifest, grid: StressorGrid, cells: Sequence[str],
                     seed_offset: int = SEED_OFFSET) -> list[ScenarioManifest]:
    """One manifest per cell: the parent with the cell's stressors (as its panel variant) on
    fresh seeds (parent.seed + seed_offset ..), ``parent`` set to the parent's hash. The
    contract is unchanged, so a policy post-trained on them still fits the panel."""
    by_name = {c.name: c for c in grid.cells}
    loop_grid = StressorGrid.model_validate({**grid.model_dump(mode="json"), "name": "loop",
                                             "seed": parent.seed + seed_offset,
                                             "description": f"failure cells of {grid.name}"})
    return [variant_manifest(parent, loop_grid, by_name[name]) for name in cells]


def merge(parts: Sequence[Demonstrations]) -> Demonstrations:
    """Demonstrations of several manifests as one set (episode indices renumbered)."""
    offsets = np.cumsum([0, *(len(p.seeds) for p in parts)])
    return Demonstrations(obs=np.concatenate([p.obs for p in parts]), act=np.concatenate([p.act for p in parts]),
                          episode=np.concatenate([p.episode + o for p, o in zip(parts, offsets)]),
                          seeds=tuple(s for p in parts for s in p.seeds),
                          successes=tuple(s for p in parts for s in p.successes))


def control_manifest(parent: ScenarioManifest, grid: StressorGrid) -> ScenarioManifest:
    """The untargeted control's manifest: the parent as it is (the nominal cell), on fresh
    seeds (parent.seed + CONTROL_SEED_OFFSET ..), so it spends the same budget of new
    demonstrations without looking at where the policy failed."""
    nominal = StressorCell(name="nominal")
    control_grid = StressorGrid.model_validate({**grid.model_dump(mode="json"), "name": "control",
                                                "cells": [nominal.model_dump(mode="json")],
                                                "seed": parent.seed + CONTROL_SEED_OFFSET,
                                                "description": f"untargeted control for {grid.name}"})
    return variant_manifest(parent, control_grid, nominal)


def before_after(before: Sequence[dict], after: Sequence[dict], targeted: Sequence[str],
                 control: Sequence[dict] | None = None) -> list[dict]:
    """Rows of two evaluations' tables on the same panel: cell, episodes, simulator success
    before and after, whether the loop made new data for the cell, and with ``control`` the
    untargeted control's success after ("untargeted")."""
    rates = {r["cell"]: r["sim"] for r in after}
    other = {r["cell"]: r["sim"] for r in control or []}
    return [{"cell": r["cell"], "episodes": r["episodes"], "before": r["sim"], "after": rates.get(r["cell"]),
             "targeted": r["cell"] in targeted, **({"untargeted": other.get(r["cell"])} if control else {})}
            for r in before]


def derived_lineage(parent_hash: str, derived: Sequence[ScenarioManifest], files: Sequence[Path],
                    picked: Sequence[tuple[str, float]], counts: Sequence[int],
                    evaluation_id: str | None = None) -> LineageBatch:
    """Each derived manifest, 'derived_from_failure' edges from the parent and from the
    evaluation whose failed cells it came from (so `audit failure` on that evaluation finds
    it, and what was made from it), and the success rate of the cell it came from."""
    batch = LineageBatch()
    for m, path, (cell, rate), n in zip(derived, files, picked, counts):
        batch.extend(manifests.lineage(m, str(path)))
        batch.edges.append(EdgeRecord(parent_id=parent_hash, child_id=m.sha256, relation=RELATION_DERIVED))
        if evaluation_id is not None:
            batch.edges.append(EdgeRecord(parent_id=evaluation_id, child_id=m.sha256, relation=RELATION_DERIVED))
        batch.metrics.append(MetricRecord(subject_id=m.sha256, name="loop_source_success_rate", value=rate,
                                          manifest_hash=parent_hash, attrs={"cell": cell, "new_episodes": n}))
    return batch


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def summary_text(table: list[dict], derived: Sequence[ScenarioManifest], counts: Sequence[int],
                 picked: Sequence[tuple[str, float]]) -> tuple[str, str]:
    """(table of success per cell before and after, list of the derived manifests) in markdown."""
    if table and "untargeted" in table[0]:
        text = markdown_table(("cell", "episodes", "before", "after (targeted)", "after (untargeted control)", "targeted"),
                              [(r["cell"], r["episodes"], _fmt(r["before"]), _fmt(r["after"]), _fmt(r["untargeted"]),
                                "yes" if r["targeted"] else "") for r in table])
    else:
        text = markdown_table(("cell", "episodes", "before", "after", "targeted"),
                              [(r["cell"], r["episodes"], _fmt(r["before"]), _fmt(r["after"]),
                                "yes" if r["targeted"] else "") for r in table])
    made = "\n".join(f"- {m.name} ({m.sha256[:12]}): {n} new episodes, from cell {cell} at {_fmt(rate)}"
                     for m, n, (cell, rate) in zip(derived, counts, picked))
    return text, made

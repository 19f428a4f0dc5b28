"""The questions the report page (tasks/report) asks of lineage, each a named function: no SQL
outside warehouse/. Each returns rows (or ``(columns, rows)`` where the page shows the table
as it comes)."""

from __future__ import annotations

from collections.abc import Sequence

from warehouse.store import Warehouse

Table = tuple[list[str], list[tuple]]


# -- finding what the user named --------------------------------------------------------------
def runs_starting(warehouse: Warehouse, prefix: str, limit: int = 2) -> list[str]:
    """At most ``limit`` run ids that start with ``prefix``, in id order."""
    _, rows = warehouse.query("SELECT run_id FROM runs WHERE starts_with(run_id, $p) ORDER BY 1 LIMIT $n",
                              {"p": prefix, "n": limit})
    return [r[0] for r in rows]


def artifacts_starting(warehouse: Warehouse, prefix: str, limit: int = 2) -> list[str]:
    """At most ``limit`` artifact ids that start with ``prefix``, in id order."""
    _, rows = warehouse.query("SELECT artifact_id FROM artifacts WHERE starts_with(artifact_id, $p) ORDER BY 1 "
                              "LIMIT $n", {"p": prefix, "n": limit})
    return [r[0] for r in rows]


def closest_ids(warehouse: Warehouse, given: str, n: int, cutoff: float = 0.5) -> list[tuple[str, str]]:
    """(id, what) of the ``n`` runs ("run <flow>") and artifacts (their kind) whose ids are most
    like ``given``, best first: the Jaro-Winkler similarity of ``given`` and the id's first
    ``len(given)`` characters (a mistyped id or prefix), or 1 for an id that contains ``given``
    (a piece of one); at least ``cutoff``. A million ids take DuckDB about a second (0.4-1.7 s here)."""
    _, rows = warehouse.query(
        "SELECT id, what FROM (SELECT id, what, greatest(jaro_winkler_similarity(left(id, length($g)), $g), "
        "CASE WHEN contains(id, $g) THEN 1.0 ELSE 0.0 END) AS score FROM (SELECT run_id AS id, 'run ' || flow AS what "
        "FROM runs UNION ALL SELECT artifact_id, kind FROM artifacts)) WHERE score >= $c "
        "ORDER BY score DESC, id LIMIT $n", {"g": given, "c": cutoff, "n": n})
    return rows


# -- a run ------------------------------------------------------------------------------------
def run_table(warehouse: Warehouse, run_id: str) -> Table:
    """The run's row."""
    return warehouse.query("SELECT run_id, flow, status, manifest_hash, prefect_flow_run_id, started_at, ended_at, "
                           "ended_at - started_at AS took, message, params FROM runs WHERE run_id = $r", {"r": run_id})


def stage_runs_table(warehouse: Warehouse, run_id: str) -> Table:
    """The run's stage runs, in the order they were recorded."""
    return warehouse.query("SELECT stage, status, n_in, n_out, round(seconds, 3) AS seconds, input_key, stage_run_id, "
                           "attrs FROM stage_runs WHERE run_id = $r ORDER BY recorded_at, stage, stage_run_id",
                           {"r": run_id})


def stage_totals(warehouse: Warehouse, run_id: str) -> list[tuple[str, int, int, int, float]]:
    """(stage, stage runs, inputs, outputs, seconds) of the run, per stage in first-run order."""
    _, rows = warehouse.query("SELECT stage, count(*), sum(n_in)::BIGINT, sum(n_out)::BIGINT, sum(seconds) "
                              "FROM stage_runs WHERE run_id = $r GROUP BY stage ORDER BY min(recorded_at), stage",
                              {"r": run_id})
    return rows


def run_artifacts_table(warehouse: Warehouse, run_id: str, limit: int) -> Table:
    """The artifacts the run's stage runs produced (at most ``limit``), kind by kind."""
    return warehouse.query("SELECT a.kind, a.artifact_id, a.uri, a.bytes, a.sha256, s.stage FROM artifacts a "
                           "JOIN stage_runs s USING (stage_run_id) WHERE s.run_id = $r "
                           "ORDER BY a.kind, a.uri NULLS LAST, a.artifact_id LIMIT $n", {"r": run_id, "n": limit})


def run_artifact_counts(warehouse: Warehouse, run_id: str) -> Table:
    """Artifacts the run produced per kind: how many, how many have a file, their bytes."""
    return warehouse.query("SELECT a.kind, count(*) AS n, count(a.uri) AS files, sum(a.bytes)::BIGINT AS bytes "
                           "FROM artifacts a JOIN stage_runs s USING (stage_run_id) WHERE s.run_id = $r "
                           "GROUP BY a.kind ORDER BY a.kind", {"r": run_id})


def run_rejection_counts(warehouse: Warehouse, run_id: str) -> Table:
    """Rejections by the run's stage runs per stage and reason."""
    return warehouse.query("SELECT j.stage, j.reason, count(*) AS n FROM rejections j JOIN stage_runs s "
                           "USING (stage_run_id) WHERE s.run_id = $r GROUP BY ALL ORDER BY n DESC, j.stage, j.reason",
                           {"r": run_id})


def run_metric_summary(warehouse: Warehouse, run_id: str) -> Table:
    """Per metric name measured by the run's stage runs: how many values, min, mean, max."""
    return warehouse.query("SELECT m.name, count(*) AS n, min(m.value) AS min, avg(m.value) AS mean, max(m.value) AS max "
                           "FROM metrics m JOIN stage_runs s USING (stage_run_id) WHERE s.run_id = $r "
                           "GROUP BY m.name ORDER BY m.name", {"r": run_id})


def run_metrics(warehouse: Warehouse, run_id: str, per_name: int) -> list[tuple[str, int, float, str]]:
    """(name, step, value, subject id) of the metrics measured by the run's stage runs, at most
    ``per_name`` of each name (the first steps, then subjects in id order), by name and step."""
    _, rows = warehouse.query("SELECT m.name, m.step, m.value, m.subject_id FROM metrics m JOIN stage_runs s "
                              "USING (stage_run_id) WHERE s.run_id = $r QUALIFY row_number() OVER "
                              "(PARTITION BY m.name ORDER BY m.step, m.subject_id) <= $n "
                              "ORDER BY m.name, m.step, m.subject_id", {"r": run_id, "n": per_name})
    return rows


def run_videos(warehouse: Warehouse, run_id: str, kinds: Sequence[str], limit: int) -> list[tuple[str, str, str]]:
    """(artifact id, kind, uri) of at most ``limit`` MP4s of these kinds the run wrote."""
    _, rows = warehouse.query("SELECT a.artifact_id, a.kind, a.uri FROM artifacts a JOIN stage_runs s "
                              "USING (stage_run_id) WHERE s.run_id = $r AND list_contains($k, a.kind) "
                              "AND lower(a.uri) LIKE '%.mp4' ORDER BY a.kind, a.uri LIMIT $n",
                              {"r": run_id, "k": list(kinds), "n": limit})
    return rows


def run_images(warehouse: Warehouse, run_id: str, limit: int) -> list[tuple[str, str, str]]:
    """(artifact id, kind, uri) of at most ``limit`` PNG files the run wrote (plots, contact sheets)."""
    _, rows = warehouse.query("SELECT a.artifact_id, a.kind, a.uri FROM artifacts a JOIN stage_runs s "
                              "USING (stage_run_id) WHERE s.run_id = $r AND lower(a.uri) LIKE '%.png' "
                              "ORDER BY a.kind, a.uri LIMIT $n", {"r": run_id, "n": limit})
    return rows


# -- an artifact and its lineage --------------------------------------------------------------
def artifact_table(warehouse: Warehouse, artifact_id: str) -> Table:
    """The artifact's row, with the run and stage that produced it."""
    return warehouse.query("SELECT a.artifact_id, a.kind, a.uri, a.bytes, a.sha256, a.manifest_hash, s.stage, "
                           "s.run_id, a.recorded_at, a.attrs FROM artifacts a LEFT JOIN stage_runs s "
                           "USING (stage_run_id) WHERE a.artifact_id = $a", {"a": artifact_id})


def run_of_artifact(warehouse: Warehouse, artifact_id: str) -> str | None:
    """The run whose stage run produced the artifact, or None."""
    _, rows = warehouse.query("SELECT s.run_id FROM artifacts a JOIN stage_runs s USING (stage_run_id) "
                              "WHERE a.artifact_id = $a", {"a": artifact_id})
    return rows[0][0] if rows else None


def artifact_metrics(warehouse: Warehouse, artifact_id: str) -> Table:
    """Every metric measured of the artifact."""
    return warehouse.query("SELECT name, step, value FROM metrics WHERE subject_id = $a ORDER BY name, step",
                           {"a": artifact_id})


def artifact_rejections(warehouse: Warehouse, artifact_id: str) -> Table:
    """Why stages rejected the artifact, if they did."""
    return warehouse.query("SELECT stage, reason, detail, scores FROM rejections WHERE artifact_id = $a "
                           "ORDER BY stage", {"a": artifact_id})


def ancestors(warehouse: Warehouse, artifact_ids: Sequence[str], limit: int) -> list[tuple[str, int, str, str]]:
    """(ancestor id, depth, kind, uri) of at most ``limit`` ancestors of any of these artifacts
    (the nearest first), from the closure the writer keeps."""
    _, rows = warehouse.query("SELECT c.ancestor_id, min(c.depth) AS depth, any_value(coalesce(a.kind, c.ancestor_kind)), "
                              "any_value(coalesce(a.uri, c.ancestor_uri)) FROM ancestry c LEFT JOIN artifacts a "
                              "ON a.artifact_id = c.ancestor_id WHERE list_contains($ids, c.descendant_id) "
                              "AND NOT list_contains($ids, c.ancestor_id) GROUP BY c.ancestor_id "
                              "ORDER BY depth, c.ancestor_id LIMIT $n", {"ids": list(artifact_ids), "n": limit})
    return rows


def descendants(warehouse: Warehouse, artifact_id: str, limit: int) -> list[tuple[str, int, str, str]]:
    """(descendant id, depth, kind, uri) of at most ``limit`` artifacts made from this one,
    directly or not (the nearest first)."""
    _, rows = warehouse.query("SELECT c.descendant_id, c.depth, a.kind, a.uri FROM ancestry c JOIN artifacts a "
                              "ON a.artifact_id = c.descendant_id WHERE c.ancestor_id = $a "
                              "ORDER BY c.depth, c.descendant_id LIMIT $n", {"a": artifact_id, "n": limit})
    return rows


def count_descendants(warehouse: Warehouse, artifact_id: str) -> int:
    _, rows = warehouse.query("SELECT count(*) FROM ancestry WHERE ancestor_id = $a", {"a": artifact_id})
    return rows[0][0]


def count_ancestors(warehouse: Warehouse, artifact_ids: Sequence[str]) -> int:
    _, rows = warehouse.query("SELECT count(DISTINCT ancestor_id) FROM ancestry WHERE list_contains($ids, descendant_id) "
                              "AND NOT list_contains($ids, ancestor_id)", {"ids": list(artifact_ids)})
    return rows[0][0]


def edges_among(warehouse: Warehouse, artifact_ids: Sequence[str]) -> list[tuple[str, str, str]]:
    """(parent id, child id, relation) of every lineage edge between two of these artifacts."""
    _, rows = warehouse.query("SELECT parent_id, child_id, relation FROM edges WHERE list_contains($ids, parent_id) "
                              "AND list_contains($ids, child_id) ORDER BY parent_id, child_id, relation",
                              {"ids": list(artifact_ids)})
    return rows


def kinds_of(warehouse: Warehouse, artifact_ids: Sequence[str]) -> dict[str, tuple[str, str | None]]:
    """artifact id -> (kind, uri) of those of these ids that are artifacts."""
    _, rows = warehouse.query("SELECT artifact_id, kind, uri FROM artifacts WHERE list_contains($ids, artifact_id)",
                              {"ids": list(artifact_ids)})
    return {a: (k, u) for a, k, u in rows}

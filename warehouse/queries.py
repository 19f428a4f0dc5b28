"""The lineage questions the flows and the CLI ask, each a named function: no SQL outside
warehouse/. Conditions on a checkpoint's attrs (``POSTTRAINED_WORLD_MODEL``, ``BC_POLICY``, ``VISION_POLICY``,
``TRANSFER_MODEL``,
`tokenizer_condition`) are passed to the checkpoint queries by name."""

from __future__ import annotations

from collections.abc import Sequence

from warehouse.store import Warehouse

# Either family: a diffusion world model's checkpoint is a world_model too, with attrs family = 'diffusion'.
POSTTRAINED_WORLD_MODEL = "attrs->>'model' = 'world_model' AND attrs->>'phase' = 'posttrain'"
BC_POLICY = "attrs->>'model' = 'bc-policy'"
VISION_POLICY = "attrs->>'model' = 'vision-policy'"
# Artifacts of kind transfer_model: any, and those train-transfer trained (one recorded by hand has no preset).
TRANSFER_MODEL = "attrs->>'model' = 'transfer'"
TRAINED_TRANSFER_MODEL = TRANSFER_MODEL + " AND attrs->>'preset' IS NOT NULL"


def tokenizer_condition(variant: str | None) -> str:
    """Tokenizer checkpoints of ``variant`` ("discrete", "continuous"), or of any when None."""
    return "attrs->>'preset' IS NOT NULL" if variant is None else f"attrs->>'variant' = '{variant}'"


def checkpoints_by_prefix(warehouse: Warehouse, condition: str, prefix: str, kind: str = "checkpoint") -> list[tuple]:
    """(artifact id, uri, sha256) of at most two checkpoints (artifacts of ``kind``) matching
    ``condition`` whose id starts with ``prefix``."""
    _, rows = warehouse.query(f"SELECT artifact_id, uri, sha256 FROM artifacts WHERE kind = $kind AND {condition} "
                              "AND artifact_id LIKE $prefix || '%' ORDER BY artifact_id LIMIT 2",
                              {"prefix": prefix, "kind": kind})
    return rows


def newest_checkpoint_uri(warehouse: Warehouse, condition: str, kind: str = "checkpoint") -> str | None:
    """The weights uri of the newest checkpoint (artifact of ``kind``) matching ``condition``, or None."""
    _, rows = warehouse.query("SELECT uri FROM artifacts WHERE kind = $kind AND "
                              f"{condition} ORDER BY recorded_at DESC, artifact_id LIMIT 1", {"kind": kind})
    return rows[0][0] if rows else None


def newest_encoding_checkpoint(warehouse: Warehouse, condition: str) -> str | None:
    """The id of the newest checkpoint matching ``condition`` that encoded something (a tokenizer
    with token shards), or None."""
    _, rows = warehouse.query(f"SELECT artifact_id FROM artifacts WHERE kind = 'checkpoint' AND {condition} AND "
                              "artifact_id IN (SELECT parent_id FROM edges WHERE relation = 'encoded_by') "
                              "ORDER BY recorded_at DESC, artifact_id LIMIT 1")
    return rows[0][0] if rows else None


def manifest_body(warehouse: Warehouse, manifest_hash: str) -> str | None:
    """The canonical JSON body lineage keeps of a manifest, or None."""
    _, rows = warehouse.query("SELECT body FROM manifests WHERE manifest_hash = $mh", {"mh": manifest_hash})
    return rows[0][0] if rows else None


def knows(warehouse: Warehouse, key: str, value: str) -> bool:
    """Whether lineage holds ``value`` as a manifest (``key`` 'manifest': registered, or named by
    a run or an artifact) or as an artifact ('artifact': recorded, or the child of an edge)."""
    sql = {"manifest": "SELECT 1 FROM manifests WHERE manifest_hash = $v UNION ALL SELECT 1 FROM runs "
                       "WHERE manifest_hash = $v UNION ALL SELECT 1 FROM artifacts WHERE manifest_hash = $v LIMIT 1",
           "artifact": "SELECT 1 FROM artifacts WHERE artifact_id = $v UNION ALL "
                       "SELECT 1 FROM edges WHERE child_id = $v LIMIT 1"}[key]
    return bool(warehouse.query(sql, {"v": value})[1])


def episode_ids(warehouse: Warehouse, manifest_hashes: Sequence[str]) -> list[str]:
    """The episode artifacts of these manifests, in id order."""
    _, rows = warehouse.query("SELECT artifact_id FROM artifacts WHERE kind = 'episode' AND list_contains($d, "
                              "manifest_hash) ORDER BY artifact_id", {"d": list(manifest_hashes)})
    return [r[0] for r in rows]


def ids_starting(warehouse: Warehouse, table: str, column: str, prefix: str) -> list[str]:
    """At most two distinct values of ``table.column`` that start with ``prefix``."""
    _, rows = warehouse.query(f"SELECT DISTINCT {column} FROM {table} WHERE {column} LIKE $p || '%' "
                              f"ORDER BY 1 LIMIT 2", {"p": prefix})
    return [r[0] for r in rows]


def runs_by_flow(warehouse: Warehouse) -> tuple[list[str], list[tuple]]:
    """(columns, rows): runs per flow and status, and when the last one ended."""
    return warehouse.query(
        "SELECT flow, status, count(*) AS runs, max(ended_at) AS last_ended FROM runs GROUP BY ALL ORDER BY flow")


def artifacts_by_kind(warehouse: Warehouse) -> tuple[list[str], list[tuple]]:
    """(columns, rows): artifacts and their bytes per kind."""
    return warehouse.query("SELECT kind, count(*) AS n, sum(bytes) AS bytes FROM artifacts GROUP BY kind ORDER BY kind")

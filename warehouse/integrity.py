"""What lineage claims about files: the rows a consumer checks a file against, and the rows
`worldline verify` audits. Rows come back as plain tuples in ``COLUMNS`` order; the checks
themselves live in tasks/integrity.py.

Manifest artifacts are left out: their uri is the YAML a manifest was read from and their
sha256 is the hash of its meaning, whose whole canonical body the manifests table keeps, so
lineage never reads that YAML again (an edited YAML is a new manifest, not a changed artifact).
"""

from __future__ import annotations

from collections.abc import Sequence

from warehouse.store import Warehouse

COLUMNS = ("artifact_id", "kind", "uri", "sha256", "manifest_hash")
_FILES = "uri IS NOT NULL AND sha256 IS NOT NULL AND kind <> 'manifest'"
_SELECT = f"SELECT {', '.join(COLUMNS)} FROM artifacts"


def claims(warehouse: Warehouse, uri: str, sha256: str, kind: str) -> list[tuple]:
    """Rows naming ``uri``, and rows of ``kind`` with bytes ``sha256`` (a copy elsewhere),
    newest first."""
    _, rows = warehouse.query(f"{_SELECT} WHERE {_FILES} AND (uri = $uri OR (kind = $kind AND sha256 = $sha)) "
                              "ORDER BY recorded_at DESC, artifact_id", {"uri": uri, "kind": kind, "sha": sha256})
    return rows


def recorded_uris(warehouse: Warehouse, uris: Sequence[str]) -> set[str]:
    """Which of ``uris`` some artifact row names."""
    if not uris:
        return set()
    _, rows = warehouse.query("SELECT DISTINCT uri FROM artifacts WHERE list_contains($uris, uri)", {"uris": list(uris)})
    return {r[0] for r in rows}


def recorded(warehouse: Warehouse, artifact_ids: Sequence[str]) -> dict[str, tuple]:
    """The row of each of ``artifact_ids`` that lineage holds with a uri and a sha256."""
    if not artifact_ids:
        return {}
    _, rows = warehouse.query(f"{_SELECT} WHERE {_FILES} AND list_contains($ids, artifact_id)",
                              {"ids": list(artifact_ids)})
    return {r[0]: r for r in rows}


def parents(warehouse: Warehouse, child_ids: Sequence[str], relation: str) -> list[tuple]:
    """The file rows of the ``relation`` parents of ``child_ids`` (e.g. the curated shards
    token shards were encoded from, ``tokens_of``)."""
    if not child_ids:
        return []
    _, rows = warehouse.query(
        f"{_SELECT} WHERE {_FILES} AND artifact_id IN (SELECT parent_id FROM edges WHERE relation = $relation "
        "AND list_contains($ids, child_id)) ORDER BY uri, artifact_id", {"relation": relation, "ids": list(child_ids)})
    return rows


def children(warehouse: Warehouse, parent_ids: Sequence[str], relation: str) -> set[str]:
    """The ids of the ``relation`` children of ``parent_ids`` (e.g. the videos an episode rendered)."""
    if not parent_ids:
        return set()
    _, rows = warehouse.query("SELECT DISTINCT child_id FROM edges WHERE relation = $relation AND "
                              "list_contains($ids, parent_id)", {"relation": relation, "ids": list(parent_ids)})
    return {r[0] for r in rows}


def files(warehouse: Warehouse, manifest_hash: str | None = None) -> list[tuple]:
    """Every artifact lineage recorded as a file, or with ``manifest_hash`` every row naming a
    path one of that manifest's artifacts names (so two rows claiming its file both show)."""
    if manifest_hash is None:
        _, rows = warehouse.query(f"{_SELECT} WHERE {_FILES} ORDER BY uri, artifact_id")
    else:
        _, rows = warehouse.query(f"{_SELECT} WHERE {_FILES} AND uri IN (SELECT uri FROM artifacts WHERE {_FILES} "
                                  "AND manifest_hash = $mh) ORDER BY uri, artifact_id", {"mh": manifest_hash})
    return rows


def clip_tags(warehouse: Warehouse, clip_ids: Sequence[str]) -> dict[str, tuple[str, ...]]:
    """The tags lineage recorded with each clip file (e.g. ``guard:faces_hidden``, which only
    the encode that hid the faces knows): a clip file reused by a re-run keeps them."""
    if not clip_ids:
        return {}
    _, rows = warehouse.query("SELECT artifact_id, CAST(attrs->'tags' AS VARCHAR[]) FROM artifacts "
                              "WHERE kind = 'clip' AND list_contains($ids, artifact_id)", {"ids": list(clip_ids)})
    return {r[0]: tuple(r[1] or ()) for r in rows}

"""Changes to recorded rows that follow a change of on-disk layout (the files move, the rows follow).

Issue 26: shards became named by their content (``schemas.paths.SHARD_FILE``). When curate
renames an old ``part-NNNNN.parquet`` file, ``rename_shard`` moves its rows to the new name.
"""

from __future__ import annotations

from warehouse.store import Warehouse


def rename_shard(warehouse: Warehouse, uri: str, new_uri: str, sha256: str) -> int:
    """Point the shard rows of file ``uri`` whose bytes were ``sha256`` at ``new_uri``, in
    artifacts and in the ancestor columns ancestry copied from them; returns how many shard rows
    name ``new_uri`` with that sha256 afterwards (0: no row knew these bytes).

    A row of ``uri`` with another sha256 is left alone: it describes bytes that file no longer
    holds (overwritten by a later run before issue 26). Run twice, the second call changes
    nothing and counts the same rows, so a run killed between this and the rename can redo both.
    """
    move = {"old": uri, "new": new_uri, "sha": sha256}
    with warehouse.transaction() as con:
        con.execute("UPDATE ancestry SET ancestor_uri = $new WHERE ancestor_uri = $old AND ancestor_sha256 = $sha "
                    "AND ancestor_kind = 'shard'", move)
        con.execute("UPDATE artifacts SET uri = $new WHERE kind = 'shard' AND uri = $old AND sha256 = $sha", move)
        (count,), = con.execute("SELECT count(*) FROM artifacts WHERE kind = 'shard' AND uri = $new AND sha256 = $sha",
                                {"new": new_uri, "sha": sha256}).fetchall()
    return int(count)

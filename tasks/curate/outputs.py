"""The curate flow's files on disk against lineage: clips encoded before (reused when their
bytes are the ones lineage recorded), clips encoded again to replace changed ones, exact
signatures kept in the analysis caches, and old-layout shards renamed by content."""

from __future__ import annotations

from pathlib import Path

from schemas import paths
from schemas.hashing import sha256_file
from schemas.records import ClipRecord
from tasks import integrity
from tasks.curate import analyse, dedup, shards
from tasks.curate.config import CurateConfig
from warehouse import integrity as claims
from warehouse import migrate
from warehouse.store import Warehouse


def reused(warehouse: Warehouse, group: list[ClipRecord], targets: list[Path], root: Path) -> list[ClipRecord] | None:
    """The clips of a source encoded before, each file hashed once and checked against the
    sha256 lineage recorded for it; None when one differs (or lineage has none), so the source
    is encoded again: its bytes are intact (the clip ids hash them), and with a fixed thread
    count x264 writes the same clips, so encoding again restores what lineage recorded."""
    recorded = claims.recorded(warehouse, [c.clip_id for c in group])
    tags = claims.clip_tags(warehouse, [c.clip_id for c in group])
    out = []
    for clip, target in zip(group, targets):
        digest = integrity.file_sha256(target)
        row = recorded.get(clip.clip_id)
        if row is None or integrity.Recorded(*row).sha256 != digest:
            want = f"lineage's {row[3][:12]}" if row is not None else "no sha256 in lineage"
            print(paths.escaped(f"{target}: sha256 {digest[:12]} differs from {want}; encoding {clip.source_uri} again"))
            return None
        # The guard's tag belongs to the file: the encode that hid the faces recorded it.
        kept = tuple(dict.fromkeys((*clip.tags, *(t for t in tags.get(clip.clip_id, ()) if t.startswith("guard:")))))
        out.append(with_file(clip.model_copy(update={"tags": kept}), target, root, sha256=digest))
    return out


def differs(warehouse: Warehouse, encoded: list[ClipRecord], targets: list[Path]) -> str | None:
    """Why clips encoded again to replace changed files still differ from lineage, or None."""
    recorded = claims.recorded(warehouse, [c.clip_id for c in encoded])
    for clip, target in zip(encoded, targets):
        if (row := recorded.get(clip.clip_id)) is not None and row[3] != clip.sha256:
            return (f"{target}: changed since lineage recorded it, and encoding it again gave sha256 "
                    f"{clip.sha256[:12]}, not lineage's {row[3][:12]}; its source's clips are left out of the shards")
    return None


def with_file(clip: ClipRecord, target: Path, root: Path, faces=(), sha256: str | None = None) -> ClipRecord:
    """The clip with its file's uri, size and sha256 (``sha256`` when the caller hashed it already)."""
    tags = (*clip.tags, "guard:faces_hidden") if faces else clip.tags
    return clip.model_copy(update={"uri": str(target.relative_to(root)), "sha256": sha256 or sha256_file(str(target)),
                                   "bytes": target.stat().st_size, "tags": tags})


def keep_exact(root: Path, analyses: list[analyse.VideoAnalysis], exact: dict[str, dedup.ClipSignature],
               config: CurateConfig) -> None:
    """Signatures dedup had decoded exactly go into their analyses' caches: a re-run decodes nothing."""
    for a in analyses:
        if mine := {cid: s for cid, s in exact.items() if cid in a.signatures}:
            a.signatures.update(mine)
            analyse.save(a, paths.resolve(root, paths.ANALYSIS_FILE, sha256=a.sha256,
                                          config_hash=config.analysis_hash()))


def rename_legacy_shards(warehouse: Warehouse, root: Path) -> None:
    """Old-layout shards (``part-NNNNN.parquet``, which a later run into the bucket overwrote:
    issue 26) move to their names by content, their rows first; nothing is deleted."""
    for old in shards.legacy_shards(root):
        known = migrate.rename_shard(warehouse, old.uri, old.new_uri, old.sha256)
        shards.rename_legacy(root, old)
        print(f"renamed shard {old.uri} to {old.new_uri}"
              + ("" if known else " (no lineage row has its bytes: a shard no run recorded, or one whose row was lost)"))

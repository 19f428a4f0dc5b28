"""What the tokenize flow reads: curated shards (a folder, a file or a manifest hash), each
checked against lineage, and the tokenizer checkpoint a training continues from."""

from __future__ import annotations

from pathlib import Path

from models.tokenizer import preset
from schemas import paths
from tasks import integrity
from tasks.lookup import verified_file
from tasks.tokenize import data, tokens
from tasks.world.inputs import tokenizer_folder
from warehouse.store import Warehouse


def shard_files(shards: str, root: Path) -> list[Path]:
    """A folder or file of shards, or a manifest hash (its first 12+ hex digits) naming its shard folder."""
    place = Path(shards)
    if not place.exists() and len(shards) >= 12 and all(ch in "0123456789abcdef" for ch in shards):
        place = paths.resolve(root, paths.SHARDS_OF_MANIFEST, manifest_hash=shards)
    found = data.find_shards([place])
    if not found:
        raise FileNotFoundError(f"{shards}: no shard files there (give a shard folder or a manifest hash)")
    return found


def shard_artifacts(warehouse: Warehouse, root: Path, files: list[Path]) -> list[tuple[Path, str, str, str | None]]:
    """(path, uri, artifact id, manifest hash) per shard, each hashed once and checked against
    lineage: a changed shard raises TamperedArtifact, one curate never wrote InvalidInput
    (registering it would start a lineage with no clips or raw videos behind it)."""
    root = root.resolve()
    out = []
    for path in files:
        shard_id, mh, _ = verified_file(warehouse, root, path, "shard", "curated shard",
                                        "tokenize reads shards `worldline curate` wrote")
        out.append((path, integrity.uri_of(path, root), shard_id, mh))
    return out


def init_checkpoint(warehouse: Warehouse, root: Path, init: str, preset_name: str) -> tuple[Path, str]:
    """(folder, artifact id) of the tokenizer checkpoint to continue from (a folder or an id in
    lineage, as `worldline train --tokenizer` takes them); it must hold the same preset."""
    folder, checkpoint_id = tokenizer_folder(warehouse, root, init, variant=None)
    found = tokens.load_checkpoint(folder).config
    if found != preset(preset_name):
        raise ValueError(f"--init {folder}: holds tokenizer {found.name!r}, not preset {preset_name!r} "
                         "(continue training with the same preset)")
    return folder, checkpoint_id

"""What the train flow reads, each file checked against lineage before it is read: the
tokenizer checkpoint, its token shards (and the curated shards behind them), and the
simulated episodes (with the text of their manifests)."""

from __future__ import annotations

import json
from pathlib import Path

from models.tokenizer import TokenizerConfig
from schemas import paths
from schemas.errors import StepMissing
from tasks import integrity, manifests
from tasks.checkpoint_files import CheckpointError
from tasks.lookup import checkpoint_by_id, is_hex_id, verified_file
from tasks.tokenize import tokens
from tasks.world import data
from warehouse import integrity as claims
from warehouse import queries
from warehouse.store import Warehouse


def uri(path: Path, root: Path) -> str:
    return path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)


def known(warehouse: Warehouse, kind: str, path: Path, root: Path, what: str, hint: str) -> tuple[str, str | None]:
    """(artifact id, manifest hash) of an input file, hashed once and checked against lineage:
    TamperedArtifact when its bytes changed, InvalidInput (``hint``) when lineage never saw it."""
    artifact_id, mh, _ = verified_file(warehouse, root, path, kind, what, hint)
    return artifact_id, mh


def tokenizer_checkpoint(warehouse: Warehouse, root: Path, tokenizer: str | None,
                         variant: str = "discrete") -> tuple[Path, str, TokenizerConfig]:
    """(folder, artifact id, config) of a ``variant`` tokenizer checkpoint (discrete for the
    autoregressive world model, continuous for the diffusion one): a checkpoint folder, a
    checkpoint id (its first 12+ hex digits), or None for the newest one in lineage with token shards."""
    # A diffusion run named a tokenizer of the wrong variant: found by id all the same, to say so below.
    lookup = None if tokenizer and variant != "discrete" else variant
    folder, checkpoint_id = tokenizer_folder(warehouse, root, tokenizer, lookup)
    config = tokens.load_checkpoint(folder).config
    if config.variant != variant:
        if variant == "discrete":
            raise ValueError(f"tokenizer {checkpoint_id} is {config.variant}: the world model reads a discrete one's "
                             "codes")
        raise ValueError(f"tokenizer {checkpoint_id} is {config.variant}: the diffusion world model reads a "
                         f"{variant} one's latents")
    return folder, checkpoint_id, config


def tokenizer_folder(warehouse: Warehouse, root: Path, tokenizer: str | None,
                     variant: str | None = "discrete") -> tuple[Path, str]:
    """(folder, artifact id) of a tokenizer checkpoint, its weights checked against lineage: a folder,
    an id prefix of one of ``variant`` (any variant when None) in lineage, or None for the newest
    one with token shards."""
    root = root.resolve()
    if tokenizer and Path(tokenizer).is_dir():
        folder = Path(tokenizer).resolve()
        if not (folder / tokens.CONFIG_FILE).is_file():
            raise FileNotFoundError(f"{tokenizer}: not a tokenizer checkpoint folder (no {tokens.CONFIG_FILE})")
        if not (folder / tokens.WEIGHTS_FILE).is_file():
            raise CheckpointError(f"{folder}: no {tokens.WEIGHTS_FILE}")
        checkpoint_id, _ = known(warehouse, "checkpoint", folder / tokens.WEIGHTS_FILE, root, "tokenizer checkpoint",
                                 "train on a tokenizer `worldline tokenize` trained")
        return folder, checkpoint_id
    if tokenizer and not is_hex_id(tokenizer):
        raise FileNotFoundError(f"{tokenizer}: no such checkpoint folder, and not a checkpoint id")
    which = queries.tokenizer_condition(variant)
    if tokenizer:
        checkpoint_id, found = checkpoint_by_id(warehouse, tokenizer, which,
                                                f"{variant} tokenizer" if variant else "tokenizer", root)
        return integrity.path_of(found, root).parent, checkpoint_id
    newest = queries.newest_encoding_checkpoint(warehouse, which)
    if newest is None:
        raise StepMissing(f"no {variant or 'trained'} tokenizer with token shards in lineage: run `worldline "
                          "tokenize` first")
    checkpoint_id, found = checkpoint_by_id(warehouse, newest, which, "tokenizer", root)
    return integrity.path_of(found, root).parent, checkpoint_id


def token_shards(warehouse: Warehouse, root: Path, tokenizer_id: str,
                 place: str | None) -> list[tuple[Path, str, str | None]]:
    """(path, artifact id, manifest hash) of the token shards in folder ``place``, or by default
    the tokenizer's own, each checked against lineage, and the curated shards behind them."""
    folder = Path(place) if place else paths.resolve(root, paths.TOKEN_SHARD_FILE, tokenizer_id=tokenizer_id,
                                                     index=0).parent
    files = data.find_shards([folder])
    if not files:
        raise StepMissing(f"{folder}: no token shards (run `worldline tokenize` first)")
    shards = [(path, *known(warehouse, "token_shard", path, root, "token shard",
                            "train reads token shards `worldline tokenize` wrote")) for path in files]
    check_sources(warehouse, [s for _, s, _ in shards], root)
    return shards


def shape(sequences: list) -> tuple[tuple[int, int], int]:
    """(latent grid, frame size) the token sequences (codes or latents) share; ValueError when they mix them."""
    grids = {s.codes.shape[1:] if hasattr(s, "codes") else s.latents.shape[2:] for s in sequences}
    sizes = {s.info["size"] for s in sequences}
    if len(grids) != 1 or len(sizes) != 1:
        raise ValueError(f"token shards mix latent grids {sorted(grids)} or frame sizes {sorted(sizes)}")
    return grids.pop(), sizes.pop()


def check_sources(warehouse: Warehouse, token_ids: list[str], root: Path) -> None:
    """The curated shards the token shards' captions come from, checked against lineage where
    they are still there (a shard gone since is read as no captions, as before)."""
    for row in claims.parents(warehouse, token_ids, "tokens_of"):
        source = integrity.Recorded(*row)
        if (path := integrity.path_of(source.uri, root)).is_file():
            integrity.check(path, source)


def episodes(warehouse: Warehouse, folders: list[Path], root: Path) -> list[tuple[Path, str, str | None]]:
    """(folder, artifact id, manifest hash) of each episode, its step table checked against lineage."""
    return [(folder, *known(warehouse, "episode", folder / "steps.parquet", root, "episode",
                            "post-train on `worldline simulate`'s episodes")) for folder in folders]


def check_episode_videos(warehouse: Warehouse, folders: list[Path], camera: str | None, root: Path) -> None:
    """Each camera video post-training will encode, checked against lineage before it is read."""
    for folder in folders:
        for name in [camera] if camera else data.read_meta(folder).get("cameras", []):
            if (video := folder / f"{name}.mp4").is_file():
                known(warehouse, "episode_video", video, root, "episode video",
                      "post-train on `worldline simulate`'s episodes")


def episode_folders(manifest: str, root: Path):
    """(episode folders, scenario or None) of a manifest YAML, an episode folder or a manifest hash."""
    scenario = None
    place = Path(manifest)
    if place.is_file():
        scenario = manifests.load(place)
        place = paths.resolve(root, paths.EPISODES_OF_MANIFEST, manifest_hash=scenario.sha256)
    elif not place.exists() and is_hex_id(manifest):
        place = paths.resolve(root, paths.EPISODES_OF_MANIFEST, manifest_hash=manifest)
    found = data.episode_dirs(place)
    if not found:
        raise StepMissing(f"{manifest}: no simulated episodes under {place} (run `worldline simulate` first)")
    return found, scenario


def episode_texts(warehouse: Warehouse, folders: list[Path], scenario) -> dict[Path, str | None]:
    """The manifest's instruction and stressor kinds per episode, where the manifest is known."""
    texts: dict[Path, str | None] = {}
    for folder in folders:
        body = scenario.model_dump(mode="json") if scenario is not None else None
        if body is None:
            found = queries.manifest_body(warehouse, data.read_meta(folder).get("manifest_hash", ""))
            body = json.loads(found) if found is not None else None
        texts[folder] = None if body is None else data.episode_text(body["task"]["instruction"],
                                                                    [s["kind"] for s in body.get("stressors", [])])
    return texts

"""Checkpoints named on the command line or in flow parameters: a folder, or the first 12 or
more hex digits of a checkpoint id in lineage (as reports and audits print them).

Each lookup takes an open warehouse (None before any flow has written one): a flow passes its
run's, the CLI a read-only one opened before the flow starts, so that a bad name is one line
rather than a failed flow run. Bad names raise FileNotFoundError, or CheckpointError (a
ValueError) for a folder whose config is unreadable or incomplete.

Every checkpoint found here has had its weights checked against the sha256 lineage recorded
for them (``verified_file``): a changed file raises TamperedArtifact (issue 26).
"""

from __future__ import annotations

from pathlib import Path

from schemas import paths
from schemas.errors import StepMissing, TamperedArtifact
from tasks import integrity
from tasks.checkpoint_files import CONFIG_FILE, WEIGHTS_FILE, CheckpointError
from warehouse import integrity as claims
from warehouse import queries
from warehouse.queries import BC_POLICY, POSTTRAINED_WORLD_MODEL, VISION_POLICY
from warehouse.store import Warehouse


def is_hex_id(text: str) -> bool:
    """12 or more lower-case hex digits: a prefix of an artifact id or a hash."""
    return len(text) >= 12 and all(ch in "0123456789abcdef" for ch in text)


def verified_file(warehouse: Warehouse | None, root: Path, path: Path, kind: str, what: str,
                  hint: str | None = None, digest: str | None = None) -> tuple[str | None, str | None, str]:
    """(artifact id, manifest hash, sha256) of a file a stage is about to read, hashed once
    (or ``digest``, when the caller already has it) and checked against lineage: the row at
    its uri must have its bytes (else TamperedArtifact); a copy elsewhere of a ``kind``
    artifact is that artifact. A file lineage has never seen raises InvalidInput with ``hint``,
    or with ``hint`` None is an external input: (None, None, sha256), and nothing is recorded."""
    digest, uri = digest or integrity.file_sha256(path), integrity.uri_of(path, root)
    rows = claims.claims(warehouse, uri, digest, kind) if warehouse is not None else []
    found = integrity.match(path, uri, digest, kind, [integrity.Recorded(*r) for r in rows])
    if found is not None:
        return found.artifact_id, found.manifest_hash, digest
    if hint is not None:
        raise integrity.unknown(path, digest, what, hint)
    return None, None, digest


def verified_checkpoint(warehouse: Warehouse | None, root: Path, folder: Path) -> tuple[str | None, str | None]:
    """(artifact id or None, weights sha256 or None) of a checkpoint folder: its weights checked
    against lineage when lineage knows them (TamperedArtifact otherwise); a folder lineage does
    not know is an external checkpoint (evaluating one is allowed; it is recorded by whoever
    links it). A folder without weights is left to the loader's one-line error."""
    weights = Path(folder) / WEIGHTS_FILE
    if not weights.is_file():
        return None, None
    artifact_id, _, digest = verified_file(warehouse, root, weights, "checkpoint", "checkpoint")
    return artifact_id, digest


def verified_artifact(warehouse: Warehouse | None, path: Path, artifact_id: str) -> None:
    """A file this flow wrote in an earlier run and now reads back instead of redoing the work,
    checked against the sha256 lineage recorded for ``artifact_id`` (TamperedArtifact)."""
    row = claims.recorded(warehouse, [artifact_id]).get(artifact_id) if warehouse is not None else None
    if row is not None and Path(path).is_file():
        integrity.check(path, integrity.Recorded(*row))


def verified_world_model(warehouse: Warehouse | None, root: Path, folder: Path | str | None) -> str | None:
    """The lineage id (None: external, or no folder) of a world-model checkpoint folder about to
    roll out, its weights and its tokenizer's (``tokenizer`` in its config) checked against
    lineage. An unreadable config is left to the loader's one-line error."""
    from tasks.world.family import read_world_config

    if not folder:
        return None
    artifact_id, _ = verified_checkpoint(warehouse, root, Path(folder))
    try:
        tokenizer = read_world_config(Path(folder)).get("tokenizer")
    except CheckpointError:
        return artifact_id
    if isinstance(tokenizer, str):
        verified_checkpoint(warehouse, root, integrity.path_of(tokenizer, Path(root).resolve()))
    return artifact_id


def recorded_files(warehouse: Warehouse | None, root: Path, held: list[Path]) -> set[Path]:
    """Which of the files ``held`` lineage records at their paths (none without a warehouse): a
    file there that it does not is someone else's, not to be written over."""
    uris = {paths.escaped(integrity.uri_of(p, root)): p for p in held}
    return {uris[u] for u in claims.recorded_uris(warehouse, list(uris))} if warehouse is not None else set()


def verified_episode(warehouse: Warehouse | None, root: Path, episode) -> dict[Path, tuple[str | None, str]]:
    """A reused episode's step table and camera videos checked against lineage: each file's
    bytes (``verified_file``), and each video the one lineage recorded as rendered for this
    episode. Videos are recorded by content, so at a path with no row of its own (a panel's
    nominal cell, byte for byte the manifest's episodes) a copy of another episode's video
    matched that episode's row and was used (TamperedArtifact now). Returns each video's
    (artifact id, sha256), so a caller need not hash it again."""
    episode_id, _, _ = verified_file(warehouse, root, episode.table, "episode", "episode")
    rendered = claims.children(warehouse, [episode_id], "rendered") if warehouse is not None and episode_id else None
    found = {}
    for video in episode.videos.values():
        video_id, _, digest = verified_file(warehouse, root, video, "episode_video", "episode video")
        if rendered is not None and video_id not in rendered:
            raise TamperedArtifact(f"{video}: sha256 {digest[:12]} is not a video lineage recorded for this "
                                   f"episode ({episode_id[:12]}); run `worldline verify`")
        found[Path(video)] = (video_id, digest)
    return found


def verified_policy(warehouse: Warehouse | None, root: Path, policy) -> None:
    """A loaded behaviour-cloning policy's weights (the sha256 it computed when it read them)
    checked against lineage; other policies have no file."""
    meta, source = getattr(policy, "meta", None) or {}, getattr(policy, "source", None)
    if source and meta.get("weights_sha256"):
        verified_file(warehouse, root, Path(source) / WEIGHTS_FILE, "checkpoint", "policy checkpoint",
                      digest=meta["weights_sha256"])


def checkpoint_by_id(warehouse: Warehouse | None, prefix: str, condition: str, what: str,
                     root: Path | None = None, kind: str = "checkpoint") -> tuple[str, str]:
    """(artifact id, weights uri) of the one checkpoint (artifact of ``kind``) matching ``condition``
    (warehouse/queries.py) whose id starts with ``prefix``; FileNotFoundError naming ``what`` when
    there is none or several (or no lineage yet: ``warehouse`` None). With ``root``, its weights
    (when there) are checked against the sha256 lineage recorded (TamperedArtifact)."""
    if warehouse is None:
        raise FileNotFoundError(f"{what} {prefix}: no lineage warehouse yet to look the id up in")
    rows = queries.checkpoints_by_prefix(warehouse, condition, prefix, kind)
    if len(rows) != 1:
        raise FileNotFoundError(f"{what} {prefix}: {'no' if not rows else 'more than one'} "
                                f"{what} checkpoint with that id in lineage")
    artifact_id, uri, sha256 = rows[0]
    weights = integrity.path_of(uri, root) if root is not None else None
    if weights is not None and sha256 and weights.is_file():
        integrity.check(weights, integrity.Recorded(artifact_id, kind, uri, sha256))
    return artifact_id, uri


def checkpoint_folder(warehouse: Warehouse | None, root: Path, name: str, condition: str, what: str,
                      kind: str = "checkpoint") -> Path:
    """The folder ``name`` (it must hold a config.json), or the folder of the checkpoint (artifact
    of ``kind``) whose id starts with ``name``."""
    if Path(name).is_dir():
        folder = Path(name).resolve()
        if not (folder / CONFIG_FILE).is_file():
            raise FileNotFoundError(f"{name}: not a {what} checkpoint folder (no {CONFIG_FILE})")
        verified_checkpoint(warehouse, root, folder)
        return folder
    if not is_hex_id(name):
        raise FileNotFoundError(f"{name}: no such checkpoint folder, and not a checkpoint id")
    root = Path(root).resolve()
    return integrity.path_of(checkpoint_by_id(warehouse, name, condition, what, root, kind)[1], root).parent


def world_model_folder(warehouse: Warehouse | None, root: Path, name: str | None) -> Path:
    """A post-trained world model of either family (``tasks.world.family``): a checkpoint folder,
    an id prefix, or None for the newest. Its config must name the tokenizer and frame size it was
    trained with."""
    from tasks.world.family import read_world_config

    if name:
        folder = checkpoint_folder(warehouse, root, name, POSTTRAINED_WORLD_MODEL, "world model")
    else:
        uri = queries.newest_checkpoint_uri(warehouse, POSTTRAINED_WORLD_MODEL) if warehouse is not None else None
        if uri is None:
            raise StepMissing("no post-trained world model in lineage: run `worldline train` first")
        folder = integrity.path_of(uri, Path(root).resolve()).parent
        verified_checkpoint(warehouse, root, folder)
    config = read_world_config(folder)
    if missing := [key for key in ("tokenizer", "size") if key not in config]:
        raise CheckpointError(f"{folder / CONFIG_FILE}: not a post-trained world model's config "
                              f"(no {', '.join(missing)})")
    return folder


def policy_spec(warehouse: Warehouse | None, root: Path, spec: str) -> str:
    """``bc:ID`` or ``vision:ID`` with ID a policy checkpoint's id prefix becomes ``KIND:FOLDER``;
    every other policy name is returned as it is."""
    kind, _, arg = spec.partition(":")
    if kind not in ("bc", "vision") or not arg or Path(arg).exists() or not is_hex_id(arg):
        return spec
    condition, what = (BC_POLICY, "behaviour-cloning policy") if kind == "bc" else (VISION_POLICY, "vision policy")
    return f"{kind}:{checkpoint_folder(warehouse, root, arg, condition, what)}"

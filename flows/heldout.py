"""What the held-out evaluations of a world model (physics, camera, rig) settle before they
compute anything: the checkpoint and its tokenizer, that no seed trained the model, the window,
the lineage ids of both checkpoints, and the evaluation's key and id."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from flows.recording import RunContext
from schemas.hashing import content_hash, stable_id
from schemas.records import ArtifactRecord, LineageBatch
from tasks.lookup import verified_file, world_model_folder
from tasks.tokenize import tokens
from tasks.world import checkpoints, evaluation
from tasks.world.family import DIFFUSION, family_of, model_section, read_world_config


def checkpoint_artifact_id(run: RunContext, path: Path, kind: str, attrs: dict) -> str:
    """The lineage id of a checkpoint file, checked against the sha256 lineage recorded for it
    (TamperedArtifact); one lineage has never seen is recorded now as an external input (a
    checkpoint brought from elsewhere may be evaluated; its row says it has no lineage here)."""
    root = run.settings.data_root.resolve()
    artifact_id, _, digest = verified_file(run.warehouse, root, path, kind, kind)
    if artifact_id is not None:
        return artifact_id
    uri = path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)
    artifact_id = stable_id(kind, uri, digest)
    run.write(LineageBatch(artifacts=[ArtifactRecord(artifact_id=artifact_id, kind=kind, uri=uri, sha256=digest,
                                                     bytes=path.stat().st_size,
                                                     attrs={**attrs, "registered_by": "evaluate-physics",
                                                            "external": True})]))
    return artifact_id


@dataclass(frozen=True)
class Heldout:
    """The world model's folder and config, its tokenizer's folder, frames ``size``, video frames
    per latent frame (``every``), the context in latent frames, both checkpoints' lineage ids, and
    the evaluation's stage key and id."""

    wm_folder: Path
    config: dict
    tok_folder: Path
    size: int
    every: int
    context: int
    wm_id: str
    tok_id: str
    key: str
    evaluation_id: str


def heldout_setup(run: RunContext, stage: str, params: dict, world_model: str | None, tokenizer: str | None,
                  seeds: list[int], horizon: int, context: int | None, sampler_steps: int) -> Heldout:
    """Resolve and check the checkpoints of an evaluation on ``seeds``. ``params`` (what the
    evaluation means) gains ``sampler_steps`` for a diffusion world model only, so an
    autoregressive evaluation's id is as it was before the diffusion family existed."""
    root = run.settings.data_root.resolve()
    wm_folder = world_model_folder(run.warehouse, root, world_model)
    config = read_world_config(wm_folder)
    if family_of(config) == DIFFUSION:
        params["sampler_steps"] = sampler_steps
    overlap = evaluation.trained_seeds(config, root) & set(seeds)
    if overlap:
        raise ValueError(f"seeds {sorted(overlap)} trained this world model: evaluate on held-out seeds")
    tok_folder = Path(tokenizer) if tokenizer else root / config["tokenizer"]
    size, window = int(config["size"]), int(model_section(config)["max_frames"])
    every = int(model_section(config)["temporal_compression"])  # report every latent step
    context = context or max(1, window - horizon)
    wm_id = checkpoint_artifact_id(run, wm_folder / checkpoints.WEIGHTS_FILE, "checkpoint", {"model": "world_model"})
    tok_id = checkpoint_artifact_id(run, tok_folder / tokens.WEIGHTS_FILE, "checkpoint", {"model": "tokenizer"})
    meaning = {**params, "world_model": wm_id, "tokenizer": tok_id, "context": context}  # not the paths
    key = stable_id(stage, wm_id, tok_id, run.manifest_hash, content_hash(meaning))
    return Heldout(wm_folder, config, tok_folder, size, every, context, wm_id, tok_id, key,
                   stable_id("evaluation", key))

"""Lineage of the transfer step (docs/transfer.md).

A trained model is a `transfer_model` artifact (its weights file) with a `trained_on` edge from
the manifest its pairs were simulated from and its training curves as metrics. Each generated
clip is a `transferred_video` with edges `transferred_from` (the source episode's camera
video), `controlled_by` (each rendered control file it read that lineage holds; one it does
not is named in the clip's attrs instead) and `transferred_by` (the model). A model or source
video lineage has never seen is recorded as the controls flow records a video: by its bytes
(a `transfer_model` or `raw_video` whose id is a hash of its sha256), so no edge hangs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

from schemas import paths
from schemas.errors import StepMissing
from schemas.hashing import sha256_file, stable_id
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, raw_video_id
from tasks.checkpoint_files import CONFIG_FILE, WEIGHTS_FILE
from tasks.guard.config import GuardConfig
from tasks.guard.faces import FaceDecision
from tasks.guard.lineage import face_attrs, face_decisions, text_decisions
from tasks.guard.text import scan_fields
from tasks.integrity import path_of, uri_of
from tasks.lookup import checkpoint_folder, is_hex_id, verified_episode, verified_file
from tasks.world.checkpoints import checkpoint_lineage
from warehouse import queries

METRICS = ("loss", "psnr")  # train_loss, train_psnr per logged step
KIND = "transfer_model"


def model_folder(warehouse, root: Path, name: str | None) -> Path:
    """A transfer checkpoint's folder: ``name`` when it is a folder or no id (its config is read
    next, `tasks.transfer.apply.model_info`), the folder of the `transfer_model` whose id starts
    with ``name`` (12+ hex digits), or for None the newest one train-transfer trained."""
    if name is not None and (Path(name).is_dir() or not is_hex_id(name)):
        return Path(name)
    if name is not None:
        return checkpoint_folder(warehouse, root, name, queries.TRANSFER_MODEL, "transfer model", KIND)
    uri = queries.newest_checkpoint_uri(warehouse, queries.TRAINED_TRANSFER_MODEL, KIND) if warehouse else None
    if uri is None:
        raise StepMissing("no transfer model in lineage: run `worldline train-transfer` first, or give --model")
    return path_of(uri, Path(root).resolve()).parent


def model_lineage(checkpoint_id: str, folder: Path, root: Path, manifest_hash: str, history: list[dict],
                  stage_run_id: str, attrs: dict) -> LineageBatch:
    """The trained `transfer_model`, `trained_on` its manifest, with its curves."""
    return checkpoint_lineage(checkpoint_id, folder, root, [(manifest_hash, "trained_on")], history, stage_run_id,
                              manifest_hash, {"model": "transfer", **attrs}, kind="transfer_model", metrics=METRICS)


def _record(kind: str, artifact_id: str, path: Path, sha: str, root: Path, attrs: dict | None = None) -> ArtifactRecord:
    return ArtifactRecord(artifact_id=artifact_id, kind=kind, uri=paths.escaped(uri_of(path, root)), sha256=sha,
                          bytes=Path(path).stat().st_size, attrs=attrs or {})


@dataclass
class Inputs:
    """The ids of what one transfer reads, and records of those lineage did not hold."""

    model_id: str
    model_sha: str
    video_id: str = ""
    video_sha: str = ""
    controls: dict[str, str | None] = field(default_factory=dict)  # control -> artifact id, None: not in lineage
    new: list[ArtifactRecord] = field(default_factory=list)


def model_inputs(warehouse, root: Path, folder: Path) -> Inputs:
    """The model's artifact id and weights sha256, checked against lineage (TamperedArtifact)."""
    weights = Path(folder) / WEIGHTS_FILE
    model_id, _, sha = verified_file(warehouse, root, weights, KIND, "transfer model")
    if model_id is not None:
        return Inputs(model_id, sha)
    model_id = stable_id("transfer_model", sha)
    config = Path(folder) / CONFIG_FILE
    return Inputs(model_id, sha, new=[_record("transfer_model", model_id, weights, sha, root,
                                              {"model": "transfer", "config_uri": paths.escaped(uri_of(config, root))})])


def episode_inputs(warehouse, root: Path, model: Inputs, video: Path, controls: dict[str, Path]) -> Inputs:
    """``model`` with the source video and the rendered control files, each checked against lineage;
    in an episode folder lineage recorded, the video must be one that episode rendered (its step
    table, copied beside the clip as its labels, must describe these frames)."""
    table = Path(video).parent / Path(paths.EPISODE_TABLE).name
    if table.is_file():  # hashed once, as the episode's
        video_id, sha = verified_episode(warehouse, root, SimpleNamespace(table=table, videos={0: Path(video)}))[Path(video)]
    else:
        video_id, _, sha = verified_file(warehouse, root, video, "episode_video", "episode video")
    new = list(model.new)
    if video_id is None:
        video_id = raw_video_id(sha)
        new.append(_record("raw_video", video_id, video, sha, root))
    ids = {c: verified_file(warehouse, root, p, "control", "control")[0] for c, p in sorted(controls.items())}
    return Inputs(model.model_id, model.model_sha, video_id, sha, ids, new)


def transferred_lineage(video: Path, key: str, inputs: Inputs, root: Path, stage_run_id: str,
                        manifest_hash: str | None, look: str, faces: list[FaceDecision], guard: GuardConfig,
                        attrs: dict) -> tuple[str, LineageBatch]:
    """(artifact id, batch) of one transferred clip: the artifact, its edges, the pre-guard's
    decision on the look and the post-guard's on the frames."""
    sha = sha256_file(str(video))
    video_id = stable_id("transferred_video", key, sha)
    where = {c: (i if i else "not in lineage: no controlled_by edge") for c, i in inputs.controls.items()}
    artifact = _record("transferred_video", video_id, video, sha, root,
                       {**attrs, "look": look, "model_id": inputs.model_id, "rendered_controls": where,
                        **face_attrs(faces, guard)})
    batch = LineageBatch(artifacts=[*inputs.new, artifact.model_copy(update={"manifest_hash": manifest_hash,
                                                                              "stage_run_id": stage_run_id})])
    batch.edges.append(EdgeRecord(parent_id=inputs.video_id, child_id=video_id, relation="transferred_from"))
    batch.edges.extend(EdgeRecord(parent_id=i, child_id=video_id, relation="controlled_by")
                       for i in inputs.controls.values() if i)
    batch.edges.append(EdgeRecord(parent_id=inputs.model_id, child_id=video_id, relation="transferred_by"))
    batch.extend(text_decisions(video_id, scan_fields({"look": look}, guard), stage_run_id, manifest_hash))
    batch.extend(face_decisions(video_id, faces, stage_run_id, manifest_hash))
    return video_id, batch

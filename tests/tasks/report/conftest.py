"""A small warehouse for the report page tests, written with the real writer: a curate run
(a raw video, three clips of it, two kept and written as MP4s, one rejected, a shard of the
kept two, per-clip metrics) and a train run (a checkpoint trained on the shard, a loss series,
a PNG plot). Videos are tiny MP4s made on the fly."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from schemas.hashing import stable_id
from schemas.records import (ArtifactRecord, EdgeRecord, LineageBatch, ManifestRow, MetricRecord, RejectionRecord,
                             RunRecord, StageRunRecord)
from tests.support import scene_frames, sha256_of, write_video
from warehouse.store import Warehouse

MANIFEST = "ab" * 32


@dataclass(frozen=True)
class Lineage:
    root: Path
    warehouse: Path
    curate_run: str
    train_run: str
    raw: str
    clips: tuple[str, str]
    rejected: str
    shard: str
    checkpoint: str
    plot: str


def _artifact(root: Path, artifact_id: str, kind: str, uri: str | None, stage_run: str, **attrs) -> ArtifactRecord:
    path = root / uri if uri else None
    return ArtifactRecord(artifact_id=artifact_id, kind=kind, uri=uri, sha256=sha256_of(path) if path else None,
                          bytes=path.stat().st_size if path else None, manifest_hash=MANIFEST,
                          stage_run_id=stage_run, attrs=attrs)


def build(root: Path) -> Lineage:
    root.mkdir(parents=True, exist_ok=True)
    (root / "raw").mkdir()
    (root / "clips").mkdir()
    (root / "shards").mkdir()
    (root / "plots").mkdir()
    write_video(root / "raw/source.mp4", scene_frames(0, n=30))
    write_video(root / "clips/clip_a.mp4", scene_frames(2, n=15))
    write_video(root / "clips/clip_b.mp4", scene_frames(3, n=15))
    (root / "shards/part-00000.parquet").write_bytes(b"PAR1 not really a shard PAR1")
    Image.fromarray(np.tile(np.linspace(0, 255, 64, dtype=np.uint8), (32, 1))).convert("RGB").save(root / "plots/loss.png")

    curate, train = "run-curate-0001", "run-train-0002"
    decode, encode, shard_sr = (stable_id("stage", s) for s in ("decode", "encode", "shard"))
    fit = stable_id("stage", "fit")
    raw, clip_a, clip_b, bad = (stable_id("artifact", s) for s in ("raw", "clip_a", "clip_b", "clip_bad"))
    shard, checkpoint, plot = (stable_id("artifact", s) for s in ("shard", "checkpoint", "plot"))
    with Warehouse(root / "lineage.duckdb") as wh:
        wh.start_run(RunRecord(run_id=curate, flow="curate", manifest_hash=MANIFEST, params={"inputs": ["raw"]}))
        wh.write(LineageBatch(
            manifests=[ManifestRow(manifest_hash=MANIFEST, name="conveyor_push", schema_version=1, body="{}")],
            stage_runs=[StageRunRecord(stage_run_id=decode, run_id=curate, stage="decode", input_key="k1", n_in=1, n_out=3,
                                       seconds=0.5, manifest_hash=MANIFEST),
                        StageRunRecord(stage_run_id=encode, run_id=curate, stage="encode", input_key="k2", n_in=3, n_out=2,
                                       seconds=1.25, manifest_hash=MANIFEST),
                        StageRunRecord(stage_run_id=shard_sr, run_id=curate, stage="shard", input_key="k3", n_in=2,
                                       n_out=1, seconds=0.1, manifest_hash=MANIFEST)],
            artifacts=[ArtifactRecord(artifact_id=MANIFEST, kind="manifest", uri=None, sha256=None),
                       _artifact(root, raw, "raw_video", "raw/source.mp4", decode),
                       _artifact(root, clip_a, "clip", "clips/clip_a.mp4", encode),
                       _artifact(root, clip_b, "clip", "clips/clip_b.mp4", encode),
                       _artifact(root, bad, "clip", None, encode),
                       _artifact(root, shard, "shard", "shards/part-00000.parquet", shard_sr)],
            edges=[EdgeRecord(parent_id=MANIFEST, child_id=raw),
                   *(EdgeRecord(parent_id=raw, child_id=c) for c in (clip_a, clip_b, bad)),
                   *(EdgeRecord(parent_id=c, child_id=shard, relation="shard_of") for c in (clip_a, clip_b))],
            metrics=[MetricRecord(subject_id=c, name="blur", value=v, stage_run_id=encode)
                     for c, v in ((clip_a, 120.0), (clip_b, 95.5), (bad, 3.0))],
            rejections=[RejectionRecord(artifact_id=bad, stage="blur", reason="blurry", scores={"blur": 3.0},
                                        stage_run_id=encode, manifest_hash=MANIFEST)]))
        wh.finish_run(curate, "completed")
        wh.start_run(RunRecord(run_id=train, flow="train", manifest_hash=MANIFEST))
        wh.write(LineageBatch(
            stage_runs=[StageRunRecord(stage_run_id=fit, run_id=train, stage="fit", input_key="k4", n_in=1, n_out=1,
                                       seconds=3.0)],
            artifacts=[ArtifactRecord(artifact_id=checkpoint, kind="checkpoint", uri="checkpoints/missing.safetensors",
                                      sha256="00" * 32, bytes=10, stage_run_id=fit),
                       _artifact(root, plot, "report", "plots/loss.png", fit)],
            edges=[EdgeRecord(parent_id=shard, child_id=checkpoint, relation="trained_on"),
                   EdgeRecord(parent_id=checkpoint, child_id=plot)],
            metrics=[MetricRecord(subject_id=fit, name="loss", step=s, value=1.0 / (s + 1), stage_run_id=fit)
                     for s in range(10)]))
        wh.finish_run(train, "partial", "one input failed")
    return Lineage(root, root / "lineage.duckdb", curate, train, raw, (clip_a, clip_b), bad, shard, checkpoint, plot)


@pytest.fixture(scope="module")
def lineage(tmp_path_factory) -> Lineage:
    return build(tmp_path_factory.mktemp("report") / "data")

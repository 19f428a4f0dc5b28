"""Records that stages return and the warehouse stores. Tasks build them; one process writes."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

ArtifactKind = Literal[
    "manifest",
    "raw_video",
    "ground_truth",
    "episode",
    "episode_video",
    "control",
    "transfer_model",
    "transferred_video",
    "clip",
    "shard",
    "checkpoint",
    "token_shard",
    "panel",
    "evaluation",
    "report",
]
Status = Literal["running", "completed", "partial", "failed", "skipped"]


class Record(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


class ManifestRow(Record):
    manifest_hash: str = Field(pattern=r"^[0-9a-f]{64}$")
    name: str
    schema_version: int
    body: str  # canonical JSON of the whole manifest
    source_uri: str | None = None
    parent_hash: str | None = None


class RunRecord(Record):
    run_id: str
    flow: str
    manifest_hash: str | None = None
    prefect_flow_run_id: str | None = None
    status: Status = "running"
    params: dict[str, Any] = {}
    message: str | None = None


class StageRunRecord(Record):
    """One stage over one input. A completed row is also the marker a re-run skips on."""

    stage_run_id: str
    run_id: str
    stage: str
    input_key: str  # hash of the inputs and the stage config
    manifest_hash: str | None = None
    status: Status = "completed"
    n_in: int = 0
    n_out: int = 0
    seconds: float = 0.0
    attrs: dict[str, Any] = {}


class ArtifactRecord(Record):
    artifact_id: str
    kind: ArtifactKind
    uri: str | None  # None for a span that was judged but never written (a rejected clip)
    sha256: str | None
    bytes: int | None = None
    manifest_hash: str | None = None
    stage_run_id: str | None = None
    attrs: dict[str, Any] = {}


class EdgeRecord(Record):
    parent_id: str
    child_id: str
    relation: str = "derived"


class MetricRecord(Record):
    subject_id: str  # an artifact or a stage run
    name: str
    value: float
    step: int = 0
    stage_run_id: str | None = None
    manifest_hash: str | None = None
    attrs: dict[str, Any] = {}


class RejectionRecord(Record):
    artifact_id: str
    stage: str
    reason: str
    scores: dict[str, float | None] = {}
    stage_run_id: str | None = None
    manifest_hash: str | None = None
    detail: str | None = None


class LineageBatch(BaseModel):
    """What a task returns: everything it made, judged or measured, written in one transaction."""

    model_config = ConfigDict(extra="forbid")

    manifests: list[ManifestRow] = []
    stage_runs: list[StageRunRecord] = []
    artifacts: list[ArtifactRecord] = []
    edges: list[EdgeRecord] = []
    metrics: list[MetricRecord] = []
    rejections: list[RejectionRecord] = []

    def extend(self, other: "LineageBatch") -> "LineageBatch":
        for name in type(self).model_fields:
            getattr(self, name).extend(getattr(other, name))
        return self

    def __len__(self) -> int:
        return sum(len(getattr(self, name)) for name in type(self).model_fields)


class ClipRecord(Record):
    """A span of a source video, with every score the filters measured and the verdict."""

    clip_id: str
    source_id: str
    source_uri: str
    start_frame: int = Field(ge=0)
    end_frame: int  # exclusive
    start_s: float
    end_s: float
    fps: float = Field(gt=0)
    width: int = Field(gt=0)
    height: int = Field(gt=0)
    scores: dict[str, float] = {}
    tags: tuple[str, ...] = ()
    caption: str = ""
    phash: str | None = None
    dedup_group: str | None = None
    kept: bool = True
    reject_stage: str | None = None
    reject_reason: str | None = None
    uri: str | None = None
    sha256: str | None = None
    bytes: int | None = None
    manifest_hash: str | None = None

    @property
    def frames(self) -> int:
        return self.end_frame - self.start_frame


class ShardRecord(Record):
    shard_id: str
    uri: str
    sha256: str
    bytes: int
    n_clips: int
    resolution_bucket: str
    length_bucket: str
    clip_ids: tuple[str, ...]
    manifest_hash: str | None = None


def raw_video_id(sha256: str) -> str:
    """A raw video is identified by its bytes: the same file under two names is one artifact."""
    from schemas.hashing import stable_id

    return stable_id("raw_video", sha256)


def clip_id(source_sha256: str, start_frame: int, end_frame: int) -> str:
    from schemas.hashing import stable_id

    return stable_id("clip", source_sha256, str(start_frame), str(end_frame))

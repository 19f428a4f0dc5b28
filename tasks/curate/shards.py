"""Parquet shards of curated clips, bucketed by resolution and length, byte-identical on a re-run.

Rows are grouped into buckets (resolution from the short side, length from the duration),
sorted inside a bucket by duration then clip id, and cut into files of at most
``max_clips`` rows and about ``max_bytes`` bytes under ``schemas.paths.SHARD_FILE``. Every file
has the schema ``SHARD_SCHEMA``; ``read_shard`` refuses any other (but reads the first layout,
``SHARD_SCHEMA_V1``, whose scores were a Parquet map, converting them). Scores are a list of
``{key, value}`` structs, since Hugging Face ``datasets`` has no type for an Arrow map: a shard
folder loads with ``datasets.load_dataset("parquet", data_dir=...)``, streamed too, and
``clip_bytes`` reads as binary. The writer stores no
timestamps and fixes compression, row-group size and column order, so the same clip records
give the same bytes (checked by tests/tasks/curate/test_shards.py). A file is named by its
content (issue 26), so a later run into the same bucket adds files and never overwrites one;
``legacy_shards`` finds files of the older ``part-NNNNN.parquet`` layout for curate to rename.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import pyarrow as pa
import pyarrow.parquet as pq
from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas import paths
from schemas.hashing import sha256_file, stable_id
from schemas.manifest import FieldError
from schemas.records import ArtifactRecord, ClipRecord, EdgeRecord, LineageBatch, ShardRecord
from tasks import faults

SHARD_SCHEMA = pa.schema(
    [
        pa.field("clip_id", pa.string(), nullable=False),
        pa.field("source_id", pa.string(), nullable=False),
        pa.field("source_uri", pa.string(), nullable=False),
        pa.field("start_frame", pa.int64(), nullable=False),
        pa.field("end_frame", pa.int64(), nullable=False),  # exclusive
        pa.field("start_s", pa.float64(), nullable=False),
        pa.field("end_s", pa.float64(), nullable=False),
        pa.field("fps", pa.float64(), nullable=False),
        pa.field("width", pa.int32(), nullable=False),
        pa.field("height", pa.int32(), nullable=False),
        pa.field("duration_s", pa.float64(), nullable=False),
        pa.field("scores", pa.list_(pa.struct([pa.field("key", pa.string(), nullable=False),
                                               pa.field("value", pa.float64(), nullable=False)])), nullable=False),
        pa.field("tags", pa.list_(pa.string()), nullable=False),
        pa.field("caption", pa.string(), nullable=False),
        pa.field("dedup_group", pa.string()),
        pa.field("phash", pa.string()),
        pa.field("sha256", pa.string()),  # of the encoded clip file
        pa.field("bytes", pa.int64()),
        pa.field("clip_uri", pa.string()),
        pa.field("clip_bytes", pa.binary()),  # the encoded MP4, when ShardConfig.embed_clips
        pa.field("manifest_hash", pa.string()),
    ],
    metadata={"worldline.shard_schema": "2"},
)
# The first layout (before 2026-11-26): scores as map<string, double>. Still read, never written.
SHARD_SCHEMA_V1 = pa.schema(
    [pa.field("scores", pa.map_(pa.string(), pa.float64()), nullable=False) if f.name == "scores" else f
     for f in SHARD_SCHEMA],
    metadata={"worldline.shard_schema": "1"},
)

# Parquet leaf column paths: per-column writer options are keyed by these, not by field names.
_NESTED = {"scores": ("scores.list.element.key", "scores.list.element.value"), "tags": ("tags.list.element",)}
LEAF_COLUMNS = tuple(leaf for name in SHARD_SCHEMA.names for leaf in _NESTED.get(name, (name,)))
RESOLUTIONS = ((2160, "2160p"), (1440, "1440p"), (1080, "1080p"), (720, "720p"), (480, "480p"), (360, "360p"), (240, "240p"))
LENGTH_EDGES = (2.0, 5.0, 10.0, 30.0, 60.0)
ROW_OVERHEAD = 512  # bytes a row costs besides its clip bytes, for the size cap


class ShardError(ValueError):
    """One line: the file and the problem."""


class ShardConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    max_bytes: int = Field(paths.SHARD_MAX_BYTES, gt=0, description="cap per file (estimated from clip bytes)")
    max_clips: int = Field(paths.SHARD_MAX_CLIPS, gt=0)
    embed_clips: bool = Field(True, description="store each clip's encoded MP4 in clip_bytes")
    # (minimum short side, name), largest first; one at least: a clip below the last is "lt<name>"
    resolutions: tuple[tuple[int, str], ...] = Field(RESOLUTIONS, min_length=1)
    length_edges: tuple[float, ...] = LENGTH_EDGES  # seconds, increasing
    # Parquet's codecs with levels, as pyarrow's writer (pq.write_table) names them: the writer
    # sets compression_level on every packed column, which pyarrow refuses for none and snappy
    compression: Literal["gzip", "brotli", "lz4", "zstd"] = "zstd"
    compression_level: int = 3
    row_group_rows: int = Field(256, gt=0)

    @model_validator(mode="after")
    def _ordered(self) -> "ShardConfig":
        sides = [s for s, _ in self.resolutions]
        if sides != sorted(sides, reverse=True) or len(set(sides)) != len(sides):
            raise ValueError("resolutions must be listed largest short side first, without repeats")
        if list(self.length_edges) != sorted(set(self.length_edges)) or not self.length_edges:
            raise ValueError("length_edges must be increasing seconds")
        return self

    @model_validator(mode="after")
    def _level_fits_codec(self) -> "ShardConfig":
        # pyarrow refuses a level outside its codec's range (gzip 12) only when it writes.
        low = pa.Codec.minimum_compression_level(self.compression)
        high = pa.Codec.maximum_compression_level(self.compression)
        if not low <= self.compression_level <= high:
            raise FieldError("compression_level", f"{self.compression_level} is outside {self.compression}'s "
                                                  f"levels, {low} to {high}")
        return self


def resolution_bucket(width: int, height: int, config: ShardConfig = ShardConfig()) -> str:
    """Name of the largest bucket whose short side the clip reaches, e.g. 1280x720 -> "720p"."""
    side = min(width, height)
    for minimum, name in config.resolutions:
        if side >= minimum:
            return name
    return f"lt{config.resolutions[-1][1]}"


def _seconds(value: float) -> str:
    return f"{value:g}"


def length_bucket(duration_s: float, config: ShardConfig = ShardConfig()) -> str:
    """e.g. "2-5s" for 2 <= d < 5; "lt2s" below the first edge, "ge60s" from the last."""
    edges = config.length_edges
    if duration_s < edges[0]:
        return f"lt{_seconds(edges[0])}s"
    for low, high in zip(edges, edges[1:]):
        if duration_s < high:
            return f"{_seconds(low)}-{_seconds(high)}s"
    return f"ge{_seconds(edges[-1])}s"


def _clip_file(clip: ClipRecord, root: Path) -> Path:
    uri = clip.uri or ""
    path = Path(uri.removeprefix("file://"))
    return path if path.is_absolute() else Path(root) / path


def _read_clip(clip: ClipRecord, root: Path) -> bytes:
    if not clip.uri:
        raise ShardError(f"clip {clip.clip_id}: no uri, so no clip bytes to embed (set embed_clips=False to shard without them)")
    path = _clip_file(clip, root)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ShardError(f"{path}: cannot read clip {clip.clip_id}: {exc.strerror or exc}") from None
    if clip.sha256 and hashlib.sha256(data).hexdigest() != clip.sha256:
        raise ShardError(f"{path}: sha256 differs from the one recorded for clip {clip.clip_id}")
    return data


def _row(clip: ClipRecord, data: bytes | None) -> dict:
    return {
        "clip_id": clip.clip_id,
        "source_id": clip.source_id,
        "source_uri": paths.escaped(clip.source_uri),
        "start_frame": clip.start_frame,
        "end_frame": clip.end_frame,
        "start_s": clip.start_s,
        "end_s": clip.end_s,
        "fps": clip.fps,
        "width": clip.width,
        "height": clip.height,
        "duration_s": clip.end_s - clip.start_s,
        "scores": [{"key": k, "value": v} for k, v in sorted(clip.scores.items())],  # key order: one layout per meaning
        "tags": list(clip.tags),
        "caption": clip.caption,
        "dedup_group": clip.dedup_group,
        "phash": clip.phash,
        "sha256": clip.sha256,
        "bytes": clip.bytes,
        "clip_uri": clip.uri,
        "clip_bytes": data,
        "manifest_hash": clip.manifest_hash,
    }


def _write_named(table: pa.Table, root: Path, bucket: dict[str, str], index: int,
                 config: ShardConfig) -> tuple[str, str]:
    """Write part ``index`` of a bucket to a temporary, hash it and rename it to its name by
    content (``SHARD_FILE``): no run overwrites another's shard. Returns (uri, sha256). The
    temporary is gone on every way out; a full disk stops the run (``EnvironmentFault``)."""
    folder = Path(root) / paths.SHARD_DIR.format(**bucket)
    tmp = folder / f".part-{index:05d}.{os.getpid()}.tmp"
    with faults.fatal_when_disk_full(tmp, "writing shards", root):
        folder.mkdir(parents=True, exist_ok=True)
        try:
            # MP4 bytes do not compress: spend no time trying, and keep them out of dictionaries.
            packed = [name for name in LEAF_COLUMNS if name != "clip_bytes"]
            pq.write_table(
                table, tmp,
                compression={name: config.compression for name in packed} | {"clip_bytes": "none"},
                compression_level={name: config.compression_level for name in packed},
                row_group_size=config.row_group_rows, use_dictionary=["source_id", "source_uri", "manifest_hash"],
                write_statistics=True,
            )
            _fsync(tmp)
            faults.point("shard", tmp)  # crash tests: a whole shard in its temporary file, not yet renamed
            digest = sha256_file(str(tmp))
            rel = paths.SHARD_FILE.format(**bucket, index=index, sha256=digest)
            os.replace(tmp, Path(root) / rel)
            _fsync(folder)  # the rename itself survives a power cut
        finally:
            tmp.unlink(missing_ok=True)
    return rel, digest


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


# Temporary files of the atomic writers (".<name>.<pid>.tmp", ".<name>.<pid>.tmp.mp4") that a
# killed process left behind. Never read: the final name only appears by rename.
TEMPORARY_GLOBS = (".*.tmp", ".*.tmp.mp4")
SWEPT_FOLDERS = ("clips", "shards", "analysis")


def remove_stale_temporaries(root: Path) -> list[Path]:
    """Delete the temporaries a crashed run left under root's clip, shard and analysis folders.

    Call it only while holding the warehouse for writing: DuckDB lets one process do that, so
    no other curate run is writing here and every temporary found is a dead process's.
    """
    removed = []
    for folder in SWEPT_FOLDERS:
        base = Path(root) / folder
        if not base.is_dir():
            continue
        for pattern in TEMPORARY_GLOBS:
            for stale in base.rglob(pattern):
                if stale.is_file():
                    stale.unlink(missing_ok=True)
                    removed.append(stale)
    return sorted(removed)


@dataclass(frozen=True)
class LegacyShard:
    """A shard under the name it had before issue 26 (``part-NNNNN.parquet``), which the next run
    into its bucket would overwrite, and the name its content gives it now."""

    uri: str  # root-relative POSIX paths
    new_uri: str
    sha256: str


def legacy_shards(root: Path) -> list[LegacyShard]:
    """Every old-layout shard under root's shard folder, sorted by path."""
    found = []
    for path in sorted((Path(root) / "shards").glob("*/*/*/*.parquet")):
        named = paths.LEGACY_SHARD_NAME.fullmatch(path.name)
        if named is None or not path.is_file():
            continue
        rel = path.relative_to(root)
        _, manifest_hash, resolution, length, _ = rel.parts
        digest = sha256_file(str(path))
        new = paths.SHARD_FILE.format(manifest_hash=manifest_hash, resolution=resolution, length=length,
                                      index=int(named["index"]), sha256=digest)
        found.append(LegacyShard(uri=rel.as_posix(), new_uri=new, sha256=digest))
    return found


def rename_legacy(root: Path, shard: LegacyShard) -> None:
    """Move an old-layout shard to its name by content. Nothing is deleted: a file already under
    that name has the same bytes (the name says so), and a run killed half way renames again."""
    os.replace(Path(root) / shard.uri, Path(root) / shard.new_uri)
    _fsync((Path(root) / shard.new_uri).parent)


def write_shards(
    clips: Sequence[ClipRecord], root: Path, manifest_hash: str, config: ShardConfig = ShardConfig()
) -> list[ShardRecord]:
    """Write the clips to Parquet shards under root and describe each file written.

    Clips marked ``kept=False`` are refused: shards hold curated clips only. Shard uris are
    root-relative POSIX paths from ``schemas.paths.SHARD_FILE``, named by their content: a
    run never overwrites a shard of another run, and the same clips give the same file.
    """
    rejected = [c.clip_id for c in clips if not c.kept]
    if rejected:
        raise ShardError(f"write_shards: {len(rejected)} clips are marked rejected, e.g. {rejected[0]}")
    ids = [c.clip_id for c in clips]
    if len(set(ids)) != len(ids):
        raise ShardError("write_shards: clip ids repeat")
    buckets: dict[tuple[str, str], list[ClipRecord]] = {}
    for clip in clips:
        key = (resolution_bucket(clip.width, clip.height, config), length_bucket(clip.end_s - clip.start_s, config))
        buckets.setdefault(key, []).append(clip)
    records = []
    for (res, length), members in sorted(buckets.items()):
        members.sort(key=lambda c: (c.end_s - c.start_s, c.clip_id))
        parts: list[list[dict]] = [[]]
        size = 0
        for clip in members:
            data = _read_clip(clip, root) if config.embed_clips else None
            cost = ROW_OVERHEAD + len(clip.caption) + (len(data) if data else 0)
            if parts[-1] and (len(parts[-1]) >= config.max_clips or size + cost > config.max_bytes):
                parts.append([])
                size = 0
            parts[-1].append(_row(clip, data))
            size += cost
        bucket = {"manifest_hash": manifest_hash, "resolution": res, "length": length}
        for index, rows in enumerate(parts):
            rel, digest = _write_named(pa.Table.from_pylist(rows, schema=SHARD_SCHEMA), root, bucket, index, config)
            records.append(ShardRecord(
                shard_id=stable_id("shard", rel, digest), uri=Path(rel).as_posix(), sha256=digest,
                bytes=(Path(root) / rel).stat().st_size, n_clips=len(rows), resolution_bucket=res, length_bucket=length,
                clip_ids=tuple(r["clip_id"] for r in rows), manifest_hash=manifest_hash,
            ))
    return records


def read_shard(path: Path) -> pa.Table:
    """The shard's table; a file whose schema is not SHARD_SCHEMA is refused with ShardError."""
    path = Path(path)
    try:
        schema = pq.read_schema(path)
    except (OSError, pa.ArrowException) as exc:
        raise ShardError(f"{path}: not a readable Parquet file: {exc}") from None
    if schema.equals(SHARD_SCHEMA_V1, check_metadata=False):
        return _from_v1(pq.read_table(path, schema=SHARD_SCHEMA_V1))
    check_schema(schema, str(path))
    return pq.read_table(path, schema=SHARD_SCHEMA)


def _from_v1(table: pa.Table) -> pa.Table:
    """A first-layout table in SHARD_SCHEMA: each scores map becomes its list of {key, value}."""
    scores = [[{"key": k, "value": v} for k, v in row] for row in table.column("scores").to_pylist()]
    column = pa.array(scores, type=SHARD_SCHEMA.field("scores").type)
    return table.set_column(table.schema.get_field_index("scores"), SHARD_SCHEMA.field("scores"), column) \
        .replace_schema_metadata(SHARD_SCHEMA.metadata)


def scores_of(row: dict) -> dict[str, float]:
    """A shard row's scores as a dict (they are stored as a list of {key, value})."""
    return {item["key"]: item["value"] for item in row["scores"]}


def check_schema(schema: pa.Schema, where: str) -> None:
    """Raise ShardError naming ``where`` and the first field that differs from SHARD_SCHEMA."""
    if schema.equals(SHARD_SCHEMA, check_metadata=False):
        return
    have = {f.name: f for f in schema}
    for field in SHARD_SCHEMA:
        if field.name not in have:
            raise ShardError(f"{where}: not a Worldline shard: column {field.name!r} is missing")
        if not have[field.name].equals(field):
            raise ShardError(f"{where}: not a Worldline shard: column {field.name!r} is {have[field.name].type}"
                             f"{'' if have[field.name].nullable else ' not null'}, expected {field.type}"
                             f"{'' if field.nullable else ' not null'}")
    extra = [n for n in have if n not in SHARD_SCHEMA.names]
    if extra:
        raise ShardError(f"{where}: not a Worldline shard: unexpected column {extra[0]!r}")
    raise ShardError(f"{where}: not a Worldline shard: columns are in a different order")


def shard_lineage(shards: Sequence[ShardRecord], stage_run_id: str) -> LineageBatch:
    """One shard artifact per file and a clip -> shard edge ("shard_of") per row; clip ids are artifact ids."""
    batch = LineageBatch()
    for shard in shards:
        batch.artifacts.append(ArtifactRecord(
            artifact_id=shard.shard_id, kind="shard", uri=shard.uri, sha256=shard.sha256, bytes=shard.bytes,
            manifest_hash=shard.manifest_hash, stage_run_id=stage_run_id,
            attrs={"n_clips": shard.n_clips, "resolution_bucket": shard.resolution_bucket,
                   "length_bucket": shard.length_bucket},
        ))
        batch.edges.extend(EdgeRecord(parent_id=c, child_id=shard.shard_id, relation="shard_of") for c in shard.clip_ids)
    return batch

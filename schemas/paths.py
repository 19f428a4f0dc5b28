"""Every on-disk path template and size cap. Nothing else formats a path."""

from __future__ import annotations

from pathlib import Path

WAREHOUSE_FILE = "lineage.duckdb"
PREFECT_DIR = "prefect"
QUARANTINE_DIR = "quarantine"

EPISODES_OF_MANIFEST = "episodes/{manifest_hash:.12}"
EPISODE_DIR = EPISODES_OF_MANIFEST + "/episode_{index:06d}"
EPISODE_VIDEO = EPISODE_DIR + "/{camera}.mp4"
EPISODE_TABLE = EPISODE_DIR + "/steps.parquet"
EPISODE_META = EPISODE_DIR + "/meta.json"

CORPUS_VIDEO = "corpus/seed_{seed:06d}/raw_{index:04d}.mp4"
CORPUS_TRUTH = "corpus/seed_{seed:06d}/raw_{index:04d}.truth.json"

ANALYSIS_FILE = "analysis/{sha256:.2}/{sha256}-{config_hash:.16}.json"
CLIP_FILE = "clips/{source_id:.2}/{clip_id}.mp4"
SHARD_FILE = "shards/{manifest_hash:.12}/{resolution}/{length}/part-{index:05d}.parquet"
SHARD_MAX_BYTES = 256 * 1024 * 1024
SHARD_MAX_CLIPS = 1000

CHECKPOINT_DIR = "checkpoints/{model}/{checkpoint_id}"
TOKEN_SHARD_FILE = "tokens/{tokenizer_id:.12}/part-{index:05d}.parquet"

PANEL_DIR = "panels/{panel_id}"
PANEL_SPEC = PANEL_DIR + "/panel.json"
PANEL_SHEET = PANEL_DIR + "/contact_sheet.png"
PANEL_VIDEO = PANEL_DIR + "/panel.mp4"
EVALUATION_FILE = "evaluations/{evaluation_id}/result.json"
# The physics evaluation of a world model (flows/physics.py): its table, report and plots.
PHYSICS_RESULT = "evaluations/{evaluation_id}/physics.json"
PHYSICS_REPORT = "evaluations/{evaluation_id}/physics.md"
PHYSICS_PLOT = "evaluations/{evaluation_id}/{plot}.png"
# A camera video's tokenizer codes (a cache the train flow may delete and rebuild).
EPISODE_CODES_FILE = "cache/episode_codes/{tokenizer_id:.12}/{video_sha256:.24}-{size}.npz"


# Manifests the loop derives from a panel's failing cells.
DERIVED_MANIFEST_FILE = "manifests/derived/{manifest_hash:.12}.yaml"


def resolve(root: Path, template: str, **fields) -> Path:
    return Path(root) / template.format(**fields)

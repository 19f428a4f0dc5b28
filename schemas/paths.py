"""Every on-disk path template and size cap. Nothing else formats a path."""

from __future__ import annotations

import os
import re
from pathlib import Path

WAREHOUSE_FILE = "lineage.duckdb"
PREFECT_DIR = "prefect"
QUARANTINE_DIR = "quarantine"

EPISODES_OF_MANIFEST = "episodes/{manifest_hash:.12}"
EPISODE_FOLDER = "episode_{index:06d}"  # an episode's folder inside its manifest's (or policy's)
EPISODE_DIR = EPISODES_OF_MANIFEST + "/" + EPISODE_FOLDER
EPISODE_VIDEO = EPISODE_DIR + "/{camera}.mp4"
EPISODE_TABLE = EPISODE_DIR + "/steps.parquet"
EPISODE_META = EPISODE_DIR + "/meta.json"
# Episodes a named policy drove (`worldline simulate --policy`): a folder beside the manifest's
# own, so training on the manifest never takes them in unasked; `train --also FOLDER` does.
POLICY_EPISODES = EPISODES_OF_MANIFEST + "-{policy_id:.12}"
POLICY_EPISODE_DIR = POLICY_EPISODES + "/" + EPISODE_FOLDER
# Controls of a video (tasks/controls, docs/transfer.md): depth and segmentation that MuJoCo
# renders (npz), edges and blur made of the video (mp4). An episode's sit in its controls/
# folder, named by camera; any other video's beside it (or under --out), named by its stem.
CONTROL_SUFFIX = {"depth": "npz", "seg": "npz", "edges": "mp4", "blur": "mp4"}
CONTROL_FILE = "{name}.{control}.{suffix}"
CONTROLS_DIR = "controls"
CAMERA_VIDEO = "{camera}.mp4"  # a camera's video inside an episode folder (EPISODE_VIDEO)
EPISODE_CONTROL = EPISODE_DIR + "/" + CONTROLS_DIR + "/" + CONTROL_FILE

# A simulated episode in another look (tasks/transfer/apply.py, docs/transfer.md): each
# camera's generated video, the source's steps.parquet and meta.json copied unchanged, and
# TRANSFER_INFO (look, model, control weights). Never beside renders or generations. {look}
# is the look with spaces as dashes; {setting:.12} hashes the model's weights and the control
# weights, so two models or weightings of one look never overwrite each other's files.
TRANSFER_DIR = "transfer/{manifest_hash:.12}/episode_{index:06d}/{look}/{setting:.12}"
TRANSFER_VIDEO = TRANSFER_DIR + "/{camera}.mp4"
TRANSFER_INFO = "transfer.json"

CORPUS_VIDEO = "corpus/seed_{seed:06d}/raw_{index:04d}.mp4"
CORPUS_TRUTH = "corpus/seed_{seed:06d}/raw_{index:04d}.truth.json"

ANALYSIS_FILE = "analysis/{sha256:.2}/{sha256}-{config_hash:.16}.json"
CLIP_FILE = "clips/{source_id:.2}/{clip_id}.mp4"
SHARDS_OF_MANIFEST = "shards/{manifest_hash:.12}"
SHARD_DIR = SHARDS_OF_MANIFEST + "/{resolution}/{length}"
# Named by content (issue 26): two runs writing one bucket never overwrite each other's files,
# and a re-run of the same clips writes the same bytes under the same name.
SHARD_FILE = SHARD_DIR + "/part-{index:05d}-{sha256:.16}.parquet"
# The name shards had before issue 26; curate renames such files to SHARD_FILE when it starts.
LEGACY_SHARD_NAME = re.compile(r"part-(?P<index>\d{5})\.parquet")
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
# The camera-control evaluation of a world model (flows/camera_control.py): its table and report.
CAMERA_RESULT = "evaluations/{evaluation_id}/camera.json"
CAMERA_REPORT = "evaluations/{evaluation_id}/camera.md"
RIG_RESULT = "evaluations/{evaluation_id}/rig.json"
RIG_REPORT = "evaluations/{evaluation_id}/rig.md"
# A camera video's tokenizer codes (a cache the train flow may delete and rebuild).
EPISODE_CODES_FILE = "cache/episode_codes/{tokenizer_id:.12}/{video_sha256:.24}-{size}.npz"
# ... and a continuous tokenizer's latents (the diffusion world model's post-training).
EPISODE_LATENTS_FILE = "cache/episode_latents/{tokenizer_id:.12}/{video_sha256:.24}-{size}.npz"


# Manifests the loop derives from a panel's failing cells.
DERIVED_MANIFEST_FILE = "manifests/derived/{manifest_hash:.12}.yaml"


# Folders of the data root that hold inputs a user curates (footage `worldline corpus` makes).
INPUT_FOLDERS = ("corpus",)


def layout_folders() -> list[str]:
    """The data root's top-level folders, from the templates above (and Prefect's home, the
    quarantine and the reports)."""
    names = {PREFECT_DIR, QUARANTINE_DIR, "reports"}
    for name, value in globals().items():
        if name.isupper() and isinstance(value, str) and "/" in value and "{" not in value.split("/")[0]:
            names.add(value.split("/")[0])
    return sorted(names)


def output_folders(root: Path) -> list[Path]:
    """The folders where Worldline writes what it makes (clips, episodes, transfers, ...): a
    folder walked for videos to curate leaves them out, unless it is inside one of them."""
    return [Path(root) / name for name in layout_folders() if name not in INPUT_FOLDERS]


def resolve(root: Path, template: str, **fields) -> Path:
    return Path(root) / template.format(**fields)


def control_file(folder: Path, name: str, control: str) -> Path:
    """``folder/CONTROL_FILE``: control ``control`` of the video (or camera) ``name``."""
    return resolve(folder, CONTROL_FILE, name=name, control=control, suffix=CONTROL_SUFFIX[control])


def episode_control(episode_dir: Path, camera: str, control: str) -> Path:
    """EPISODE_CONTROL of the episode in ``episode_dir``."""
    return control_file(Path(episode_dir) / CONTROLS_DIR, camera, control)


def escaped(value):
    """``value`` with every undecodable filename byte written as a ``\\xff`` escape.

    A name that is not UTF-8 comes from the OS as a str holding lone surrogates
    ("surrogateescape"); neither DuckDB nor JSON nor a terminal takes those. Every path that
    enters a record or a message passes through here; the file itself is still opened by its
    real bytes. Strings, bytes and paths are escaped, dicts, lists and tuples item by item; anything
    else is returned as it is.
    """
    if isinstance(value, os.PathLike):
        value = os.fspath(value)
    if isinstance(value, bytes):
        return value.decode("utf-8", "backslashreplace")
    if isinstance(value, str):
        try:
            raw = value.encode("utf-8", "surrogateescape")
        except UnicodeEncodeError:  # a surrogate no OS name decodes to: escape it as it is
            raw = value.encode("utf-8", "backslashreplace")
        return raw.decode("utf-8", "backslashreplace")
    if isinstance(value, dict):
        return {escaped(k): escaped(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(escaped(v) for v in value)
    return value

"""A trained transfer model run on simulated episodes: each camera clip in another look, its
labels unchanged (`worldline transfer`, docs/transfer.md).

The controls are made as `tasks.transfer.pairs.make_pairs` makes them for training, at the
checkpoint's size: edges and blur by `frame_controls` of the camera's frames resized to that
size (here decoded from the episode's H.264 video, where training had the rendered frames),
depth and segmentation from the episode's `controls/` npz (`worldline simulate --controls`),
checked by `tasks.controls.check.check_controls` and resized nearest. A rendered control the
episode lacks is refused unless its weight is 0: a weight of 0 removes a control exactly, so
it then enters as zeros. The clip is made frame by frame from the model's own previous frame.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from models.transfer import ALL_CONTROLS, PROMPTS, TransferConfig, TransferNet
from schemas import paths
from schemas.hashing import stable_id
from tasks.checkpoint_files import CONFIG_FILE, WEIGHTS_FILE, CheckpointError, model_config, read_config
from tasks.controls.check import ControlError, check_controls
from tasks.controls.files import read_segmentation
from tasks.guard.config import GuardConfig
from tasks.guard.faces import FaceDecision, guard_frames
from tasks.integrity import uri_of
from tasks.transfer.pairs import PairClip, camera_clip, resize_frames
from tasks.transfer.train import CHECKPOINT_KEY, checkpoint_size, clip_look, look_row, pair_tensors
from tasks.video.read import display_frames, probe

# Part of every transfer stage's key: a change to how clips are made makes new files.
TRANSFER_VERSION = 1
RENDERED = {"depth": "depth", "segmentation": "seg"}  # control -> its npz in the episode's controls/
COPIED = ("steps.parquet", "meta.json")  # the labels, copied byte for byte


def parse_looks(text: str) -> tuple[str, ...]:
    """``look[,look...]`` -> the looks, each once; ValueError for one outside PROMPTS."""
    looks = tuple(dict.fromkeys(part.strip() for part in text.split(",") if part.strip()))
    if not looks:
        raise ValueError("no look given")
    for look in looks:
        if look not in PROMPTS:
            raise ValueError(f"unknown look {look!r}; known: {', '.join(PROMPTS)}")
    return looks


def parse_weights(text: str | None) -> dict[str, float]:
    """``edges=1,blur=0.5`` -> a weight per control of ALL_CONTROLS (1 where not given; a model
    reads those of its own controls)."""
    weights = dict.fromkeys(ALL_CONTROLS, 1.0)
    for part in filter(None, (p.strip() for p in (text or "").split(","))):
        name, eq, value = part.partition("=")
        name = name.strip()
        if name not in weights or not eq:
            raise ValueError(f"{part!r}: expected CONTROL=WEIGHT with CONTROL one of {', '.join(ALL_CONTROLS)}")
        try:
            weights[name] = float(value)
        except ValueError:
            raise ValueError(f"{part!r}: {value.strip()!r} is not a number") from None
        if not 0 <= weights[name] <= 100:
            raise ValueError(f"{part!r}: a weight is from 0 to 100")
    return weights


def look_slug(look: str) -> str:
    return look.replace(" ", "-")


def model_info(folder: Path | str) -> tuple[TransferConfig, dict]:
    """(architecture, config.json with ``size`` filled in by `checkpoint_size`) of a transfer
    checkpoint; CheckpointError in one line for any other folder."""
    folder = Path(folder)
    body = read_config(folder, CHECKPOINT_KEY, "transfer checkpoint")
    config = model_config(TransferConfig, body, CHECKPOINT_KEY, folder)
    if not (folder / WEIGHTS_FILE).is_file():
        raise CheckpointError(f"{folder}: no {WEIGHTS_FILE}")
    size = checkpoint_size(folder)
    if size % config.multiple:
        raise CheckpointError(f"{folder / CONFIG_FILE}: size {size} is not a multiple of {config.multiple}")
    return config, {**body, "size": size}


@dataclass(frozen=True)
class EpisodeSource:
    """One camera of one episode to transfer, and the rendered control files it reads."""

    folder: Path
    camera: str
    meta: dict
    controls: dict[str, Path]  # "depth" / "segmentation" -> npz, for weights above 0

    @property
    def video(self) -> Path:
        return self.folder / paths.CAMERA_VIDEO.format(camera=self.camera)


def episode_source(folder: Path, camera: str | None, weights: dict[str, float], default: str | None = None
                   ) -> EpisodeSource:
    """The camera (``camera``, else ``default`` when the episode has it, else its first) of the
    episode in ``folder``, its controls checked; ControlError in one line otherwise."""
    meta_file = folder / Path(paths.EPISODE_META).name
    try:
        meta = json.loads(meta_file.read_text())
        cameras = list(meta["cameras"])
    except (OSError, ValueError, KeyError, TypeError):
        raise ControlError(f"{folder}: not a finished episode (no readable {meta_file.name})") from None
    chosen = camera or (default if default in cameras else cameras[0])
    if chosen not in cameras:
        raise ControlError(f"{folder}: camera {chosen!r} is not one of the episode's ({', '.join(cameras)})")
    need = [c for c in RENDERED if weights[c] > 0]
    found = check_controls(folder, chosen) if need else {}
    if missing := [c for c in need if RENDERED[c] not in found]:
        raise ControlError(f"{folder}: no {missing[0]} control of camera {chosen!r} (run `worldline simulate "
                           f"--controls`, or give --weights {missing[0]}=0 to run without it)")
    return EpisodeSource(folder, chosen, meta, {c: found[RENDERED[c]] for c in need})


def source_clip(source: EpisodeSource, size: int) -> PairClip:
    """The episode camera's controls at ``size`` x ``size`` as training pairs hold them (zeros
    for a control that is not read), its frames resized as the clip's ``frames``."""
    depth, ids, legend = None, None, ()
    if "depth" in source.controls:
        with np.load(source.controls["depth"], allow_pickle=False) as npz:
            depth = npz["depth_mm"]
    if "segmentation" in source.controls:
        ids, legend = read_segmentation(source.controls["segmentation"])
    return camera_clip(np.stack(list(display_frames(source.video))), size, source.camera,
                       int(source.meta.get("seed", 0)), depth, ids, legend)


@torch.no_grad()
def generate(model: TransferNet, clip: PairClip, look: str, weights: dict[str, float],
             device: torch.device | str = "cpu", reference: torch.Tensor | None = None) -> np.ndarray:
    """The clip in ``look``: F x H x W x 3 uint8, frame by frame from the model's own previous
    frame; ``reference``: ``reference_look`` of a clip whose look it is to take, or None."""
    config = model.config
    controls, _ = pair_tensors(clip, config)
    prompt = torch.tensor([config.prompt_index(look)], device=device)
    w = torch.tensor([[weights[c] for c in config.controls]], dtype=torch.float32, device=device)
    ref = None if reference is None else reference.to(device)
    out = model(controls[None].to(device), prompt, w, reference=ref)[0].float().cpu()
    return out.add(1).mul(127.5).round().clamp(0, 255).to(torch.uint8).permute(1, 2, 3, 0).numpy()


def reference_look(video: Path | str, size: int, config: TransferConfig) -> torch.Tensor:
    """``1 x config.reference_size``: the look of a reference video's frames (display
    orientation) at ``size`` x ``size``, as the model saw its training clips. For a palette
    model, a reference that is a simulated episode's camera video with its segmentation
    control (`worldline simulate --controls`) also gives each class's mean colour; any other
    clip gives the clip-wide statistics alone, every class unknown."""
    video = Path(video)
    if config.palette and (clip := _segmented_episode(video, size)) is not None:
        return clip_look(config, clip)
    return look_row(config, resize_frames(np.stack(list(display_frames(video))), size))


def _segmented_episode(video: Path, size: int) -> PairClip | None:
    """The episode camera clip ``video`` is, with its segmentation, or None when it is not one."""
    camera = video.stem  # paths.CAMERA_VIDEO; checked below against the episode's own name for it
    weights = {**dict.fromkeys(ALL_CONTROLS, 0.0), "segmentation": 1.0}
    try:
        source = episode_source(video.parent, camera, weights)
    except ControlError:
        return None
    return source_clip(source, size) if source.video == video else None


def setting_id(model_sha: str, weights: dict[str, float], reference_sha: str | None = None) -> str:
    """What tells two transfers of one look apart: the model's weights, the control weights and
    the reference clip's bytes, if any."""
    return stable_id("transfer_setting", model_sha, json.dumps(weights, sort_keys=True),
                     *([reference_sha] if reference_sha else []))


def stage_key(video_sha: str, camera: str, look: str, setting: str, size: int) -> str:
    return stable_id("transfer", str(TRANSFER_VERSION), video_sha, camera, look, setting, str(size))


def output_paths(root: Path, source: EpisodeSource, look: str, setting: str) -> dict[str, Path]:
    """video, steps.parquet, meta.json and transfer.json of one transfer under TRANSFER_DIR."""
    fields = dict(manifest_hash=source.meta["manifest_hash"], index=int(source.meta["index"]), look=look_slug(look),
                  setting=setting)
    folder = paths.resolve(root, paths.TRANSFER_DIR, **fields)
    return {"video": paths.resolve(root, paths.TRANSFER_VIDEO, camera=source.camera, **fields),
            **{name: folder / name for name in COPIED}, "info": folder / paths.TRANSFER_INFO}


def write_labels(source: EpisodeSource, out: dict[str, Path], root: Path, info: dict) -> None:
    """The episode's step table and meta.json copied unchanged, and the transfer's own json
    (``info`` and the source episode's folder)."""
    out["info"].parent.mkdir(parents=True, exist_ok=True)
    for name in COPIED:
        shutil.copyfile(source.folder / name, out[name])
    body = {**info, "source": paths.escaped(uri_of(source.folder, root))}
    out["info"].write_text(json.dumps(body, indent=1, sort_keys=True))


def fps_of(video: Path) -> float:
    return probe(video).fps



def guarded_clip(model: TransferNet, clip: PairClip, look: str, weights: dict[str, float], guard: GuardConfig,
                 device: torch.device | str = "cpu", reference: torch.Tensor | None = None
                 ) -> tuple[np.ndarray, list[FaceDecision]]:
    """`generate`, then the face post-guard over the frames (as panels guard theirs before writing)."""
    frames = generate(model, clip, look, weights, device, reference)
    return guard_frames(frames, guard) if guard.enabled else (frames, [])

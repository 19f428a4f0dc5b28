"""Whether an episode's controls fit its camera video: frame count, frame size and camera.

The transfer step calls `check_controls` before it reads a control; each refusal is one line
naming the file (ControlError, exit 2 from the CLI).
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from schemas import paths
from schemas.errors import InvalidInput
from tasks.video.read import DecodeError, frame_pts, output_size, probe

ARRAYS = {"depth": "depth_mm", "seg": "ids"}


class ControlError(InvalidInput):
    """A control that does not fit its episode, in one line."""


def _video_shape(path: Path) -> tuple[int, int, int]:
    """(frames, height, width) of a video as display_frames decodes it."""
    try:
        width, height = output_size(probe(path))
        return int(frame_pts(path)[0].size), height, width
    except DecodeError as exc:
        raise ControlError(str(exc)) from None


def _npz_shape(path: Path, control: str) -> tuple[tuple[int, ...], str]:
    try:
        with np.load(path, allow_pickle=False) as npz:
            return npz[ARRAYS[control]].shape, str(npz["camera"])
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise ControlError(f"{path}: not a readable {control} control ({exc})") from None


def check_controls(episode_dir: Path | str, camera: str) -> dict[str, Path]:
    """The controls of ``camera`` in the episode folder (control name -> file), each checked to
    have the camera video's frame count and size and, for rendered ones, its camera; raises
    ControlError naming the first that does not, or when there are none."""
    episode_dir = Path(episode_dir)
    meta = episode_dir / Path(paths.EPISODE_META).name
    try:
        cameras = json.loads(meta.read_text())["cameras"]
    except (OSError, ValueError, KeyError):
        raise ControlError(f"{episode_dir}: not a finished episode (no readable {meta.name})") from None
    if camera not in cameras:
        raise ControlError(f"{episode_dir}: camera {camera!r} is not one of the episode's ({', '.join(cameras)})")
    video = episode_dir / paths.CAMERA_VIDEO.format(camera=camera)
    frames, height, width = _video_shape(video)
    found = {c: p for c in paths.CONTROL_SUFFIX if (p := paths.episode_control(episode_dir, camera, c)).is_file()}
    if not found:
        raise ControlError(f"{episode_dir}: no controls of camera {camera!r} "
                           f"(run `worldline simulate --controls` or `worldline controls`)")
    for control, path in found.items():
        if control in ARRAYS:
            shape, named = _npz_shape(path, control)
            if named != camera:
                raise ControlError(f"{path}: rendered for camera {named!r}, not {camera!r}")
            got = (shape[0], *shape[1:3]) if len(shape) == 3 else None
        else:
            got = _video_shape(path)
        if got is None:
            raise ControlError(f"{path}: {len(shape)}-d array, not frames x height x width")
        if got[0] != frames:
            raise ControlError(f"{path}: {got[0]} frames, the episode's {camera} video has {frames}")
        if got[1:] != (height, width):
            raise ControlError(f"{path}: {got[2]}x{got[1]} px, the episode's {camera} video is {width}x{height}")
    return found

"""Simulator footage for the raw corpus: one camera of a manifest's scene, rendered small."""

from __future__ import annotations

import cv2
import numpy as np

from schemas.manifest import ScenarioManifest
from tasks.sim.episode import rollout


def sim_segment(manifest: ScenarioManifest, seed: int, n_frames: int, width: int, height: int,
                camera: str | None = None, fps: float = 30.0, render_width: int = 480) -> np.ndarray:
    """n_frames x height x width x 3 uint8 RGB of the arm (or base) working, forklift included.

    Rendered at most `render_width` wide at the camera's aspect, then resized, so memory and
    time stay bounded whatever the output size; camera jitter is left to the manifest.
    """
    chosen = next((c for c in manifest.cameras if c.name == camera), manifest.cameras[0])
    rw = min(render_width, width)
    rh = max(16, round(rw * height / width)) // 2 * 2
    cam = chosen.model_copy(update={"resolution": (max(16, rw // 2 * 2), rh), "fps": fps})
    scenario = manifest.model_copy(update={"cameras": (cam,), "horizon_s": (n_frames + 0.5) / fps})
    frames = rollout(scenario, seed).frames[cam.name][:n_frames]
    if len(frames) < n_frames:  # pad with the last frame: rounding of the horizon, never more than one
        frames = np.concatenate([frames, np.repeat(frames[-1:], n_frames - len(frames), axis=0)])
    if frames.shape[1:3] == (height, width):
        return frames
    return np.stack([cv2.resize(f, (width, height), interpolation=cv2.INTER_LINEAR) for f in frames])

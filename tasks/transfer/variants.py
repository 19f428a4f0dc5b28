"""Vision demonstrations in other looks: the same steps, the camera frames made by a transfer model.

A vision policy's demonstrations (`tasks.policy.vision.collect`) hold, per control step, the
latest frame of each observed camera as the policy saw it (collection renders at the
`physics_only` cameras' 1 fps) and the proprioception and expert move. A transferred variant
keeps every step's proprioception and move and replaces one camera's frames by the transfer
model's output in a look (issue 32 point 6).

The controls are made as `tasks.transfer.pairs.make_pairs` makes them for training: the
demonstration's seed rolled out again with the manifest's cameras at their own fps and the
controls recorder (`tasks.controls.render.Recorder`: depth and segmentation of each frame),
edges and blur by `frame_controls` of those frames at the model's size. The scripted expert is
seeded, so the rollout is the demonstration's own (`check` compares the frames the policy saw
with the rollout's). The clip is generated free-running at the camera's fps, as the model was
trained, and each step takes the generated frame the policy would have seen then.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from models.transfer import TransferNet, reference_features
from schemas.manifest import ScenarioManifest
from tasks.controls.render import Recorder
from tasks.controls.video import frame_controls
from tasks.policy.bc import physics_only
from tasks.policy.vision import VisionDemonstrations
from tasks.policy.vision_obs import ObservationSpec
from tasks.sim.episode import rollout
from tasks.transfer.apply import generate
from tasks.transfer.pairs import PairClip, look_manifest, resize_frames, seg_classes
from tasks.transfer.train import frames_tensor


def frame_index(tau: np.ndarray, horizon_s: float, seen_fps: float, fps: float) -> np.ndarray:
    """Per step: the index, among a camera's frames at ``fps``, of the frame a policy observing
    at ``seen_fps`` shows, from the proprioception's time fraction ``tau`` (time / horizon, float32)."""
    t = np.asarray(tau, np.float64) * horizon_s
    seen = np.floor(t * seen_fps + 1e-3)  # float32 time: an exact frame time may read just below it
    return np.rint(seen / seen_fps * fps).astype(np.int64)


@dataclass(frozen=True)
class EpisodeClip:
    """One demonstration episode's camera clip at the model's size and the steps that see it."""

    clip: PairClip
    rows: np.ndarray  # row indices of the episode in the demonstrations
    index: np.ndarray  # per row, its frame in ``clip``
    mismatch: float  # mean absolute difference, 0-255, between the frames the policy saw and the clip's


def episode_clips(manifest: ScenarioManifest, demos: VisionDemonstrations, spec: ObservationSpec, camera: str,
                  size: int, rendered: bool = True) -> list[EpisodeClip]:
    """Each demonstrated episode's controls for ``camera``; ``rendered`` False: no depth and
    segmentation (zeros; to be given weight 0)."""
    if camera not in spec.cameras:
        raise ValueError(f"the demonstrations observe {', '.join(spec.cameras)}, not {camera!r}")
    c = spec.cameras.index(camera)
    cam = next(x for x in manifest.cameras if x.name == camera)
    seen_fps = next(x for x in physics_only(manifest).cameras if x.name == camera).fps
    out = []
    for k, seed in enumerate(demos.seeds):
        rows = np.flatnonzero(demos.episode == k)
        if not len(rows):
            continue  # a failed demonstration collect left out
        recorder = Recorder() if rendered else None
        ep = rollout(manifest, seed, on_frame=recorder)
        frames = resize_frames(ep.frames[camera], size)
        made = frame_controls(frames)
        shape = frames.shape[:3]
        depth, seg = np.zeros(shape, np.uint16), np.zeros(shape, np.uint8)
        if recorder is not None:
            r = recorder.rendered()
            depth = resize_frames(r.depth_mm[camera], size, nearest=True)
            seg = resize_frames(seg_classes(r.ids[camera], r.legend), size, nearest=True)
        index = np.minimum(frame_index(demos.proprio[rows, -1], manifest.horizon_s, seen_fps, cam.fps), len(frames) - 1)
        seen = resize_frames(demos.frames[rows, c].transpose(0, 2, 3, 1), size)
        mismatch = float(np.abs(seen.astype(np.int16) - frames[index].astype(np.int16)).mean())
        none = np.zeros((0, 0, 7))
        clip = PairClip(prompt="nominal", seed=seed, camera=camera, edges=made["edges"], blur=made["blur"],
                        depth_mm=depth, seg=seg, frames=frames, source_pose=none, target_pose=none)
        out.append(EpisodeClip(clip, rows, index, mismatch))
    return out


def transferred(demos: VisionDemonstrations, spec: ObservationSpec, clips: list[EpisodeClip], model: TransferNet,
                look: str, weights: dict[str, float], references: list[torch.Tensor] | None = None
                ) -> VisionDemonstrations:
    """The demonstrations' episodes in ``look``: every step as it was, the clips' camera frames
    generated by ``model`` (free-running per episode, at the camera's fps) and resized to the
    spec's image size; ``references``: per clip, `reference_look` features of a clip in
    ``look`` (a model trained with reference clips)."""
    c = spec.cameras.index(clips[0].clip.camera)
    frames = demos.frames.copy()
    for i, item in enumerate(clips):
        made = generate(model, item.clip, look, weights, reference=None if references is None else references[i])
        made = resize_frames(made, spec.image_size)
        frames[item.rows, c] = made[item.index].transpose(0, 3, 1, 2)
    return VisionDemonstrations(frames=frames, proprio=demos.proprio.copy(), act=demos.act.copy(),
                                episode=demos.episode.copy(), round=demos.round.copy(), seeds=demos.seeds,
                                successes=demos.successes)


def with_variants(demos: VisionDemonstrations, spec: ObservationSpec, clips: list[EpisodeClip], model: TransferNet,
                  looks: tuple[str, ...], weights: dict[str, float],
                  references: dict[str, list[torch.Tensor]] | None = None) -> VisionDemonstrations:
    """The demonstrations followed by their variant in each look (one thread, no gradient);
    ``references``: per look, per clip (see `transferred`)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        out = demos
        for look in looks:
            given = None if references is None else references[look]
            out = out + transferred(demos, spec, clips, model, look, weights, given)
        return out
    finally:
        torch.set_num_threads(threads)


def look_references(manifest: ScenarioManifest, seeds: list[int], camera: str, size: int, looks: tuple[str, ...]
                    ) -> dict[str, list[torch.Tensor]]:
    """Per look, per seed: `reference_features` of the camera's true render of ``seed`` in that look
    (`tasks.transfer.pairs.look_manifest`) at ``size``, for a model trained with reference clips."""
    out: dict[str, list[torch.Tensor]] = {}
    for look in looks:
        variant = look_manifest(manifest, look)
        out[look] = [reference_features(frames_tensor(resize_frames(rollout(variant, s).frames[camera], size))[None])
                     for s in seeds]
    return out


def mean_mismatch(clips: list[EpisodeClip]) -> float:
    return math.fsum(c.mismatch for c in clips) / max(1, len(clips))

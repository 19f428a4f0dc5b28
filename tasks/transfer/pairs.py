"""Paired training clips for the transfer model, free from the simulator.

The same manifest and seed rendered in its source look and under an appearance stressor has
the same geometry and motion: appearance (colour jitter, textures) draws from its own random
stream and dim light only scales the lights, so layout, controller and physics are untouched
(``tests/tasks/transfer/test_pairs.py`` checks the poses are identical). So the source
rollout's controls plus a prompt naming the look, against the stressed rollout's frames, is a
supervised pair. Stressors that change physics or the picture's geometry (distractors,
forklift, occluder, camera jitter) are kept as the parent has them in both rollouts, never
used as a look.

Controls are made at ``size`` x ``size`` from the source rollout: edges and blur with
`tasks.controls.video.frame_controls` (its Canny thresholds and blur), depth and segmentation
from `tasks.controls.render.Recorder`, resized (nearest for ids).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from schemas.manifest import Appearance, DimLight, ScenarioManifest
from schemas.panel import StressorCell, StressorGrid
from tasks.controls.render import Recorder
from tasks.controls.video import frame_controls
from tasks.panels.grid import primary_camera, variant_manifest
from tasks.sim.episode import rollout

LOOK_KINDS = ("appearance", "dim_light")
# Prompt -> the stressors that render it (models.transfer.PROMPTS lists the same names).
# "nominal" is the source look itself: no appearance or dim-light stressor.
LOOKS: dict[str, tuple] = {
    "nominal": (),
    "dim": (DimLight(lux=200),),
    "very dim": (DimLight(lux=80),),  # the panels' dim cell
    "colour shift": (Appearance(colour_jitter=0.3, texture=False),),
    "textures": (Appearance(colour_jitter=0.1, texture=True),),
}
# Segmentation one-hot classes: legend names grouped into a fixed set, so scenes with
# different legends share channels. Anything not listed is "other".
SEG_GROUPS: tuple[tuple[str, ...], ...] = (
    ("background",), ("package",), ("robot",), ("table", "floor", "bin"), ("goal",),
)
SEG_CLASSES = len(SEG_GROUPS) + 1
# One class per object the scenes name: what a palette model's colours are drawn over
# (`TransferConfig.seg_groups: objects`). SEG_GROUPS puts table and floor in one class, whose
# colours a colour shift draws apart: one gain per class then recovers 21 dB of a colour-shifted
# render, one per object 54 dB (push_closeup, seeds 25 and 40).
OBJECT_GROUPS: tuple[tuple[str, ...], ...] = (
    ("background",), ("package",), ("robot",), ("table",), ("floor",), ("bin",), ("goal",),
)
OBJECT_CLASSES = len(OBJECT_GROUPS) + 1


@dataclass(frozen=True)
class PairClip:
    """One camera of one seed in one look. Source controls: ``edges`` F x H x W uint8 {0, 255},
    ``blur`` F x H x W x 3 uint8, ``depth_mm`` F x H x W uint16, ``seg`` F x H x W uint8 class
    in [0, SEG_CLASSES), ``source_frames`` F x H x W x 3 uint8 (the source look's own frames: the
    ``frame`` control, a blur of sigma 0; None where a clip was made without them); target
    ``frames`` F x H x W x 3 uint8 in the look ``prompt``."""

    prompt: str
    seed: int
    camera: str
    edges: np.ndarray
    blur: np.ndarray
    depth_mm: np.ndarray
    seg: np.ndarray
    frames: np.ndarray
    source_pose: np.ndarray
    target_pose: np.ndarray
    source_frames: np.ndarray | None = None
    objects: np.ndarray | None = None  # F x H x W OBJECT_GROUPS classes (None: made without them)


def source_manifest(parent: ScenarioManifest) -> ScenarioManifest:
    """The parent without its look stressors: the rollout the controls come from."""
    grid = StressorGrid(name="transfer", cells=(StressorCell(name="source", drop=LOOK_KINDS),))
    return variant_manifest(parent, grid, grid.cells[0])


def look_manifest(parent: ScenarioManifest, prompt: str) -> ScenarioManifest:
    """The source manifest rendered in the look ``prompt``."""
    if prompt not in LOOKS:
        raise ValueError(f"unknown look {prompt!r}; known: {', '.join(LOOKS)}")
    name = prompt.replace(" ", "-")
    stressors = LOOKS[prompt]
    drop = tuple(k for k in LOOK_KINDS if k not in {s.kind for s in stressors})  # a set stressor replaces its kind
    grid = StressorGrid(name="transfer", cells=(StressorCell(name=name, drop=drop, stressors=stressors),))
    return variant_manifest(parent, grid, grid.cells[0])


def seg_classes(ids: np.ndarray, legend: tuple[str, ...], groups: tuple[tuple[str, ...], ...] = SEG_GROUPS
                ) -> np.ndarray:
    """Legend ids -> ``groups`` classes (the last class for names in no group)."""
    table = np.full(len(legend), len(groups), np.uint8)
    for i, name in enumerate(legend):
        for k, group in enumerate(groups):
            if name in group:
                table[i] = k
    return table[ids]


def resize_frames(stack: np.ndarray, size: int, nearest: bool = False) -> np.ndarray:
    if stack.shape[1:3] == (size, size):
        return stack
    how = cv2.INTER_NEAREST if nearest else cv2.INTER_AREA
    return np.stack([cv2.resize(f, (size, size), interpolation=how) for f in stack])


def depth_signal(depth_mm: np.ndarray) -> np.ndarray:
    """uint16 millimetres ``... x H x W`` -> float32 in [-1, 1]: near -1, the clip's farthest
    depth (and nothing, 0) 1. One scale per clip, so depth does not flicker."""
    d = depth_mm.astype(np.float32)
    far = float(d.max()) or 1.0
    d = np.where(d == 0, far, d)
    return d / far * 2 - 1


def camera_clip(frames: np.ndarray, size: int, camera: str, seed: int, depth_mm: np.ndarray | None = None,
                ids: np.ndarray | None = None, legend: tuple[str, ...] = ()) -> PairClip:
    """A camera's frames (F x H x W x 3, any size) as a source-look PairClip at ``size``: edges
    and blur by `frame_controls` of the resized frames, depth (millimetres) and segmentation ids
    (with their ``legend``) resized nearest, zeros where not given; the frames are its target
    and its ``source_frames``. How training pairs, `worldline transfer` and demonstration
    variants all make a model's input."""
    small = resize_frames(frames, size)
    made = frame_controls(small)
    shape = small.shape[:3]
    depth = np.zeros(shape, np.uint16) if depth_mm is None else resize_frames(depth_mm, size, nearest=True)
    seg = np.zeros(shape, np.uint8) if ids is None else resize_frames(seg_classes(ids, legend), size, nearest=True)
    objects = np.zeros(shape, np.uint8) if ids is None else resize_frames(seg_classes(ids, legend, OBJECT_GROUPS), size,
                                                                           nearest=True)
    none = np.zeros((0, 0, 7))
    return PairClip(prompt="nominal", seed=seed, camera=camera, edges=made["edges"], blur=made["blur"], depth_mm=depth,
                    seg=seg, frames=small, source_pose=none, target_pose=none, source_frames=small, objects=objects)


def make_pairs(parent: ScenarioManifest, seeds: list[int] | tuple[int, ...], prompts: tuple[str, ...] = tuple(LOOKS),
               size: int = 64, camera: str | None = None, horizon_s: float | None = None) -> list[PairClip]:
    """One PairClip per seed and prompt, for ``camera`` (default: the primary camera).
    ``horizon_s`` shortens the episodes (tests)."""
    if horizon_s is not None:
        parent = parent.model_copy(update={"horizon_s": horizon_s})
    camera = primary_camera(parent, camera)
    source_look = source_manifest(parent)
    pairs: list[PairClip] = []
    for seed in seeds:
        recorder = Recorder()
        nominal = rollout(source_look, seed, on_frame=recorder)
        rendered = recorder.rendered()
        source = camera_clip(nominal.frames[camera], size, camera, seed, rendered.depth_mm[camera],
                             rendered.ids[camera], rendered.legend)
        for prompt in prompts:
            episode = nominal if prompt == "nominal" else rollout(look_manifest(parent, prompt), seed)
            pairs.append(dataclasses.replace(source, prompt=prompt, frames=resize_frames(episode.frames[camera], size),
                                             source_pose=nominal.object_pose, target_pose=episode.object_pose))
    return pairs

"""Held-out episodes for the physics evaluation: the simulator's truth, code windows, and the
world model's predictions decoded back to frames.

`render_truth` replays a rollout exactly as `tasks.sim.episode.rollout` renders it (the same
scene, controller and capture instants) and adds, per frame of one camera, the package's
segmentation mask and position. `prepare` encodes an episode with the tokenizer and fits the
colour models; `predict` rolls the world model out from every window with the true actions
and with actions from another window, and decodes everything to `physics.Window`s. No
files, no Prefect.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

import tasks.sim  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
from models.tokenizer import VideoTokenizer
from models.world_model import WorldModel
from schemas.manifest import ScenarioManifest
from tasks.sim.episode import Simulation
from tasks.sim.render import MultiCameraRenderer
from tasks.sim.scene import SimConfig, build_scene
from tasks.tokenize.data import square
from tasks.tokenize.train import to_uint8
from tasks.world import physics
from tasks.world.data import align_actions, encode_frames
from tasks.world.geometry import PinholeCamera


@dataclass(frozen=True)
class Truth:
    """One camera of one episode: frames ``F x H x W x 3`` uint8 (bit-identical to the
    rollout's), package masks ``F x H x W`` bool (from the segmentation render; None for a
    camera whose frames are only compared between views), the package
    body's position ``F x 3`` (m) at each frame, its top face's height at rest (m), and the
    control steps' start times ``T`` (s) and actions ``T x A``."""

    camera: str
    fps: float
    frames: np.ndarray
    masks: np.ndarray | None
    package_xyz: np.ndarray
    top_z: float
    step_time: np.ndarray
    action: np.ndarray


def render_truth(manifest: ScenarioManifest, seed: int, camera: str, config: SimConfig = SimConfig()) -> Truth:
    """Replay `rollout(manifest, seed)` rendering `camera` with the package's segmentation."""
    cam = next((c for c in manifest.cameras if c.name == camera), None)
    if cam is None:
        raise ValueError(f"manifest {manifest.name} has no camera {camera!r}")
    if manifest.stressor("camera_jitter"):
        raise ValueError(f"manifest {manifest.name}: camera jitter moves the picture at render time, "
                         "which the segmentation render does not follow")
    scene = build_scene(manifest, seed, config)
    sim = Simulation(scene, seed)
    model = sim.model
    body, geom = model.body(scene.objects[0]).id, model.geom(f"{scene.objects[0]}_geom").id
    n = int(math.floor(manifest.horizon_s * cam.fps + 1e-9))
    w, h = cam.resolution
    frames, masks, xyz = np.zeros((n, h, w, 3), np.uint8), np.zeros((n, h, w), bool), np.zeros((n, 3))
    taken = [0]
    with MultiCameraRenderer(model, {camera: (w, h)}) as renderer:
        def capture(data) -> None:
            j = taken[0]
            if j < n and data.time >= j / cam.fps - 1e-9:
                frames[j] = renderer.render(data, camera)
                masks[j] = renderer.segment(data, camera) == geom
                xyz[j] = data.xpos[body]
                taken[0] = j + 1

        capture(sim.data)
        steps = round(manifest.horizon_s * config.control_hz)
        actions = [sim.advance(capture) for _ in range(steps)]
    return Truth(camera=camera, fps=float(cam.fps), frames=frames, masks=masks, package_xyz=xyz,
                 top_z=float(xyz[0, 2] + scene.target_half[2]), step_time=np.arange(steps) / config.control_hz,
                 action=np.array(actions))


@dataclass(frozen=True)
class Prepared:
    """An episode's camera at the world model's size: frames ``N x S x S x 3`` (N = 1 + t k
    frames the tokenizer takes), their codes ``T' x H' x W'`` (a continuous tokenizer's latents
    ``T' x C x H' x W'`` for a diffusion world model), its reconstruction, aligned
    actions ``(T' - 1) x F``, package coverage and position per frame, the colour models of
    true and decoded frames (None where the package cannot be found reliably) and the camera."""

    key: str
    frames: np.ndarray
    codes: np.ndarray
    recon: np.ndarray
    actions: np.ndarray
    cover: np.ndarray | None
    package_xyz: np.ndarray
    top_z: float
    camera: PinholeCamera
    true_colour: physics.ColourModel | None
    decoded_colour: physics.ColourModel | None
    text: str
    fit_iou: dict = field(default_factory=dict)  # "true" / "decoded": the fitted IoU, kept or not


@torch.no_grad()
def decode(tokenizer: VideoTokenizer, codes: np.ndarray | torch.Tensor) -> np.ndarray:
    """Codes ``T' x H' x W'`` (a discrete tokenizer) or latents ``T' x C x H' x W'`` (a
    continuous one) -> frames ``(1 + t (T' - 1)) x S x S x 3`` uint8."""
    if tokenizer.config.variant == "continuous":
        latents = torch.as_tensor(codes, dtype=torch.float32).transpose(0, 1)[None]
        return to_uint8(tokenizer.eval().decode(latents)[0])
    codes = torch.as_tensor(codes, dtype=torch.int64)[None]
    return to_uint8(tokenizer.eval().decode(codes)[0])


def encode(tokenizer: VideoTokenizer, frames: np.ndarray, size: int) -> np.ndarray:
    """Frames -> codes ``T' x H' x W'`` (discrete) or latents ``T' x C x H' x W'`` (continuous)."""
    if tokenizer.config.variant == "continuous":
        from tasks.world.diffusion import encode_latents

        return encode_latents(tokenizer, frames, size)
    return encode_frames(tokenizer, frames, size)


def prepare(key: str, truth: Truth, camera: PinholeCamera, tokenizer: VideoTokenizer, size: int, action_dim: int,
            text: str, min_fit_iou: float = 0.5, totals: int = 0) -> Prepared:
    """Encode and reconstruct the episode, align its actions, fit both colour models.

    A colour model whose fit IoU on its own episode is below `min_fit_iou` is dropped: the
    package is then too close in colour to something else in this scene to be tracked. The
    decoded frames' model is fitted on the frames that show at least half the package
    (`physics.MIN_VISIBLE`): a decoder does not keep the slivers the arm leaves visible.
    """
    t = tokenizer.config.temporal_compression
    codes = encode(tokenizer, truth.frames, size)
    n = 1 + (codes.shape[0] - 1) * t
    frames = square(truth.frames[:n], size)
    recon = decode(tokenizer, codes)
    cover = None if truth.masks is None else physics.coverage(truth.masks[:n], size)
    actions = align_actions(truth.step_time, truth.action, np.arange(n) / truth.fps, t, codes.shape[0], action_dim,
                            totals)

    fits = {}

    def fit(name, source, min_visible=0.0):
        model = None if cover is None else physics.fit_colour_model(source, cover, min_visible=min_visible)
        fits[name] = None if model is None else model.fit_iou
        return model if model is not None and model.fit_iou >= min_fit_iou else None

    return Prepared(key=key, frames=frames, codes=codes, recon=recon, actions=actions, cover=cover,
                    package_xyz=truth.package_xyz[:n], top_z=truth.top_z, camera=camera.square(size),
                    true_colour=fit("true", frames), decoded_colour=fit("decoded", recon, physics.MIN_VISIBLE), text=text, fit_iou=fits)


def window_starts(latent_frames: int, context: int, horizon: int, stride: int) -> list[int]:
    """First latent frame of every window of `context` + `horizon` latent frames, `stride` apart."""
    return list(range(0, latent_frames - context - horizon + 1, stride))


def _rollout(world_model, context: np.ndarray, horizon: int, text: list[str], actions: np.ndarray,
             sampler_steps: int, seed: int) -> torch.Tensor:
    """A batch of windows rolled out: codes ``B x c x H' x W'`` by the autoregressive model
    (greedy), or latents ``B x c x C x H' x W'`` by the diffusion one (``sampler_steps`` Euler
    steps from noise drawn with ``seed`` on the CPU), in the layout they came in."""
    from models.diffusion_world import DiffusionWorldModel

    if isinstance(world_model, DiffusionWorldModel):
        generator = torch.Generator().manual_seed(seed)
        out = world_model.eval().rollout(torch.from_numpy(context).transpose(1, 2), horizon, text=text,
                                         actions=torch.from_numpy(actions), steps=sampler_steps, generator=generator)
        return out.transpose(1, 2)
    return world_model.eval().rollout(torch.from_numpy(context), horizon, text=text, actions=torch.from_numpy(actions))


@torch.no_grad()
def predict(world_model: WorldModel, tokenizer: VideoTokenizer, episodes: list[Prepared], context: int, horizon: int,
            stride: int, move_threshold_m: float = 0.02, shuffle_seed: int = 0,
            batch: int = 16, sampler_steps: int = 8) -> list[physics.Window]:
    """Every window of every episode: the model's rollout of `horizon` latent frames after
    `context` true ones, with the true actions and with shuffled ones (`physics.shuffle_actions`
    over all windows), decoded after the episode's true codes up to the context. A diffusion
    world model (``Prepared.codes`` then holds latents) samples with ``sampler_steps`` steps, the
    true and the shuffled actions' windows from the same noise (so only the actions differ)."""
    t = tokenizer.config.temporal_compression
    spans = [(e, s) for e in episodes for s in window_starts(e.codes.shape[0], context, horizon, stride)]
    if not spans:
        return []
    rows = context - 1 + horizon
    true_actions = np.stack([e.actions[s:s + rows] for e, s in spans])
    shuffled = physics.shuffle_actions(true_actions, context - 1, shuffle_seed)
    predicted = {}
    for name, acts in (("model", true_actions), ("shuffled", shuffled)):
        out = []
        for i in range(0, len(spans), batch):
            part = spans[i:i + batch]
            ctx = np.stack([e.codes[s:s + context] for e, s in part])
            out.append(_rollout(world_model, ctx, horizon, [e.text for e, _ in part], acts[i:i + batch],
                                sampler_steps, i))
        predicted[name] = torch.cat(out).numpy()
    windows = []
    for i, (e, s) in enumerate(spans):
        last = t * (s + context - 1)  # video frame of the last context frame
        future = slice(last + 1, last + 1 + t * horizon)
        outputs = {"ceiling": e.recon[future]}
        for name, codes in predicted.items():
            outputs[name] = decode(tokenizer, np.concatenate([e.codes[:s + context], codes[i]]))[future]
        shift = np.linalg.norm(e.package_xyz[future, :2] - e.package_xyz[last, :2], axis=1)
        windows.append(physics.Window(key=f"{e.key}@{last}", true=e.frames[future], outputs=outputs,
                                      context_last=e.recon[last], camera=e.camera, plane_z=e.top_z,
                                      moved=bool(shift.max() >= move_threshold_m), true_colour=e.true_colour,
                                      decoded_colour=e.decoded_colour,
                                      info={"episode": e.key, "last_context_frame": last,
                                            "moved_m": float(shift.max()), "fit_iou": e.fit_iou}))
    return windows

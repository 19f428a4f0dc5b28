"""A vision policy evaluated inside a world model (closed loop), and what is refused first.

`tasks.panels.closed_loop` drives a world model with any ``(frame, time_s) -> action``
callable. A vision policy also needs proprioception, which a world model does not generate.
It comes from the robot's kinematic twin: the cell's scene at the episode's seed, stepped
with the policy's own commands, in which every object (the package, distractors) and the
forklift are out of contact, so nothing they do reaches the arm. Only the arm's state, what
`tasks.policy.vision_obs.proprio` reads, leaves the twin; its frames are never rendered. The
policy's frames are the world model's decoded ones, downscaled as `Observer` downscales a
render. Its action at each control step is the one `ArmController.apply` returns in the twin,
which is the action the simulator records for the same command (`tasks.sim.episode.rollout`),
so the world model gets actions in the layout it was post-trained on.

The arm in the twin meets no package, so where the real arm would be held back by one, the
twin's arm moves freely: proprioception from the twin is what the robot commanded, not what
the world made of it (the world model shows that, in the frames).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

import tasks.sim  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
import mujoco
from schemas.manifest import ScenarioManifest
from tasks.panels.closed_loop import ClosedLoopRequest, closed_loop
from tasks.panels.detect import judge_frames
from tasks.panels.world import world_text
from tasks.policy.vision import VisionPolicy, _Learner
from tasks.policy.vision_obs import proprio, proprio_size
from tasks.sim.control import ArmController
from tasks.sim.scene import Scene, SimConfig, build_scene

if TYPE_CHECKING:
    from tasks.policy.evaluate import Rollout

TWIN_VERSION = 1  # what the policy sees in closed loop; enters the evaluation's id


def _moving_bodies(scene: Scene) -> set[int]:
    """Ids of every body in the subtree of an object or of the forklift."""
    m = scene.model
    roots = {m.body(name).id for name in scene.objects}
    if scene.manifest.stressor("forklift_crossing"):
        roots.add(m.body("forklift").id)
    out = set()
    for body in range(m.nbody):  # a body's parents have lower ids
        if body in roots or int(m.body_parentid[body]) in out:
            out.add(body)
    return out


class KinematicTwin:
    """The robot alone: ``variant``'s scene at ``seed`` with objects and the forklift out of
    contact, stepped at the simulator's control rate."""

    def __init__(self, variant: ScenarioManifest, seed: int, config: SimConfig = SimConfig()):
        self.scene = build_scene(variant, seed, config)
        m = self.model = self.scene.model
        moving = _moving_bodies(self.scene)
        for geom in range(m.ngeom):
            if int(m.geom_bodyid[geom]) in moving:
                m.geom_contype[geom] = m.geom_conaffinity[geom] = 0
        self.data = mujoco.MjData(m)
        self.data.qpos[:] = self.scene.initial_qpos
        self.data.ctrl[:] = self.scene.initial_ctrl
        mujoco.mj_forward(m, self.data)
        # As tasks.sim.episode.Simulation steps it.
        self.substeps = max(1, round(1.0 / (config.control_hz * config.timestep)))

    def step(self) -> None:
        for _ in range(self.substeps):
            mujoco.mj_step(self.model, self.data)


class _TwinLearner(_Learner):
    """The vision policy's actuation (`_Learner.act` and `apply`), without its renderer."""

    def __init__(self, policy: VisionPolicy, scene: Scene, seed: int):
        self.arm = ArmController(scene, seed, noise=0.0)
        if proprio_size(self.arm) != policy.model.config.proprio_size:
            raise ValueError(f"policy expects {policy.model.config.proprio_size} proprioceptive values; this robot "
                             f"gives {proprio_size(self.arm)}")
        self.model, self.observer = policy.model, None

    def close(self) -> None:
        pass


class TwinDriven:
    """A vision policy as a `tasks.panels.closed_loop.FramePolicy`: the frame from the world
    model, proprioception from the kinematic twin, which then takes the chosen action."""

    def __init__(self, policy: VisionPolicy, variant: ScenarioManifest, seed: int, config: SimConfig = SimConfig()):
        self.size = policy.spec.image_size
        self.twin = KinematicTwin(variant, seed, config)
        self.learner = _TwinLearner(policy, self.twin.scene, seed)
        self.learner.reset(self.twin.data)
        self.dt = 1.0 / config.control_hz

    def observe(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(1 x 3 x S x S uint8 frames, proprioception) as the policy gets them now."""
        if frame.shape[:2] != (self.size, self.size):
            frame = cv2.resize(frame, (self.size, self.size), interpolation=cv2.INTER_AREA)
        return np.ascontiguousarray(frame.transpose(2, 0, 1))[None], proprio(self.twin.data, self.learner.arm)

    def __call__(self, frame: np.ndarray, time_s: float) -> np.ndarray:
        if abs(self.twin.data.time - time_s) > self.dt / 2:
            raise ValueError(f"the twin is at {self.twin.data.time:.3f} s; asked for an action at {time_s:.3f} s")
        action = self.learner.apply(self.twin.data, self.learner.act(*self.observe(frame)))
        self.twin.step()
        return action


def drive_problem(policy, camera: str) -> str | None:
    """Why ``policy`` cannot be driven by a world model generating ``camera``; None if it can."""
    if not isinstance(policy, VisionPolicy):
        return (f"policy {policy.name} reads the simulator's state, not frames; only vision policies "
                "(vision:PATH or vision:ID) can be driven by a world model")
    cams = policy.spec.cameras
    if cams != (camera,):
        return (f"policy {policy.name} sees camera(s) {', '.join(cams)}; the world model generates {camera} "
                "only, so only a policy that sees that one camera can be driven by it")
    return None


def closed_loop_verdict(world_model: str, variant: ScenarioManifest, camera: str, done: "Rollout",
                        policy: VisionPolicy, seed: int, root: Path,
                        device: str | None = None) -> tuple[bool | None, str]:
    """The policy drives the world model from the episode's first true frame to the horizon;
    the frame detector judges the generated frames, as `tasks.policy.evaluate.world_verdict`
    judges an open-loop rollout."""
    cam = next(c for c in variant.cameras if c.name == camera)
    request = ClosedLoopRequest(camera=camera, context=done.context, control_hz=done.control_hz, fps=cam.fps,
                                frames=int(variant.horizon_s * cam.fps + 1e-9), text=world_text(variant))
    result = closed_loop(world_model, request, TwinDriven(policy, variant, seed), root, device=device)
    verdict = judge_frames(result.frames, cam, variant.evaluation, done.package_start, reference=done.context[0])
    return verdict.success, verdict.reason


def action_width(manifest: ScenarioManifest) -> int:
    """Values per control step in the manifest's action layout (`tasks.sim.control`)."""
    if manifest.embodiment.kind != "arm":
        return 3 if manifest.embodiment.action_space == "twist" else 2
    return 7 if manifest.embodiment.action_space == "joint_position" else 5


def world_model_mismatch(folder: Path | str, manifest: ScenarioManifest, camera: str, root: Path,
                         driven: bool = False) -> str | None:
    """What in a world-model checkpoint does not fit the panel of ``manifest`` seen through
    ``camera``, in words (None: nothing): the camera it was post-trained on, its tokenizer,
    and the action layout; with ``driven``, also that it takes actions at all. Reads the
    configs (and one training episode's step table when it is still there), no weights. Either
    family (``tasks.world.family``): a diffusion model's tokenizer must be continuous, with its
    latent channels; closed loop (``driven``) drives autoregressive models only."""
    from models.tokenizer import TokenizerConfig
    from tasks.checkpoint_files import CheckpointError, model_config, read_config
    from tasks.world.data import read_steps
    from tasks.world.family import DIFFUSION, family_of, read_world_config
    from tasks.world.family import model_config as world_config

    try:
        body = read_world_config(Path(folder))
        config = world_config(folder, body)
        tok_path = Path(body.get("tokenizer", ""))
        tok_path = tok_path if tok_path.is_absolute() else Path(root) / tok_path
        tok = model_config(TokenizerConfig, read_config(tok_path, "tokenizer", "tokenizer checkpoint"), "tokenizer",
                           tok_path)
    except CheckpointError as exc:
        return str(exc)
    trained_on = body.get("camera")
    if trained_on and trained_on != camera:
        return f"it was post-trained on camera {trained_on}; the panel's camera is {camera}"
    if family_of(body) == DIFFUSION:
        reads = (tok.variant, tok.latent_channels, tok.temporal_compression)
        if reads != ("continuous", config.latent_channels, config.temporal_compression):
            return (f"its tokenizer {tok_path} is {tok.variant} with {tok.code_channels} channels and temporal "
                    f"compression {tok.temporal_compression}; the diffusion model reads continuous latents of "
                    f"{config.latent_channels} channels and {config.temporal_compression}")
        if driven:
            return ("it is a diffusion world model; closed loop ({in_world_model}) drives autoregressive world "
                    "models only")
    elif (tok.codebook_size, tok.temporal_compression) != (config.codebook_size, config.temporal_compression):
        return (f"its tokenizer {tok_path} has codebook {tok.codebook_size} and temporal compression "
                f"{tok.temporal_compression}; the model reads codebook {config.codebook_size} and "
                f"{config.temporal_compression}")
    width, space = action_width(manifest), f"{manifest.embodiment.kind} {manifest.embodiment.action_space}"
    if config.action_conditioned and width + config.action_totals > config.action_dim:
        return (f"the panel's robot ({space}) gives {width} action values a step (+ {config.action_totals} totals); "
                f"the model takes {config.action_dim}")
    for uri in body.get("episodes", [])[:1]:
        try:
            trained = read_steps(Path(root) / uri)[1].shape[1]
        except (OSError, ValueError):  # the training episodes are gone: nothing left to compare
            break
        if trained != width:
            return (f"it was post-trained on actions of {trained} values a step; the panel's robot ({space}) "
                    f"gives {width}")
    if driven and not config.action_conditioned:
        return "it is not action-conditioned, so no policy can drive it (post-train it on episodes first)"
    return None

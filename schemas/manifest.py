"""ScenarioManifest: the contract every artifact is keyed by (via `manifest_hash`)."""

from __future__ import annotations

import math
import re
from functools import cached_property
from pathlib import PurePosixPath
from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_serializer, model_validator

from schemas import SCHEMA_VERSION
from schemas.hashing import content_hash

Vec3 = tuple[float, float, float]
# Bounds that keep a hostile or mistyped manifest from asking for absurd work.
MAX_SIDE = 4096
MAX_FPS = 240
MAX_HORIZON_S = 3600.0
# Where a drive task's waypoints may lead the base's centre (tasks/sim/scene.py): along the aisle
# between the rack runs (x from -2 to 8 m), clear of the racks' inner faces at |y| = 1.0 m by the
# chassis half width with its wheels (0.3 m) and a 0.1 m margin.
AISLE_X_M = (-1.5, 7.5)
AISLE_HALF_WIDTH_M = 0.6
# Two cameras on the same mount closer than this, looking along directions closer than this
# (difference of the unit view directions), have one pose: they would record the same view.
SAME_POSITION_M = 1e-3
SAME_DIRECTION = 1e-3
# The fewest frames the horizon must give every camera (ScenarioManifest._horizon_films_every_camera).
MIN_CAMERA_FRAMES = 2
# The rate `worldline simulate` steps the controller at (tasks/sim/scene.py SimConfig.control_hz,
# tests/schemas/test_manifest.py keeps the two equal): an episode needs one step at least.
CONTROL_HZ = 50.0


def camera_frames(horizon_s: float, fps: float) -> int:
    """The frames an episode of ``horizon_s`` records of a camera at ``fps``: the count
    tasks/sim/episode.py `rollout` renders and writes."""
    return int(math.floor(horizon_s * fps + 1e-9))


class FieldError(ValueError):
    """A validation error about one field below the validator's own: ``field`` is its dotted path
    (``cameras.1.name``) relative to the model that raised it. `tasks.manifests.validated` puts it
    in the error's location, so the one line names the field itself."""

    def __init__(self, field: str, problem: str):
        super().__init__(f"{field}: {problem}")
        self.field, self.problem = field, problem


class Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


def check_relative_path(value: str | None) -> str | None:
    """Paths inside manifests are relative and may not climb out of their root."""
    if value is None:
        return value
    if "\0" in value:
        raise ValueError("path contains a NUL byte")
    path = PurePosixPath(value.replace("\\", "/"))
    if not path.parts:
        raise ValueError("path is empty")
    if path.is_absolute() or value.startswith("~") or ":" in path.parts[0]:
        raise ValueError(f"path {value!r} must be relative")
    if ".." in path.parts:
        raise ValueError(f"path {value!r} climbs out of its root with '..'")
    return value


class Camera(Frozen):
    """A named camera: pose (position looking at a point), resolution and frame rate."""

    name: str = Field(pattern=r"^[a-z][a-z0-9_]{0,31}$")
    mount: Literal["world", "wrist", "vehicle"] = "world"
    position: Vec3
    look_at: Vec3 = (0.0, 0.0, 0.0)
    fovy_deg: float = Field(45.0, gt=5, lt=170)
    resolution: tuple[Annotated[int, Field(ge=16, le=MAX_SIDE)], Annotated[int, Field(ge=16, le=MAX_SIDE)]]
    fps: float = Field(30.0, gt=0, le=MAX_FPS)

    @model_validator(mode="after")
    def _looks_somewhere(self) -> "Camera":
        if self.position == self.look_at:
            raise ValueError("camera position and look_at coincide")
        return self


def same_pose(a: Camera, b: Camera) -> bool:
    """Positions within SAME_POSITION_M and unit view directions within SAME_DIRECTION
    (a look_at farther along the same ray is the same pose)."""
    if max(abs(p - q) for p, q in zip(a.position, b.position)) > SAME_POSITION_M:
        return False
    views = []
    for cam in (a, b):
        d = [t - p for t, p in zip(cam.look_at, cam.position)]
        norm = sum(v * v for v in d) ** 0.5
        views.append([v / norm for v in d])
    return sum((u - v) ** 2 for u, v in zip(*views)) ** 0.5 <= SAME_DIRECTION


class Rig(Frozen):
    """Several cameras recorded as one video: their frames tiled in ``layout`` (rows of camera
    names, each row as wide as the others), so a world model trained on the rig's video
    generates every view together (issue 33 point 4). The cameras must share resolution and fps."""

    name: str = Field(pattern=r"^[a-z][a-z0-9_]{0,31}$")
    layout: tuple[tuple[str, ...], ...] = Field(min_length=1, max_length=4)

    @field_validator("layout")
    @classmethod
    def _rectangular(cls, value: tuple[tuple[str, ...], ...]) -> tuple[tuple[str, ...], ...]:
        widths = {len(row) for row in value}
        if len(widths) != 1 or 0 in widths:
            raise ValueError(f"rows of {sorted(widths)} cameras: every row of the layout needs the same number")
        if max(widths) > 4:
            raise ValueError("at most 4 cameras a row")
        names = [n for row in value for n in row]
        if len(names) < 2:
            raise ValueError("a rig tiles at least two cameras")
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise ValueError(f"camera(s) {', '.join(repeated)} appear more than once")
        return value

    @property
    def cameras(self) -> list[str]:
        return [n for row in self.layout for n in row]


class Embodiment(Frozen):
    kind: Literal["arm", "mobile", "vehicle"]
    robot: str = Field("builtin_arm", pattern=r"^[a-z][a-z0-9_\-]{0,63}$")
    mjcf: str | None = Field(None, description="MJCF file relative to the robots root")
    # twist (a base only): [vx, vy, wz], the base also turns, and its cameras with it.
    action_space: Literal["ee_delta", "joint_position", "velocity", "twist"] = "ee_delta"

    _mjcf = field_validator("mjcf")(classmethod(lambda cls, v: check_relative_path(v)))

    @model_validator(mode="after")
    def _twist_turns_a_base(self) -> "Embodiment":
        if self.action_space == "twist" and self.kind == "arm":
            raise FieldError("action_space", "twist ([vx, vy, wz]) drives a mobile base or a vehicle, not an arm")
        return self


# Bodies the scene adds itself (tasks/sim: the built-in arm, the mobile base, an MJCF arm
# attached as robot_*/gripper_*, the forklift, the distractors): an object whose body took one
# of these names would be refused by MuJoCo only when the scene compiles (issue 26). Reserved
# whatever stressors the manifest lists, because a panel or loop cell adds distractors to it.
SCENE_BODIES = re.compile(r"world|base|ee|forklift|finger_(left|right)|arm_link\d+|distractor_\d+|(robot|gripper)_.*")


def object_body_name(name: str, index: int) -> str:
    """The body a task object becomes in the scene: lower case, every other character '_', at
    most 24 characters ('object' if none), and '_<index>' after all but the first."""
    clean = "".join(ch if ch.isalnum() else "_" for ch in name.lower())[:24] or "object"
    return f"{clean}_{index}" if index else clean


class Task(Frozen):
    kind: Literal["bin_pick", "push", "drive"]
    instruction: str = Field(min_length=1, max_length=500)
    objects: tuple[str, ...] = Field(default=("package",), max_length=32,
                                     description="the objects to place; the first is the target every task moves")
    controller_noise: float = Field(0.0, ge=0, le=1)
    waypoints: tuple[tuple[float, float], ...] = Field(
        default=(), max_length=64,
        description="drive only: the (x, y) points in metres the base drives through in order from its start at "
                    "(0, 0), on straight legs; the last is the goal. Empty: straight down the aisle to x = 6 m")
    waypoint_jitter_m: float = Field(
        0.0, ge=0, le=0.5,
        description="each episode moves every waypoint by up to this much in x and y (uniform, from its seed; "
                    "kept inside the aisle), so episodes command different trajectories")

    @model_validator(mode="after")
    def _waypoints_stay_in_the_aisle(self) -> "Task":
        if not self.waypoints:
            if self.waypoint_jitter_m:
                raise FieldError("waypoint_jitter_m", "jitters the task's waypoints, and there are none")
            return self
        if self.kind != "drive":
            raise FieldError("waypoints", f"only a drive task follows waypoints, not {self.kind!r}")
        (x0, x1), half = AISLE_X_M, AISLE_HALF_WIDTH_M
        for i, (x, y) in enumerate(self.waypoints):
            # The aisle is a box and the legs are straight from a start inside it: every leg
            # stays inside when every waypoint does.
            if not (x0 <= x <= x1 and abs(y) <= half):
                raise FieldError(f"waypoints.{i}", f"({x:g}, {y:g}) leaves the aisle: the base's centre must stay "
                                                   f"within x {x0:g} to {x1:g} m and |y| <= {half:g} m")
        return self

    @model_serializer(mode="wrap")
    def _leave_out_no_waypoints(self, handler):
        # No waypoints dumps (and hashes) as a manifest from before the field: every existing
        # manifest keeps its hash.
        body = handler(self)
        if isinstance(body, dict) and not self.waypoints:
            body.pop("waypoints", None)
        if isinstance(body, dict) and not self.waypoint_jitter_m:
            body.pop("waypoint_jitter_m", None)
        return body

    @field_validator("objects")
    @classmethod
    def _objects_become_bodies(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        if not value:
            raise ValueError("the task needs at least one object: the first is its target")
        cleaned = [object_body_name(o, 0) for o in value]
        if len(set(cleaned)) != len(cleaned):
            raise ValueError(f"objects repeat (once named as bodies): {list(value)}")
        bodies: dict[str, str] = {}
        for i, name in enumerate(value):
            body = object_body_name(name, i)
            if SCENE_BODIES.fullmatch(body):
                raise ValueError(f"object {name!r} would be body {body!r}, a name the scene gives its own bodies")
            if body in bodies:
                raise ValueError(f"objects {bodies[body]!r} and {name!r} would both become body {body!r}")
            bodies[body] = name
        return value


# Stressors: each a real change to the scene, typed with its parameters.
class DimLight(Frozen):
    kind: Literal["dim_light"] = "dim_light"
    lux: float = Field(50.0, gt=0, le=100_000, description="lux-like level; 500 is a lit warehouse")


class ForkliftCrossing(Frozen):
    kind: Literal["forklift_crossing"] = "forklift_crossing"
    speed_mps: float = Field(1.5, gt=0, le=20)
    lane_m: float = Field(0.8, ge=-10, le=10, description="lateral offset of the lane from the workcell")
    start_s: float = Field(1.0, ge=0, le=MAX_HORIZON_S)


class Occluder(Frozen):
    kind: Literal["occluder"] = "occluder"
    coverage: float = Field(0.3, gt=0, le=1, description="fraction of the target hidden")


class CameraJitter(Frozen):
    kind: Literal["camera_jitter"] = "camera_jitter"
    amplitude_deg: float = Field(1.0, gt=0, le=30)
    frequency_hz: float = Field(5.0, gt=0, le=60)


class Distractors(Frozen):
    kind: Literal["distractors"] = "distractors"
    count: int = Field(3, ge=1, le=50)


class Appearance(Frozen):
    kind: Literal["appearance"] = "appearance"
    colour_jitter: float = Field(0.3, ge=0, le=1)
    texture: bool = True


Stressor = Annotated[
    Union[DimLight, ForkliftCrossing, Occluder, CameraJitter, Distractors, Appearance],
    Field(discriminator="kind"),
]


class Evaluation(Frozen):
    target: Literal["lift_clear", "push_to_goal", "reach_goal"]
    lift_height_m: float = Field(0.10, gt=0, le=5)
    goal_tolerance_m: float = Field(0.05, gt=0, le=5)
    min_success_rate: float = Field(0.8, ge=0, le=1)


class ManifestMeta(Frozen):
    """Bookkeeping that does not change what a manifest means: left out of the hash."""

    author: str | None = None
    created: str | None = None
    notes: str | None = Field(None, max_length=10_000)


class ScenarioManifest(Frozen):
    schema_version: Literal[1] = SCHEMA_VERSION
    name: str = Field(pattern=r"^[a-z0-9][a-z0-9_\-]{0,63}$")
    description: str = Field("", max_length=2000)
    embodiment: Embodiment
    task: Task
    cameras: tuple[Camera, ...] = Field(min_length=1, max_length=16)
    stressors: tuple[Stressor, ...] = Field(default=(), max_length=32)
    evaluation: Evaluation
    horizon_s: float = Field(gt=0, le=MAX_HORIZON_S)
    seed: int = Field(0, ge=0, lt=2**31)
    parent: str | None = Field(None, pattern=r"^[0-9a-f]{64}$", description="hash of the manifest this one derives from")
    rigs: tuple[Rig, ...] = Field(default=(), max_length=4,
                                  description="cameras also recorded together as one tiled video each")
    meta: ManifestMeta = ManifestMeta()

    @field_validator("stressors", mode="after")
    @classmethod
    def _stressor_set(cls, value: tuple) -> tuple:
        # Stressors are a set: listing order carries no meaning, so it cannot change the hash.
        kinds = [s.kind for s in value]
        if len(set(kinds)) != len(kinds):
            raise ValueError(f"stressor kinds repeat: {sorted(kinds)}")
        return tuple(sorted(value, key=lambda s: s.kind))

    @model_validator(mode="after")
    def _horizon_films_every_camera(self) -> "ScenarioManifest":
        # tasks/sim/episode.py records floor(horizon_s * fps) frames of each camera (the same
        # 1e-9 slack), and its video writer refuses a camera with none: a horizon shorter than a
        # camera's frame passed validation and crashed `simulate` after making the episode's
        # folder. Two frames at least, so every camera's video shows some motion; and one control
        # step, or the episode's step table has no rows to write.
        for i, cam in enumerate(self.cameras):
            frames = camera_frames(self.horizon_s, cam.fps)
            if frames < MIN_CAMERA_FRAMES:
                raise FieldError("horizon_s", f"{self.horizon_s:g} s gives camera {cam.name!r} (cameras.{i}, "
                                              f"{cam.fps:g} fps) {frames} frame(s): simulate records floor(horizon_s "
                                              f"* fps) frames a camera and needs at least {MIN_CAMERA_FRAMES}, so "
                                              f"horizon_s must be at least {MIN_CAMERA_FRAMES / cam.fps:g} s")
        if round(self.horizon_s * CONTROL_HZ) < 1:  # as rollout counts its steps
            raise FieldError("horizon_s", f"{self.horizon_s:g} s is shorter than one control step: simulate steps "
                                          f"round(horizon_s * {CONTROL_HZ:g}) times and needs at least one, so "
                                          f"horizon_s must be at least {1 / CONTROL_HZ:g} s")
        return self

    @model_validator(mode="after")
    def _unique_cameras(self) -> "ScenarioManifest":
        # Each camera is one view: a second camera with the same name would overwrite the first's
        # video, one at the same pose would record the same frames again.
        for i, cam in enumerate(self.cameras):
            for j, other in enumerate(self.cameras[:i]):
                if cam.name == other.name:
                    raise FieldError(f"cameras.{i}.name", f"{cam.name!r} is also the name of cameras.{j}; "
                                                          f"camera names must differ")
                if cam.mount == other.mount and same_pose(cam, other):
                    raise FieldError(f"cameras.{i}.position",
                                     f"{cam.name!r} has the pose of cameras.{j} ({other.name!r}): the same "
                                     f"{cam.mount} mount, position and view direction (look_at); cameras at one "
                                     f"pose record the same view")
        return self

    @model_validator(mode="after")
    def _rigs_tile_cameras(self) -> "ScenarioManifest":
        cameras = {c.name: c for c in self.cameras}
        taken: dict[str, str] = dict.fromkeys(cameras, "a camera")
        for i, rig in enumerate(self.rigs):
            if rig.name in taken:
                raise FieldError(f"rigs.{i}.name", f"{rig.name!r} is also the name of {taken[rig.name]}; "
                                                   "rig and camera names must differ")
            taken[rig.name] = f"rigs.{i}"
            first = None
            for r, row in enumerate(rig.layout):
                for c, name in enumerate(row):
                    cam = cameras.get(name)
                    if cam is None:
                        raise FieldError(f"rigs.{i}.layout.{r}.{c}", f"{name!r} is not one of the manifest's "
                                                                     f"cameras ({', '.join(cameras)})")
                    first = first or cam
                    if (cam.resolution, cam.fps) != (first.resolution, first.fps):
                        raise FieldError(f"rigs.{i}.layout.{r}.{c}",
                                         f"{name!r} records {cam.resolution[0]}x{cam.resolution[1]} at {cam.fps:g} "
                                         f"fps, {first.name!r} {first.resolution[0]}x{first.resolution[1]} at "
                                         f"{first.fps:g}: a rig's cameras share resolution and fps")
        return self

    @model_serializer(mode="wrap")
    def _leave_out_no_rigs(self, handler):
        # No rigs dumps (and hashes) as a manifest from before the field: every existing manifest keeps its hash.
        body = handler(self)
        if isinstance(body, dict) and not self.rigs:
            body.pop("rigs", None)
        return body

    def rig(self, name: str) -> "Rig | None":
        return next((r for r in self.rigs if r.name == name), None)

    def stressor(self, kind: str):
        return next((s for s in self.stressors if s.kind == kind), None)

    @cached_property
    def sha256(self) -> str:
        """The manifest hash: sha256 of the canonical JSON of what the manifest means (meta and
        description left out). Computed once: the manifest is frozen."""
        return content_hash(self.model_dump(mode="json", exclude=set(VOLATILE_FIELDS)))

    def model_copy(self, *, update=None, deep: bool = False):
        copied = super().model_copy(update=update, deep=deep)
        copied.__dict__.pop("sha256", None)  # a copy with changes has a hash of its own
        return copied


VOLATILE_FIELDS = frozenset({"meta", "description"})


def manifest_hash(manifest: ScenarioManifest) -> str:
    """sha256 of the canonical JSON of what the manifest means (meta and description left out):
    ``manifest.sha256``, computed once per manifest."""
    return manifest.sha256

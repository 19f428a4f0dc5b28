"""Parameters of the panel and policy flows: panels, evaluate, train-policy, loop."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, model_validator

from flows.params import (DeviceParams, Episodes, FlowParams, Holdout, PanelEpisodes, ParamsError, Refused, Seed, Side,
                          Steps, WorldSamples, Worst)

GRID = "stressor grid YAML (schemas/panel.py StressorGrid); default: nominal, clean, then one stressor at a time"
# tasks/policy/vision_train.DAGGER_GATE, repeated here so checking parameters imports no torch
# (tests/flows/test_param_checks.py holds them equal).
DAGGER_GATE = 1.0


class PanelsParams(DeviceParams):
    manifest: str = Field(description="scenario manifest YAML")
    grid: str | None = Field(None, description=GRID)
    episodes: PanelEpisodes | None = Field(None, description="seeds per cell (default: the grid's)")
    world_model: str | None = Field(None, description="post-trained world-model checkpoint folder or id, for "
                                                      "side-by-side rollouts")
    camera: str | None = Field(None, description="camera shown (default: the first world-mounted one)")
    guard: bool = Field(True, description="text pre-guard and face post-guard")
    cli_arguments = ("manifest",)
    cli_paths = ("manifest", "grid")

    def check_world(self, scenario, folder: str | None, root, flow: bool = False) -> None:
        """The world model at ``folder`` against the panel's camera, tokenizer and action layout
        (``tasks.policy.world_env.world_model_mismatch``): Refused, or in a flow ParamsError."""
        from tasks.panels.grid import primary_camera
        from tasks.policy.world_env import world_model_mismatch

        if not folder:
            return
        problem = world_model_mismatch(folder, scenario, primary_camera(scenario, self.camera), root)
        if problem:
            refused = Refused(f"{{world_model}} {folder}: {problem}")
            raise ParamsError(str(refused)) if flow else refused


class EvaluateParams(DeviceParams):
    manifest: str = Field(description="scenario manifest YAML")
    policies: list[str] | None = Field(None, description="scripted | scripted:NOISE | bc:CHECKPOINT_FOLDER | "
                                       "bc:CHECKPOINT_ID (repeat; default: scripted and scripted:0.8)")
    grid: str | None = Field(None, description="stressor grid YAML (default: one stressor at a time)")
    episodes: PanelEpisodes | None = Field(None, description="seeds per cell (default: the grid's)")
    compare: list[str] | None = Field(None, description="another manifest whose panel is evaluated too (its "
                                      "contract must match; repeat)")
    world_model: str | None = Field(None, description="post-trained world-model checkpoint folder or id: verdicts "
                                                      "on generated frames")
    detector: bool = Field(True, description="also judge the simulator's renders with the frame detector")
    guard: bool = True
    world_samples: WorldSamples = Field(1, description="rollouts per episode the world model judges from: 1 greedy, "
                                        "or that many sampled, the verdict undecided when under 3/4 of them agree")
    in_world_model: bool = Field(False, description="also run each vision policy closed loop in the world model (it "
                                 "sees the generated frames, its actions drive the model) and judge those frames")
    cli_arguments = ("manifest",)
    cli_paths = ("manifest", "grid", "compare")
    cli_names = {"policies": "--policy"}
    cli_hidden = ("guard",)

    @model_validator(mode="after")
    def _closed_loop_needs(self):
        if self.in_world_model and not self.world_model:
            raise Refused("{in_world_model} needs {world_model}: the world model the policies are driven in")
        if self.in_world_model:
            for name in self.policies or ["scripted"]:
                if not name.startswith("vision:"):
                    raise Refused(f"{{in_world_model}}: policy {name!r} reads the simulator's state, not frames; only "
                                  "vision policies (vision:PATH or vision:ID) can be driven by a world model")
        return self

    def check_world(self, scenario, policies: list, folder: str | None, root, flow: bool = False) -> None:
        """The world model at ``folder`` against the panel of ``scenario`` (its camera, tokenizer
        and action layout) and, with ``in_world_model``, each loaded policy against the camera
        it generates: Refused, or in a flow ParamsError (one line either way)."""
        from tasks.panels.grid import primary_camera
        from tasks.policy.world_env import drive_problem, world_model_mismatch

        if not folder:
            return
        camera = primary_camera(scenario, None)
        problem = world_model_mismatch(folder, scenario, camera, root, driven=self.in_world_model)
        refused = Refused(f"{{world_model}} {folder}: {problem}") if problem else None
        if refused is None and self.in_world_model:
            why = next((why for policy in policies if (why := drive_problem(policy, camera))), None)
            refused = Refused(f"{{in_world_model}}: {why}") if why else None
        if refused is not None:
            raise ParamsError(str(refused)) if flow else refused


def _drives_arms(scenario, manifest: str, what: str) -> None:
    if scenario.embodiment.kind != "arm":
        raise Refused(f"{manifest}: {what}; this manifest's embodiment is {scenario.embodiment.kind!r}")


class TrainPolicyParams(DeviceParams):
    manifest: str = Field(description="scenario manifest YAML")
    episodes: Episodes = Field(30, description="scripted demonstrations (seeds seed+1000...)")
    steps: Steps = Field(3000, description="training steps")
    preset_name: str = Field("tiny", description="policy network preset (models/bc_policy.py PRESETS)")
    seed: Seed = 0
    holdout: Holdout = Field(10, description="held-out seeds to measure success on (seed+2000...)")
    observe: str | None = Field(None, description="cameras a vision policy sees, comma-separated, e.g. side or "
                                "front_left,wrist (default: a state policy reading the simulator)")
    image_size: Side = Field(64, description="a vision policy's frames, downscaled to this square size")
    dagger: Annotated[int, Field(ge=0, le=20)] = Field(0, description="DAgger rounds of a vision policy: the "
                                                                     "learner drives, the scripted expert labels "
                                                                     "and takes over where it strays")
    dagger_gate: Annotated[float, Field(ge=0, le=100)] = Field(
        DAGGER_GATE, description="the expert takes over and labels a DAgger step only where the learner's move is off its "
                         "own by more than this many spreads of the demonstrations' moves (HG-DAgger); 0 labels "
                         "every step and leaves the learner in charge (plain DAgger, which hurt: docs/evaluation.md)")
    encoder: str = Field("cnn", description="a vision policy's image encoder: cnn (its own convolutions), or "
                                            "tokenizer:CHECKPOINT (a tokenizer's encoder, folder or id, frozen)")
    encoder_layer: Literal["latent", "hidden"] = Field(
        "latent", description="with a tokenizer encoder: its latents (what the world model reads) or its last hidden "
                              "features")
    shift: Annotated[int, Field(ge=0, le=16)] = Field(
        0, description="a vision policy's training frames each moved by up to this many pixels, a new draw every "
                       "step (random-shift augmentation; 0: none; post-training in the loop keeps it)")
    cli_arguments = ("manifest",)
    cli_paths = ("manifest",)
    cli_names = {"preset_name": "--preset"}
    cli_hidden = ("seed",)

    @model_validator(mode="after")
    def _known_preset(self):
        from models.bc_policy import PRESETS as STATE
        from models.vision_policy import PRESETS as VISION

        known = VISION if self.observe else STATE
        if self.preset_name not in known:
            raise Refused(f"{{preset_name}}: unknown {'vision' if self.observe else 'state'} policy preset "
                          f"{self.preset_name!r}; known: {', '.join(sorted(known))}")
        if self.observe is not None:
            from tasks.policy.vision_obs import parse_cameras

            try:
                parse_cameras(self.observe)
            except ValueError as exc:
                raise Refused(f"{{observe}} {self.observe!r}: {str(exc).split(': ', 1)[1]}") from None
        if self.encoder != "cnn":
            if not self.encoder.startswith("tokenizer:") or not self.encoder[len("tokenizer:"):]:
                raise Refused(f"{{encoder}} {self.encoder!r}: cnn, or tokenizer: and a tokenizer checkpoint folder or "
                              "id")
            if self.observe is None:
                raise Refused("{encoder}: a state policy reads the simulator, it has no image encoder; add {observe}")
        elif self.encoder_layer != "latent":
            raise Refused("{encoder_layer}: only a tokenizer encoder has layers to choose; add {encoder} tokenizer:...")
        if self.shift and (self.observe is None or self.encoder != "cnn"):
            raise Refused("{shift} moves a vision policy's frames for its own convolutions; add {observe}, with "
                          "{encoder} cnn (a tokenizer encoder's features are computed once per frame)")
        if self.dagger and self.observe is None:
            raise Refused("{dagger}: DAgger rounds train a vision policy; add {observe} (a state policy has none)")
        if self.dagger_gate != DAGGER_GATE and not (self.dagger and self.observe):
            raise Refused("{dagger_gate} gates the DAgger rounds of a vision policy; add {observe} and {dagger}")
        return self

    def check_tokenizer(self, folder: str) -> None:
        """The tokenizer checkpoint at ``folder`` against the frames it would encode."""
        from models.tokenizer import TokenizerConfig
        from tasks.checkpoint_files import model_config, read_config

        config = model_config(TokenizerConfig, read_config(Path(folder), "tokenizer", "tokenizer checkpoint"),
                              "tokenizer", Path(folder))
        if self.image_size % config.spatial_compression:
            raise Refused(f"{{encoder}} {self.tokenizer()}: its tokenizer compresses {config.spatial_compression}x "
                          f"spatially; {{image_size}} {self.image_size} is not a multiple of it")

    def tokenizer(self) -> str | None:
        """The tokenizer checkpoint (folder or id) a vision policy sees through; None for its own CNN."""
        return self.encoder.removeprefix("tokenizer:") if self.encoder != "cnn" else None

    def spec(self):
        """The vision policy's observation spec; None for a state policy."""
        from tasks.policy.vision_obs import ObservationSpec, parse_cameras

        return ObservationSpec(cameras=parse_cameras(self.observe), image_size=self.image_size) if self.observe else None

    def check_scenario(self, scenario) -> None:
        _drives_arms(scenario, self.manifest, "behaviour cloning drives arms")
        spec = self.spec()
        problem = spec.mismatch(scenario) if spec else None
        if problem:
            raise Refused(f"{{observe}}: {problem}")


class LoopParams(FlowParams):
    manifest: str = Field(description="scenario manifest YAML")
    policy: str | None = Field(None, description="bc: or vision: CHECKPOINT_FOLDER or CHECKPOINT_ID (default: a weak "
                                                 "state policy trained in-flow)")
    grid: str | None = Field(None, description="stressor grid YAML (default: one stressor at a time)")
    episodes: PanelEpisodes | None = Field(None, description="seeds per cell (default: the grid's)")
    worst: Worst = Field(1, description="how many of the lowest-success cells to derive manifests from")
    new_episodes: Episodes = Field(12, description="new episodes in all, weighted by failure rate")
    post_steps: Steps = Field(2000, description="post-training steps")
    control: bool = Field(False, description="also post-train on as many new episodes of the manifest as it is "
                                            "(an untargeted control) and compare it on the same panel")
    cli_arguments = ("manifest",)
    cli_paths = ("manifest", "grid")

    @model_validator(mode="after")
    def _behaviour_cloning(self):
        if self.policy is not None and not self.policy.startswith(("bc:", "vision:")):
            raise Refused(f"policy {self.policy!r}: the loop post-trains learned policies (bc:PATH, bc:ID, vision:PATH "
                          "or vision:ID)")
        return self

    def check_scenario(self, scenario) -> None:
        _drives_arms(scenario, self.manifest, "the loop post-trains behaviour cloning, which drives arms")

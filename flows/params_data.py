"""Parameters of the flows that bring data in: register, simulate, corpus, curate."""

from __future__ import annotations

from pydantic import Field, model_validator

from flows.params import Episodes, FlowParams, Fps, Height, Minutes, Refused, Seed, Width


class RegisterParams(FlowParams):
    manifest_path: str = Field(description="scenario manifest YAML")
    cli_arguments = ("manifest_path",)


class SimulateParams(FlowParams):
    manifest: str = Field(description="scenario manifest YAML")
    episodes: Episodes = Field(2, description="episodes (seeds seed..seed+N-1)")
    controls: bool = Field(False, description="also render each camera's depth and segmentation "
                           "(docs/transfer.md); episodes simulated without them are simulated again")
    policy: str | None = Field(None, description="drive the robot with this policy instead of the manifest's scripted "
                               "controller: scripted:NOISE, bc: or vision: CHECKPOINT_FOLDER or CHECKPOINT_ID; its "
                               "episodes go in a folder of their own (for `train --also`)")
    cli_arguments = ("manifest",)
    cli_paths = ("manifest",)


class CorpusParams(FlowParams):
    minutes: Minutes = Field(1.0, description="minutes of footage")
    seed: Seed = Field(0, description="same seed, same videos and truth")
    width: Width = 640
    height: Height = 360
    fps: Fps = 30.0

    @model_validator(mode="after")
    def _even_size(self):
        # tasks/corpus/generate.py writes 4:2:0 H.264, whose frames have even sides: it refuses
        # an odd size only when the flow has started.
        for field in ("width", "height"):
            value = getattr(self, field)
            if value % 2:
                raise Refused(f"{{{field}}}: {value} is odd; the corpus videos (H.264, 4:2:0) need an even width "
                              f"and height")
        return self


class CurateParams(FlowParams):
    inputs: list[str] = Field(description="video files or folders of videos")
    manifest: str | None = Field(None, description="scenario manifest the footage belongs to")
    config: str | None = Field(None, description="YAML overrides of CurateConfig")
    cli_arguments = ("inputs",)
    cli_paths = ("inputs", "manifest", "config")


class ControlsParams(FlowParams):
    source: str = Field(description="a video, an episode folder, or a folder of videos")
    out: str | None = Field(None, description="folder for the control files (default: beside each video; an "
                            "episode's in its controls/ folder)")
    cli_arguments = ("source",)
    cli_paths = ("source", "out")

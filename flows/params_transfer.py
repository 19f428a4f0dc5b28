"""Parameters of the transfer flows: train-transfer and transfer (docs/transfer.md)."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, model_validator

from flows.params import DeviceParams, ParamsError, Refused, Side, Steps
from schemas.errors import StepMissing

MAX_SEEDS = 10_000


def seed_list(text: str) -> tuple[int, ...]:
    """``N`` (seeds 0..N-1) or ``A-B`` (A..B inclusive); ValueError in one line otherwise."""
    first, dash, last = text.strip().partition("-")
    try:
        seeds = range(int(first), int(last) + 1) if dash else range(int(first))
    except ValueError:
        raise ValueError(f"{text!r}: N (seeds 0..N-1) or a range A-B") from None
    if dash and seeds.stop <= seeds.start:
        raise ValueError(f"{text!r}: a range A-B runs upwards (A at most B)")
    if not 1 <= len(seeds) <= MAX_SEEDS or seeds.start < 0:
        raise ValueError(f"{text!r}: from 1 to {MAX_SEEDS} seeds, none negative")
    return tuple(seeds)


class TrainTransferParams(DeviceParams):
    manifest: str = Field(description="scenario manifest YAML whose simulator pairs (docs/transfer.md) train the model")
    seeds: str = Field("9", description="N (seeds 0..N-1) or a range A-B: each seed simulated in every look")
    preset_name: str = Field("small-palette", description="transfer model preset (models/transfer.py PRESETS): "
                             "small-palette | small | small-ref | small-frame | small-affine | tiny")
    steps: Steps = Field(2000, description="training steps")
    seconds: float | None = Field(None, gt=0, description="training-time budget: stops at --steps or this")
    temporal: float = Field(1.0, ge=0, le=100, description="weight of the temporal loss (frame-to-frame changes as "
                            "the target's; 1 kept small-palette's flicker within 1.2x the source's)")
    size: Side = Field(64, description="pairs are made at size x size (and so is every transfer with the model)")
    camera: str | None = Field(None, description="the camera pairs are made of (default: the first world-mounted)")
    cli_arguments = ("manifest",)
    cli_paths = ("manifest",)
    cli_names = {"preset_name": "--preset"}

    @model_validator(mode="after")
    def _fits(self):
        from models.transfer import PRESETS

        try:
            seed_list(self.seeds)
        except ValueError as exc:
            raise Refused(f"{{seeds}}: {exc}") from None
        if self.preset_name not in PRESETS:
            raise Refused(f"{{preset_name}}: unknown transfer preset {self.preset_name!r}; known: "
                          f"{', '.join(sorted(PRESETS))}")
        if self.size % (m := PRESETS[self.preset_name].multiple):
            raise Refused(f"{{size}}: {self.size} is not a multiple of {m}, as preset {self.preset_name} needs")
        return self

    def check_scenario(self, scenario) -> str:
        """The camera pairs are made of, refused when the manifest lacks it."""
        from tasks.panels.grid import primary_camera

        try:
            return primary_camera(scenario, self.camera)
        except ValueError as exc:
            raise Refused(f"{{camera}}: {exc}") from None


class TransferParams(DeviceParams):
    source: str = Field(description="an episode folder, or a manifest YAML or hash: every episode simulated of it")
    model: str | None = Field(None, description="transfer checkpoint folder, or the first 12+ hex digits of its id "
                                                "(default: the newest `worldline train-transfer` trained)")
    look: str = Field(description="look[,look...]: nominal, dim, very dim, colour shift, textures")
    camera: str | None = Field(None, description="camera to transfer (default: the one the model was trained on, "
                                                 "else the episode's first)")
    weights: str | None = Field(None, description="control weights, e.g. edges=1,blur=1,depth=0,segmentation=1 "
                                                  "(1 where not given; 0 removes a control)")
    reference: str | None = Field(None, description="a video (e.g. a curated clip) whose look, its colour statistics, "
                                                    "the output takes beside the look's word (models whose preset "
                                                    "takes reference clips: small-ref, small-frame, small-affine, "
                                                    "small-palette)")
    cli_arguments = ("source",)
    cli_paths = ("model", "reference")

    @model_validator(mode="after")
    def _words(self):
        from tasks.guard.text import GuardError, check_text
        from tasks.transfer.apply import parse_looks, parse_weights

        try:  # the text pre-guard first: a blocked prompt is refused as such, whatever else it is
            check_text(self.look, "look")
        except GuardError as exc:
            raise Refused(f"{{look}}: blocked term {exc.term!r} (found {exc.found!r})") from None
        for name, parse in (("look", parse_looks), ("weights", parse_weights)):
            try:
                parse(getattr(self, name))
            except ValueError as exc:
                raise Refused(f"{{{name}}}: {exc}") from None
        return self

    def check_inputs(self, root: Path, flow: bool = False):
        """(model folder, its config, the episodes' sources) with every file check made: a
        transfer checkpoint holding the looks, episodes, their camera and controls. Refused, or
        in a flow ParamsError (one line either way), before anything is written."""
        from tasks.checkpoint_files import CheckpointError
        from tasks.controls.check import ControlError
        from tasks.lookup import is_hex_id
        from tasks.manifests import ManifestError
        from tasks.transfer.apply import episode_source, model_info, parse_looks, parse_weights
        from tasks.video import DecodeError, probe
        from tasks.world.inputs import episode_folders

        try:
            try:
                folder = self._model_folder(root)
                config, info = model_info(folder)
                if missing := [look for look in parse_looks(self.look) if look not in config.prompts]:
                    raise CheckpointError(f"{folder}: the model has no look {missing[0]!r}")
            except StepMissing:
                raise  # no transfer model trained yet: exit 3 (not built), as every step that needs an earlier one
            except (CheckpointError, FileNotFoundError) as exc:
                raise Refused(f"{{model}}: {exc}") from None
            if self.reference is not None:
                if not config.reference:
                    raise Refused(f"{{reference}}: the model {folder} was not trained with reference clips "
                                  "(train it with a preset that takes them: small-ref, small-frame, small-affine "
                                  "or small-palette, the default)")
                try:
                    probe(self.reference)
                except DecodeError as exc:
                    raise Refused(f"{{reference}}: {exc}") from None
            weights = parse_weights(self.weights)
            if not Path(self.source).exists() and not is_hex_id(self.source):
                raise Refused(f"{{source}} {self.source}: no such file or folder, and not a manifest hash")
            try:  # StepMissing (nothing simulated of it yet) is left to say so with its own exit code
                sources = [episode_source(folder, self.camera, weights, info.get("camera"))
                           for folder in episode_folders(self.source, Path(root).resolve())[0]]
            except (ControlError, ManifestError) as exc:
                raise Refused(str(exc)) from None
        except Refused as refused:
            if flow:
                raise ParamsError(str(refused)) from None
            raise
        return folder.resolve(), info, sources

    def _model_folder(self, root: Path) -> Path:
        """``model`` as a folder: an id or None looked up in lineage, opened read-only."""
        from schemas.settings import Settings
        from tasks.transfer.lineage import model_folder
        from warehouse.store import Warehouse

        if self.model is not None and Path(self.model).is_dir():
            return Path(self.model)
        place = Settings().warehouse_path
        if not place.exists():
            return model_folder(None, root, self.model)
        with Warehouse(place, read_only=True) as warehouse:
            return model_folder(warehouse, root, self.model)

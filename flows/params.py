"""Flow parameters: one pydantic model per flow (flows/params_*.py), built on the bounded types
and the base class here. A model holds every check of its flow's parameters: the bounds (which
Prefect also puts in each deployment's parameter schema, so `prefect deployment run` with an
out-of-range value is refused before a run is created), and the checks between parameters.
Each flow validates its parameters with its model first thing, so a deployment run gets the
same checks as the CLI, whose options are declared from the model's fields (flows/cli_shell.py)."""

from __future__ import annotations

import re
from typing import Annotated, ClassVar, Literal, Mapping

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

Episodes = Annotated[int, Field(ge=1, le=10_000, description="episodes or seeds")]
PanelEpisodes = Annotated[int, Field(ge=1, le=1000, description="seeds per stressor cell")]
Steps = Annotated[int, Field(ge=1, le=1_000_000, description="training steps")]
Seed = Annotated[int, Field(ge=0)]
Batch = Annotated[int, Field(ge=1, le=256)]
Weight = Annotated[float, Field(ge=0.0, le=100.0)]
Share = Annotated[float, Field(ge=0.0, le=1.0)]
Side = Annotated[int, Field(ge=8, le=1024, description="pixels")]
Minutes = Annotated[float, Field(ge=0.05, le=600)]
Width = Annotated[int, Field(ge=32, le=3840)]
Height = Annotated[int, Field(ge=32, le=2160)]
Fps = Annotated[float, Field(ge=1, le=120)]
Window = Annotated[int, Field(ge=2, le=64)]
Patch = Annotated[int, Field(ge=1, le=16)]
ActionTotals = Annotated[int, Field(ge=0, le=8)]
FocusCrops = Annotated[int, Field(ge=1, le=64)]
EncodeFrames = Annotated[int, Field(ge=1)]
Holdout = Annotated[int, Field(ge=0, le=10_000)]
Horizon = Annotated[int, Field(ge=1, le=64)]
Worst = Annotated[int, Field(ge=1, le=8)]
WorldSamples = Annotated[int, Field(ge=1, le=64)]
SamplerSteps = Annotated[int, Field(ge=1, le=1000, description="a diffusion world model's Euler steps per sample")]


class Refused(ValueError):
    """A check's refusal. ``{field}`` in its text names a parameter: the field itself for a flow
    (``preset_name``), its option for the CLI (``--preset``)."""

    def __init__(self, text: str):
        super().__init__(text)
        self.text = text

    def named(self, names: Mapping[str, str]) -> str:
        return re.sub(r"\{(\w+)\}", lambda m: names.get(m[1], m[0]), self.text)

    def __str__(self) -> str:
        return re.sub(r"\{(\w+)\}", r"\1", self.text)


class ParamsError(ValueError):
    """Parameters a flow's model refused, in one line."""


class FlowParams(BaseModel):
    """The parameters of one flow. The class variables say how the CLI shows them: fields that
    are positional arguments, options named otherwise than ``--field-name``, fields the CLI
    leaves at their defaults, and fields it reads as paths."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    cli_arguments: ClassVar[tuple[str, ...]] = ()
    cli_names: ClassVar[dict[str, str]] = {}
    cli_hidden: ClassVar[tuple[str, ...]] = ()
    cli_paths: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def option(cls, field: str) -> str:
        return cls.cli_names.get(field, "--" + field.replace("_", "-"))

    @classmethod
    def labels(cls, cli: bool) -> dict[str, str]:
        return {f: cls.option(f) if cli and f not in cls.cli_arguments else f for f in cls.model_fields}

    @classmethod
    def of(cls, values: Mapping, cli: bool = False):
        """The model of ``values`` (a flow's ``locals()`` at its first line, or the CLI's
        options), or ParamsError with the first problem in one line."""
        try:
            return cls.model_validate(dict(values))
        except ValidationError as exc:
            raise ParamsError(cls.explain(exc, cli)) from None

    @classmethod
    def explain(cls, exc: ValidationError, cli: bool) -> str:
        first = exc.errors()[0]
        refused = first.get("ctx", {}).get("error")
        if isinstance(refused, Refused):
            return refused.named(cls.labels(cli))
        where = ".".join(str(p) for p in first["loc"])
        name = cls.labels(cli).get(where, where)
        return f"{name}: {first['msg']}" + (f" (got {first['input']!r})" if "input" in first else "")


class DeviceParams(FlowParams):
    """Where a flow's models compute (``tasks.device``); it never enters an id or a result."""

    device: str | None = Field(None, description="auto | cpu | cuda | cuda:N (default: $WORLDLINE_DEVICE, else auto)")

    @model_validator(mode="after")
    def _device_is_there(self):
        self.torch_device()
        return self

    def torch_device(self):
        from tasks.device import DeviceError, Runtime

        try:
            return (Runtime(device=self.device) if self.device else Runtime()).torch_device()
        except ValidationError as exc:  # a device name Runtime does not know
            raise Refused(f"{{device}}: {exc.errors()[0]['msg'].removeprefix('Value error, ')}") from None
        except DeviceError as exc:
            raise Refused(f"{{device}}: {str(exc).removeprefix(f'--device {self.device}: ')}") from None


class ComputeParams(DeviceParams):
    """Where a training flow runs (``tasks.device.Runtime``); none of it enters a checkpoint id."""

    precision: Literal["fp32", "bf16"] = Field("fp32", description="bf16: bfloat16 autocast (CUDA only)")
    compile_model: bool = Field(False, description="torch.compile(mode='reduce-overhead'): CUDA graphs")

    @model_validator(mode="after")
    def _precision_fits(self):
        device = self.torch_device()
        if self.precision == "bf16" and device.type != "cuda":
            raise Refused(f"{{precision}}: bf16 runs only on a CUDA device ({{device}} gives {device})")
        return self

    def runtime(self):
        from tasks.device import Runtime

        chosen = {"device": self.device} if self.device else {}
        return Runtime(**chosen, precision=self.precision, compile=self.compile_model)

"""Commands declared from a flow's parameter model (flows/params.py): each field an argument
or option of the command, with its help and bounds; the values given checked by the model, a
refusal in one line with exit 2."""

from __future__ import annotations

import inspect
import types
import typing
from pathlib import Path
from typing import Annotated, Optional, Union

import typer

from flows.cli_shell import FORMAT, check_format, checked, fail
from flows.params import FlowParams, ParamsError


def _plain(annotation, metadata: list) -> tuple[object, dict]:
    """(the type typer reads, its bounds as typer's min and max) of a field: Optional and
    Annotated peeled off."""
    optional = typing.get_origin(annotation) in (Union, types.UnionType)
    if optional:
        annotation = next(a for a in typing.get_args(annotation) if a is not type(None))
    if typing.get_origin(annotation) is Annotated:
        annotation, *extra = typing.get_args(annotation)
        metadata = [*metadata, *(m for e in extra for m in getattr(e, "metadata", [e]))]
    bounds = {key: getattr(m, attr) for m in metadata for key, attr in (("min", "ge"), ("max", "le"))
              if getattr(m, attr, None) is not None}
    return (Optional[annotation] if optional else annotation), bounds


def _as_path(hint):
    return {str: Path, Optional[str]: Optional[Path], list[str]: list[Path],
            Optional[list[str]]: Optional[list[Path]]}[hint]


def _as_str(value):
    return [str(v) for v in value] if isinstance(value, list) else None if value is None else str(value)


def command(group: typer.Typer, model: type[FlowParams], name: str | None = None, listing: bool = False):
    """Register ``body(params)`` as a command of ``group`` whose arguments and options are the
    fields of ``model`` (but its ``cli_hidden`` ones, left at their defaults); the values given
    are checked by the model, a refusal in one line with exit 2. A ``listing`` command prints
    rows: it takes ``--format`` too, checked before it starts, and is called ``body(params, fmt)``."""

    def register(body):
        parameters, fields = [], {}
        for field, info in model.model_fields.items():
            if field in model.cli_hidden:
                continue
            hint, bounds = _plain(info.annotation, info.metadata)
            if field in model.cli_paths:  # typed as paths, given to the flow as their str()
                hint = _as_path(hint)
            if field in model.cli_arguments:
                key, default = field, typer.Argument(... if info.is_required() else info.default,
                                                     help=info.description)
            else:
                option = model.option(field)
                key = option[2:].replace("-", "_")
                decl = f"{option}/--no-{option[2:]}" if hint is bool else option
                default = typer.Option(... if info.is_required() else info.default, decl, help=info.description, **bounds)
            fields[key] = field
            parameters.append(inspect.Parameter(key, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=hint))
        if listing:
            parameters.append(inspect.Parameter("fmt", inspect.Parameter.KEYWORD_ONLY, default=FORMAT, annotation=str))

        def run(fmt: str = "table", **given):
            check_format(fmt)
            values = {fields[k]: _as_str(v) if fields[k] in model.cli_paths else v for k, v in given.items()}
            try:
                params = model.of(values, cli=True)
            except ParamsError as exc:
                fail(str(exc))
            with checked(model):
                return body(params, fmt) if listing else body(params)

        run.__signature__ = inspect.Signature(parameters)
        run.__name__, run.__doc__, run.body = body.__name__, body.__doc__, body
        group.command(name)(run)
        return body

    return register

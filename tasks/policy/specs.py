"""Policies named on a command line: ``scripted`` (the manifest's noise), ``scripted:0.8``,
``bc:PATH`` (a state policy's checkpoint folder), ``vision:PATH`` (a vision policy's)."""

from __future__ import annotations

from pathlib import Path

from tasks.policy.base import Policy, ScriptedPolicy


class PolicySpecError(ValueError):
    """A policy name that cannot be used: one line saying why."""


def load_policy(spec: str) -> Policy:
    kind, _, arg = spec.partition(":")
    if kind == "scripted":
        if not arg:
            return ScriptedPolicy()
        try:
            return ScriptedPolicy(float(arg))
        except ValueError as exc:
            raise PolicySpecError(f"policy {spec!r}: {exc}") from None
    if kind in ("bc", "vision"):
        if kind == "bc":
            from tasks.policy.bc import BCPolicy as Kind
        else:
            from tasks.policy.vision import VisionPolicy as Kind
        if not arg:
            raise PolicySpecError(f"policy {spec!r}: name a checkpoint folder, {kind}:PATH")
        try:
            return Kind.from_checkpoint(Path(arg))
        except (FileNotFoundError, ValueError, KeyError) as exc:
            raise PolicySpecError(f"policy {spec!r}: {exc}") from None
    raise PolicySpecError(f"policy {spec!r}: unknown kind {kind!r} (scripted, scripted:NOISE, bc:PATH or vision:PATH)")

"""Policies named on a command line: ``scripted`` (the manifest's noise), ``scripted:0.8``,
``bc:PATH`` (a behaviour-cloning checkpoint folder)."""

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
    if kind == "bc":
        from tasks.policy.bc import BCPolicy

        if not arg:
            raise PolicySpecError(f"policy {spec!r}: name a checkpoint folder, bc:PATH")
        try:
            return BCPolicy.from_checkpoint(Path(arg))
        except (FileNotFoundError, ValueError, KeyError) as exc:
            raise PolicySpecError(f"policy {spec!r}: {exc}") from None
    raise PolicySpecError(f"policy {spec!r}: unknown kind {kind!r} (scripted, scripted:NOISE or bc:PATH)")

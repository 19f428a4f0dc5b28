"""demo: the whole loop on built-in generated data, with the embedded defaults."""

from __future__ import annotations

from pathlib import Path

from prefect import flow

from flows.register import register

MANIFESTS = Path(__file__).resolve().parent.parent / "manifests"


@flow(name="demo", log_prints=True)
def demo() -> None:
    for path in sorted(MANIFESTS.glob("*.yaml")):
        register(str(path))

"""Constants shared by tests (kept out of conftest so it is imported once)."""

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
MANIFESTS = REPO / "manifests"


"""Session-wide test setup: a private data root, and one Prefect test harness for all flow tests."""

import os
import tempfile
from pathlib import Path

import pytest

from tests.support import SHARED_DATA

# Before anything imports prefect or reads settings: keep tests away from the user's data.
_ROOT = Path(tempfile.mkdtemp(prefix="worldline-tests-"))
os.environ["WORLDLINE_DATA_ROOT"] = str(_ROOT)
os.environ["PREFECT_HOME"] = str(_ROOT / "prefect")
os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(scope="session")
def prefect_harness():
    """One ephemeral Prefect API for the whole session (each start costs ~10 s)."""
    import flows  # noqa: F401
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=180):
        yield


@pytest.fixture
def data_root(tmp_path, monkeypatch) -> Path:
    """A fresh data root (and so a fresh warehouse) for one test."""
    monkeypatch.setenv("WORLDLINE_DATA_ROOT", str(tmp_path))
    return tmp_path


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is absent")
    return SHARED_DATA

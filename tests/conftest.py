"""Session-wide test setup: a private data root, and one Prefect test harness for all flow tests."""

import os
import tempfile
from pathlib import Path

import pytest

from tests.support import REPO, SHARED_DATA

# Before anything imports prefect or reads settings: keep tests away from the user's data.
_ROOT = Path(tempfile.mkdtemp(prefix="worldline-tests-"))
os.environ["WORLDLINE_DATA_ROOT"] = str(_ROOT)
os.environ["PREFECT_HOME"] = str(_ROOT / "prefect")
os.environ.setdefault("MUJOCO_GL", "egl")
# Every flow run would write its HTML report page (seconds each, over a hundred runs here);
# tests/flows/test_corpus.py turns them on for its two runs, tests/tasks/report tests the page.
os.environ.setdefault("WORLDLINE_REPORT_PAGES", "false")

# Integration tests: they start a Prefect API server or other processes, read the real footage
# and robots in ../shared/data, or simulate and train for seconds at a time. `make test` runs
# every test; `make test-fast` (pytest -m "not integration") leaves these out. A test is one
# when it uses one of these fixtures, is marked slow, or is named below.
INTEGRATION_FIXTURES = {"prefect_harness", "shared_data", "real_frames"}

# Whole files, each with why.
INTEGRATION_FILES = {
    "tests/tasks/test_mujoco_backend.py": "imports MuJoCo in a fresh interpreter per case",
    "tests/warehouse/test_lock.py": "another process holds the lock",
    "tests/tasks/curate/test_scenes_real.py": "../shared/data/videos-dev",
    "tests/tasks/corpus/test_generate.py": "renders three minutes of corpus footage",
    "tests/tasks/policy/test_policy.py": "simulates demonstrations and trains policies on them",
    "tests/tasks/world/test_train.py": "trains world models",
    "tests/tasks/panels/test_detect.py": "simulates push episodes to judge",
    # MuJoCo episodes simulated and rendered, a second or more each
    "tests/tasks/sim/test_control.py": "simulates each task to its end",
    "tests/tasks/sim/test_files.py": "simulates and writes episodes",
    "tests/tasks/sim/test_segments.py": "simulates and renders footage",
    "tests/tasks/sim/test_stressors.py": "simulates and renders every stressor",
    "tests/tasks/world/test_physics.py": "simulates and renders a push episode",
    "tests/tasks/transfer/test_pairs.py": "simulates a push episode in every look",
    "tests/tasks/transfer/test_train.py": "trains transfer models",
}

# Single tests (every parametrisation) in files whose other tests are unit tests.
INTEGRATION_TESTS = {
    "tests/flows/test_cli.py": {  # the CLI in another process
        "test_console_script_runs",
        "test_a_failed_flow_from_the_cli_ends_without_traceback_or_binding_noise",
        "test_a_wrong_setting_is_named_in_one_line",
        "test_a_busy_data_root_is_exit_4_in_one_line_before_prefect_starts",
    },
    "tests/flows/test_reliability.py": {"test_a_second_writer_waits_for_the_first_then_gives_up_in_one_line"},
    "tests/warehouse/test_store.py": {  # another process writes or holds the file
        "test_a_wal_left_by_a_killed_writer_is_replayed",
        "test_a_warehouse_another_process_holds_is_busy_after_the_timeout",
        "test_a_warehouse_released_within_the_timeout_opens",
    },
    "tests/tasks/curate/test_inputs.py": {"test_fault_point_kills_at_the_named_hit_only"},  # processes killed
    # ../shared/data, read without the fixtures
    "tests/tasks/curate/test_overlay_text.py": {"test_real_cctv_timestamp_is_overlay_text",
                                                "test_real_footage_without_overlays_is_kept"},
    "tests/tasks/curate/test_video_type.py": {"test_real_cgi_scores_above_real_camera_footage"},
    "tests/tasks/curate/test_quality.py": {"test_real_decoder_freeze_is_found"},
    "tests/tasks/curate/test_detectors.py": {"test_adaptive_ratio_accounts_for_frames_left_undecoded"},
    "tests/tasks/curate/test_motion.py": {"test_real_handheld_footage"},
    "tests/tasks/curate/test_smear.py": {"test_the_real_concealment_frame_is_the_only_smeared_one"},
    "tests/tasks/sim/test_scene.py": {"test_the_shipped_robots_pass"},
    # training, or building a model
    "tests/tasks/curate/test_captions.py": {"test_vlm_backend_loads_local_model_and_generates",
                                            "test_vlm_backend_with_a_processor_and_prompt"},
    "tests/models/test_world_model.py": {"test_a_tiny_model_overfits_one_sequence",
                                         "test_a_patched_model_learns_each_slot_of_its_block"},
    "tests/tasks/tokenize/test_tokenize_tasks.py": {"test_training_lowers_the_loss_and_is_deterministic"},
}


def _is_integration(item) -> bool:
    if INTEGRATION_FIXTURES & set(getattr(item, "fixturenames", ())) or item.get_closest_marker("slow"):
        return True
    path = item.path.as_posix().removeprefix(f"{REPO.as_posix()}/")
    return path in INTEGRATION_FILES or getattr(item, "originalname", item.name) in INTEGRATION_TESTS.get(path, ())


def pytest_collection_modifyitems(config, items):
    """Mark integration tests (see pyproject's markers) here, so that no test file needs to."""
    for item in items:
        if _is_integration(item):
            item.add_marker(pytest.mark.integration)


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

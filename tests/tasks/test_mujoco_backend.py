"""MuJoCo picks its GL backend when it is first imported: the `tasks` package sets
MUJOCO_GL=egl before any of its modules can import it, or a fresh `worldline` process that
reaches it first renders through GLFW and dies on a machine without a display."""

import os
import subprocess
import sys

import pytest

from tests.support import REPO

# Every module outside tasks/sim that imports mujoco, and the flows that reach them first.
MODULES = ["tasks.policy.bc", "tasks.policy.features", "tasks.world.heldout", "flows.policy", "flows.evaluate"]


@pytest.mark.parametrize("module", MODULES)
def test_first_import_picks_egl(module):
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    code = f"import {module}, mujoco; print(mujoco.GLContext.__module__)"
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "mujoco.egl"

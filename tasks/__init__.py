"""Tasks: the work flows are made of (no Prefect here).

MuJoCo picks its GL backend when it is first imported, and on this CPU-only machine only EGL
works headless; setting it here, before any ``tasks.*`` module can import mujoco, makes the
order of imports inside the package irrelevant.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

"""MuJoCo scenario episodes: scene from a manifest, scripted control, headless rendering.

Modules: `robots` (arms and mobile base), `scene` (the world and its stressors), `control`
(scripted controllers), `render` (multi-camera offscreen renderer), `episode` (rollout and
judging), `files` (MP4 + Parquet + meta.json and lineage), `segments` (footage for the corpus).
"""

import os

# MuJoCo picks its GL backend when first imported; on this CPU-only machine only EGL works
# headless, so this must run before any `import mujoco` anywhere in the package.
os.environ.setdefault("MUJOCO_GL", "egl")

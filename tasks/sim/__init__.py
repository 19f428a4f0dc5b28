"""MuJoCo scenario episodes: scene from a manifest, scripted control, headless rendering.

Modules: `robots` (built-in arm, MJCF arm + gripper, mobile base), `scene` (the world from a
manifest and a seed), `stressors` (forklift, occluder, distractors, appearance), `kinematics`
(differential IK), `control` (scripted controllers), `render` (multi-camera offscreen
renderer), `episode` (rollout and judging), `files` (MP4 + Parquet + meta.json, lineage),
`segments` (continuous footage for the raw corpus).
"""

import os

# MuJoCo picks its GL backend when first imported; on this CPU-only machine only EGL works
# headless, so this must run before any `import mujoco` anywhere in the package.
os.environ.setdefault("MUJOCO_GL", "egl")

"""MuJoCo scenario episodes: scene from a manifest, scripted control, headless rendering.

Modules: `robots` (built-in arm, MJCF arm + gripper, mobile base), `scene` (the world from a
manifest and a seed), `stressors` (forklift, occluder, distractors, appearance), `kinematics`
(differential IK), `control` (scripted controllers), `render` (multi-camera offscreen
renderer), `episode` (rollout and judging), `files` (MP4 + Parquet + meta.json, lineage),
`segments` (continuous footage for the raw corpus).

MUJOCO_GL=egl is set by the `tasks` package itself, before any of these modules loads mujoco.
"""

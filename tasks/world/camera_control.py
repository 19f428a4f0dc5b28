"""Camera control evaluated (issue 33 point 3): held-out episodes of a rig whose action is its
cameras' motion, the world model's frames from their first true frames and the commanded
twist, and the camera motion re-estimated from the generated frames against the motion the
simulator drove (`tasks.world.camera_motion`), beside copy-last-frame (the floor: a held frame
shows no motion) and the tokenizer's reconstruction of the truth (the ceiling).

Each window's reference is its last context frame: the true render for the simulator's row, its
reconstruction for every decoded row (the model, the shuffled actions, the ceiling and the
floor), so like is compared with like. The trajectory from it is re-estimated frame to frame
(`camera_motion.trajectory_errors`: a ground rig's planar motion, composed) and scored h video
frames later.
"""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from schemas.manifest import ScenarioManifest
from tasks.world import heldout, physics
from tasks.world.camera_motion import motion_table, trajectory_errors
from tasks.world.geometry import PinholeCamera

SOURCES = ("simulator", "ceiling", "model", "shuffled", "floor")


def moving_cameras(manifest: ScenarioManifest) -> list[str]:
    """The manifest's cameras that ride on the base (its vehicle-mounted ones)."""
    return [c.name for c in manifest.cameras if c.mount == "vehicle"]


def render_heldout(manifest: ScenarioManifest, seed: int, camera: str) -> tuple[heldout.Truth, list[PinholeCamera]]:
    """One held-out episode of `camera`: its frames, the control steps' times and actions (no
    package masks: the measure here is the camera's motion), and the camera's pose at each frame."""
    from tasks.sim.episode import rollout

    cam = next((c for c in manifest.cameras if c.name == camera), None)
    if cam is None or cam.mount != "vehicle":
        raise ValueError(f"manifest {manifest.name}: no camera {camera!r} riding on the base "
                         f"(has {', '.join(moving_cameras(manifest)) or 'none'})")
    if manifest.stressor("camera_jitter"):
        raise ValueError(f"manifest {manifest.name}: camera jitter moves the picture at render time, not the camera")
    poses: list[PinholeCamera] = []

    def on_frame(scene, renderer, data, name, angles) -> None:
        if name == camera:
            poses.append(PinholeCamera.from_mujoco(scene.model, data, camera, *cam.resolution))

    ep = rollout(manifest, seed, on_frame=on_frame, record=(camera,))
    n = len(ep.frames[camera])
    truth = heldout.Truth(camera=camera, fps=float(cam.fps), frames=ep.frames[camera], masks=None,
                          package_xyz=np.zeros((n, 3)), top_z=0.0, step_time=np.asarray(ep.time, float),
                          action=np.asarray(ep.action, float))
    return truth, poses


def window_rows(windows: list[physics.Window], truths: dict[str, np.ndarray], poses: dict[str, list[PinholeCamera]],
                horizons: list[int], size: int) -> list[dict]:
    """Per window, horizon and source: the re-estimated motion's errors (`motion_errors`).
    truths[episode key] holds the episode's true frames at the model's size, poses[key] the
    camera at each of its frames (the rollout's resolution)."""
    rows, true_steps = [], {}  # the true frames' steps, estimated once where windows overlap
    for w in windows:
        key, last = w.info["episode"], int(w.info["last_context_frame"])
        cams = [c.square(size) for c in poses[key][last:last + len(w.true) + 1]]
        clips = {"simulator": [truths[key][last], *w.true],
                 **{s: [w.context_last, *w.frames(s)] for s in SOURCES[1:]}}
        for source, clip in clips.items():
            shared = {"steps": true_steps, "keys": [(key, last + i) for i in range(len(clip))]} \
                if source == "simulator" else {}
            for h, errors in enumerate(trajectory_errors(clip, cams, **shared), start=1):
                if h in horizons:
                    rows.append({"window": w.key, "horizon": h, "source": source, **errors})
    return rows


def paired_difference(rows: list[dict], horizon: int, source: str, other: str, draws: int = 2000,
                      seed: int = 0, value: str = "rotation_deg") -> dict | None:
    """Mean of ``source``'s minus ``other``'s ``value`` (rotation error) over the windows both have at
    ``horizon``, with a 95% bootstrap interval that resamples whole episodes (a window's key is
    ``episode@frame``; windows of one episode overlap, so they are not independent draws).
    None when no window has both."""
    per_episode: dict[str, list[float]] = defaultdict(list)
    pairs: dict[str, dict] = defaultdict(dict)
    for r in rows:
        if r["horizon"] == horizon and r["source"] in (source, other):
            pairs[r["window"]][r["source"]] = r[value]
    for window, got in pairs.items():
        if source in got and other in got and not (math.isnan(got[source]) or math.isnan(got[other])):
            per_episode[window.rsplit("@", 1)[0]].append(got[source] - got[other])
    if not per_episode:
        return None
    episodes = [np.asarray(v) for v in per_episode.values()]
    rng = np.random.default_rng(seed)
    means = [np.concatenate([episodes[i] for i in rng.integers(0, len(episodes), len(episodes))]).mean()
             for _ in range(draws)]
    low, high = np.percentile(means, [2.5, 97.5])
    return {"mean": float(np.concatenate(episodes).mean()), "low": float(low), "high": float(high),
            "episodes": len(episodes), "windows": int(sum(len(v) for v in episodes))}


def check_beats_copy_last(table: list[dict], min_h: int = 4, rows: list[dict] | None = None) -> dict:
    """Issue 33's target: the model's mean rotation error below copy-last-frame's at every horizon
    of `min_h` frames or more. With the per-window ``rows``, each horizon's model-minus-floor
    difference also carries its episode-bootstrap interval (`paired_difference`), which says
    whether the margin holds beyond the episodes drawn."""
    by = {(r["horizon"], r["source"]): r["rotation_mean_deg"] for r in table}
    horizons = sorted({h for h, _ in by if h >= min_h})
    detail = {h: (by.get((h, "model")), by.get((h, "floor"))) for h in horizons}
    passed = bool(horizons) and all(m is not None and f is not None and m < f for m, f in detail.values())
    out = {"passed": passed, "min_horizon": min_h,
           "model_vs_floor_deg": {str(h): [m, f] for h, (m, f) in detail.items()}}
    if rows is not None:
        out["model_minus_floor_deg"] = {str(h): paired_difference(rows, h, "model", "floor") for h in horizons}
        out["model_minus_shuffled_deg"] = {str(h): paired_difference(rows, h, "model", "shuffled") for h in horizons}
    return out


def report_body(table: list[dict], check: dict, counts: dict) -> str:
    """Markdown: the table per horizon and source, the check, the window counts."""
    def fmt(v, digits=2):
        return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"

    lines = ["| horizon (frames) | source | pairs | rotation error mean / median (deg) | "
             "direction error mean / median (deg) | true rotation (deg) | failed |", "|---|---|---|---|---|---|---|"]
    for r in table:
        lines.append(f"| {r['horizon']} | {r['source']} | {r['pairs']} | {fmt(r['rotation_mean_deg'])} / "
                     f"{fmt(r['rotation_median_deg'])} | {fmt(r['direction_mean_deg'])} / "
                     f"{fmt(r['direction_median_deg'])} | {fmt(r.get('true_rotation_mean_deg'))} | {r['failures']} |")
    verdict = "passed" if check["passed"] else "failed"
    paired = []
    for name, other in (("model_minus_floor_deg", "copy-last"), ("model_minus_shuffled_deg", "shuffled actions")):
        for h, d in check.get(name, {}).items():
            if d is not None:
                paired.append(f"| {h} | model minus {other} | {d['mean']:+.2f} [{d['low']:+.2f}, {d['high']:+.2f}] | "
                              f"{d['episodes']} / {d['windows']} |")
    paired_table = ("\n\nPaired difference of rotation error per window, 95% interval from resampling whole "
                    "episodes:\n\n| horizon (frames) | difference | mean [interval] (deg) | episodes / windows |\n"
                    "|---|---|---|---|\n" + "\n".join(paired)) if paired else ""
    return (f"{counts['windows']} windows of {counts['episodes']} held-out episodes (seeds {counts['seeds']}), "
            f"camera `{counts['camera']}`; {counts['rollout_s_per_frame']:.4f} s of rollout per generated frame "
            "(encoding and decoding included).\n\n" + "\n".join(lines) +
            f"\n\nRotation error below copy-last-frame's at every horizon of {check['min_horizon']} frames or more: "
            f"**{verdict}** (model, floor: {check['model_vs_floor_deg']}).{paired_table}\n")


__all__ = ["SOURCES", "moving_cameras", "render_heldout", "window_rows", "motion_table", "check_beats_copy_last",
           "paired_difference", "report_body"]

"""Multi-view rigs evaluated (issue 33 point 4): a world model trained on a rig's tiled video
generates every view together; from held-out first frames and the commanded motion, does the
rig move as commanded, and do its views agree with each other?

Per window (its reference is the last context frame: the render for the simulator's row, its
reconstruction for every decoded row) and horizon, per source (simulator, ceiling, model,
shuffled actions, floor = copy-last-frame):
- **ego-motion**: the rig's planar motion from all views (`tasks.world.ego_motion`, metric
  through the reference's rendered depth) against the motion the simulator drove, in cm at the
  rig's centre and degrees of yaw, and against the motion the actions commanded (their
  velocities integrated over the horizon; the simulator's own motion lags the command a little,
  and that gap is reported beside it);
- **views agree**: each view's own estimate of the rig's motion; per neighbouring pair of the
  layout, how far apart (cm) the two put the rig's centre. Views drawn as one rigid rig agree to
  within the estimator's noise (the simulator's row); views generated each its own way do not;
- **Sampson error** of ORB matches between neighbouring views under the rig's known geometry, as
  the physics evaluation reports it for camera pairs (with views 90 degrees apart and about 20
  degrees of overlap most matches are wrong even between renders: read it against the
  simulator's row).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass

import cv2
import numpy as np

from schemas.manifest import ScenarioManifest
from tasks.sim.rigs import ring_pairs, tile, untile
from tasks.tokenize.data import square
from tasks.world import ego_motion, heldout, physics
from tasks.world.geometry import PinholeCamera, fundamental_matrix, orb_matches, sampson_distances

SOURCES = ("simulator", "ceiling", "model", "shuffled", "floor")


@dataclass(frozen=True)
class RigTruth:
    """One held-out episode of a rig: its tiled frames, steps and actions (``truth``), and per
    camera its pose and depth map (m, ``F x H x W`` float32) at each frame."""

    truth: heldout.Truth
    layout: tuple[tuple[str, ...], ...]
    poses: dict[str, list[PinholeCamera]]
    depths: dict[str, np.ndarray]


def render_heldout(manifest: ScenarioManifest, seed: int, rig_name: str) -> RigTruth:
    """Roll the manifest out at ``seed`` recording the rig's cameras, with their poses and depth."""
    from tasks.sim.episode import rollout

    rig = manifest.rig(rig_name)
    if rig is None:
        raise ValueError(f"manifest {manifest.name}: no rig {rig_name!r} "
                         f"(has {', '.join(r.name for r in manifest.rigs) or 'none'})")
    cams = {c.name: c for c in manifest.cameras}
    fixed = [n for n in rig.cameras if cams[n].mount != "vehicle"]
    if fixed:
        raise ValueError(f"manifest {manifest.name}: rig {rig_name!r} camera(s) {', '.join(fixed)} do not ride on "
                         "the vehicle; the rig's ego-motion needs cameras that move with it")
    if manifest.stressor("camera_jitter"):
        raise ValueError(f"manifest {manifest.name}: camera jitter moves the picture at render time, not the camera")
    width, height = cams[rig.cameras[0]].resolution
    width, height = width * len(rig.layout[0]), height * len(rig.layout)
    if width != height:
        raise ValueError(f"manifest {manifest.name}: rig {rig_name!r} tiles to {width}x{height}; a world model sees "
                         "square pictures (frames are centre-cropped to a square), so its views would be cut")
    poses: dict[str, list[PinholeCamera]] = {n: [] for n in rig.cameras}
    depths: dict[str, list[np.ndarray]] = {n: [] for n in rig.cameras}

    def on_frame(scene, renderer, data, name, angles) -> None:
        if name in poses:
            poses[name].append(PinholeCamera.from_mujoco(scene.model, data, name, *cams[name].resolution))
            depths[name].append(renderer.depth(data, name).astype(np.float32))

    ep = rollout(manifest, seed, on_frame=on_frame, record=tuple(rig.cameras))
    frames = tile(ep.frames, rig.layout)
    truth = heldout.Truth(camera=rig.name, fps=float(cams[rig.cameras[0]].fps), frames=frames, masks=None,
                          package_xyz=np.zeros((len(frames), 3)), top_z=0.0, step_time=np.asarray(ep.time, float),
                          action=np.asarray(ep.action, float))
    return RigTruth(truth, rig.layout, poses, {n: np.stack(d) for n, d in depths.items()})


def scaled(camera: PinholeCamera, side: int) -> PinholeCamera:
    """A square view's camera for the view resized to ``side`` x ``side``."""
    return camera.square(side) if camera.width != side else camera


def _depth(depth: np.ndarray, side: int) -> np.ndarray:
    return depth if depth.shape[0] == side else cv2.resize(depth, (side, side), interpolation=cv2.INTER_NEAREST)


def _sampson(later: dict[str, np.ndarray], cams: dict[str, PinholeCamera], a: str, b: str) -> np.ndarray:
    pa, pb = orb_matches(later[a], later[b])
    return sampson_distances(fundamental_matrix(cams[a], cams[b]), pa, pb) if len(pa) else np.zeros(0)


def window_rows(windows: list[physics.Window], truths: dict[str, RigTruth], horizons: list[int]) -> list[dict]:
    """Per window, horizon and source: ego-motion error (cm, degrees), the true displacement, the
    points fitted, and per neighbouring pair of views their motions' disagreement (cm) and the
    Sampson distances of their ORB matches. ``truths[episode key]`` is the episode's `RigTruth`."""
    rows = []
    for w in windows:
        key, last = w.info["episode"], int(w.info["last_context_frame"])
        rig = truths[key]
        side = w.true.shape[1] // len(rig.layout)
        names = [n for row in rig.layout for n in row]
        pairs = ring_pairs(rig.layout)
        cams = {n: scaled(rig.poses[n][last], side) for n in names}
        depths = {n: _depth(rig.depths[n][last], side) for n in names}
        centre = np.mean([rig.poses[n][last].position for n in names], axis=0)
        reference = {"simulator": untile(square(rig.truth.frames[last:last + 1], w.true.shape[1])[0],
                                         rig.layout),
                     **{s: untile(w.context_last, rig.layout) for s in SOURCES[1:]}}
        fps = rig.truth.fps
        reached = [h for h in horizons if h <= len(w.true)]
        clips = {"simulator": w.true, **{s: w.frames(s) for s in SOURCES[1:]}}
        views = {s: [untile(clips[s][h - 1], rig.layout) for h in reached] for s in SOURCES}
        # Per source, every view's corners tracked once through the horizons' frames in order
        # (each horizon's through the earlier ones'), shared by the joint fit and each view's own.
        tracked = {s: ego_motion.correspondences_through(reference[s], views[s], cams, depths) for s in SOURCES}
        for i, h in enumerate(reached):
            truth = ego_motion.true_motion(rig.poses[names[0]][last], rig.poses[names[0]][last + h])
            command = ego_motion.commanded_motion(rig.truth.step_time, rig.truth.action, last / fps,
                                                  (last + h) / fps, centre)
            driven_cm = ego_motion.error_cm(truth, command, centre)[0]
            later_cams = {n: scaled(rig.poses[n][last + h], side) for n in names}
            for source in SOURCES:
                later, points = views[source][i], tracked[source][i]
                joint = ego_motion.fit(list(points.values()))
                cm, yaw = ego_motion.error_cm(joint, truth, centre)
                own = {n: ego_motion.fit([points[n]]) if n in points else None for n in names}
                agree = {f"{a}-{b}": (100.0 * float(np.linalg.norm(own[a].apply(centre) - own[b].apply(centre)))
                                      if own[a] is not None and own[b] is not None else math.nan) for a, b in pairs}
                rows.append({"window": w.key, "horizon": h, "source": source, "ego_cm": cm, "yaw_deg": yaw,
                             "command_cm": ego_motion.error_cm(joint, command, centre)[0], "driven_cm": driven_cm,
                             "true_cm": 100.0 * math.hypot(truth.dx, truth.dy),
                             "points": joint.points if joint is not None else 0, "views_cm": agree,
                             "sampson_px": {f"{a}-{b}": _sampson(later, later_cams, a, b).tolist() for a, b in pairs}})
    return rows


def _stats(values) -> tuple[float | None, float | None]:
    v = np.asarray([x for x in values if x is not None and not math.isnan(x)], float)
    return (float(v.mean()), float(np.median(v))) if len(v) else (None, None)


def ego_table(rows: list[dict]) -> list[dict]:
    """Per horizon and source: ego-motion error mean and median (cm), yaw error mean (deg), the
    error against the commanded motion (mean cm) and how far the simulator's motion itself is
    from the command (mean cm), the true displacement's mean (cm), windows measured and windows
    where the fit failed."""
    groups: dict[tuple[int, str], list[dict]] = defaultdict(list)
    for r in rows:
        groups[(r["horizon"], r["source"])].append(r)
    table = []
    for (h, source), group in sorted(groups.items(), key=lambda kv: (kv[0][0], SOURCES.index(kv[0][1]))):
        mean, median = _stats(r["ego_cm"] for r in group)
        table.append({"horizon": h, "source": source, "windows": len(group), "ego_mean_cm": mean,
                      "ego_median_cm": median, "yaw_mean_deg": _stats(r["yaw_deg"] for r in group)[0],
                      "command_mean_cm": _stats(r["command_cm"] for r in group)[0],
                      "driven_vs_command_cm": _stats(r["driven_cm"] for r in group)[0],
                      "true_mean_cm": _stats(r["true_cm"] for r in group)[0],
                      "failures": sum(1 for r in group if r["ego_cm"] is None or math.isnan(r["ego_cm"]))})
    return table


def views_table(rows: list[dict]) -> list[dict]:
    """Per horizon, source and neighbouring pair: the views' motions' disagreement (median cm)
    and the Sampson distances pooled over windows (matches, median px, share within 1 px)."""
    agree: dict[tuple, list[float]] = defaultdict(list)
    sampson: dict[tuple, list[float]] = defaultdict(list)
    for r in rows:
        for pair, cm in r["views_cm"].items():
            agree[(r["horizon"], r["source"], pair)].append(cm)
            sampson[(r["horizon"], r["source"], pair)].extend(r["sampson_px"][pair])
    table = []
    for key in sorted(agree, key=lambda k: (k[0], SOURCES.index(k[1]), k[2])):
        d = np.asarray(sampson[key], float)
        table.append({"horizon": key[0], "source": key[1], "pair": key[2], "views_median_cm": _stats(agree[key])[1],
                      "matches": int(len(d)), "sampson_median_px": float(np.median(d)) if len(d) else None,
                      "sampson_within_1px": float((d < 1).mean()) if len(d) else None})
    return table


def check_beats_copy_last(table: list[dict], rows: list[dict]) -> dict:
    """The model's mean ego-motion error below copy-last-frame's at every horizon, each margin with
    its episode-bootstrap 95% interval (`camera_control.paired_difference` on ``ego_cm``)."""
    from tasks.world.camera_control import paired_difference

    by = {(r["horizon"], r["source"]): r["ego_mean_cm"] for r in table}
    horizons = sorted({h for h, _ in by})
    detail = {h: (by.get((h, "model")), by.get((h, "floor"))) for h in horizons}
    passed = bool(horizons) and all(m is not None and f is not None and m < f for m, f in detail.values())
    return {"passed": passed, "model_vs_floor_cm": {str(h): [m, f] for h, (m, f) in detail.items()},
            "model_minus_floor_cm": {str(h): paired_difference(rows, h, "model", "floor", value="ego_cm")
                                     for h in horizons}}


def report_body(ego: list[dict], views: list[dict], check: dict, counts: dict) -> str:
    """Markdown: the ego-motion table, the views' agreement and Sampson table, the check."""
    def fmt(v, digits=2):
        return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"

    lines = ["| horizon (frames) | source | windows | ego-motion error mean / median (cm) | yaw error (deg) | "
             "from the commanded motion, mean (cm) | true motion (cm) | failed |", "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['horizon']} | {r['source']} | {r['windows']} | {fmt(r['ego_mean_cm'])} / "
              f"{fmt(r['ego_median_cm'])} | {fmt(r['yaw_mean_deg'])} | {fmt(r['command_mean_cm'])} | "
              f"{fmt(r['true_mean_cm'])} | {r['failures']} |" for r in ego]
    drift = {r["horizon"]: r["driven_vs_command_cm"] for r in ego}
    pairs = ["| horizon (frames) | source | views | motions apart, median (cm) | Sampson matches | median (px) | "
             "within 1 px |", "|---|---|---|---|---|---|---|"]
    pairs += [f"| {r['horizon']} | {r['source']} | {r['pair']} | {fmt(r['views_median_cm'])} | {r['matches']} | "
              f"{fmt(r['sampson_median_px'])} | {fmt(r['sampson_within_1px'])} |" for r in views]
    paired = [f"{h}: {d['mean']:+.2f} cm [{d['low']:+.2f}, {d['high']:+.2f}]"
              for h, d in check["model_minus_floor_cm"].items() if d is not None]
    verdict = "passed" if check["passed"] else "failed"
    return (f"{counts['windows']} windows of {counts['episodes']} held-out episodes (seeds {counts['seeds']}), "
            f"rig `{counts['rig']}` ({counts['views']} views); {counts['rollout_s_per_frame']:.4f} s of rollout "
            "per generated frame (encoding and decoding included).\n\n"
            "Ego-motion: where the views put the rig against where the simulator drove it, and against where the "
            "commanded velocities would put it (the simulator's own motion is "
            + ", ".join(f"{fmt(d)} cm" for d in drift.values()) + " from the command at horizons "
            + ", ".join(str(h) for h in drift) + ").\n\n" + "\n".join(lines) +
            "\n\nViews: how far apart neighbouring views' own motion estimates put the rig, and the Sampson error of "
            "their ORB matches under the rig's geometry.\n\n" + "\n".join(pairs) +
            f"\n\nEgo-motion error below copy-last-frame's at every horizon: **{verdict}** "
            f"(model minus copy-last, 95% interval over episodes: {'; '.join(paired) or '-'}).\n")


__all__ = ["SOURCES", "RigTruth", "render_heldout", "window_rows", "ego_table", "views_table", "check_beats_copy_last",
           "report_body"]

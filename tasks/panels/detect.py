"""Judge an episode from its frames alone: the verdict a world model's generated video earns.

The simulator judges from its state; a world model only has pixels. `judge_frames` finds
what the evaluation target is about in a world-mounted camera's frames and decides it the
way the simulator would. Shipped: ``push_to_goal``: the green goal disc in the first frame
(the real one, for generated frames), and success when the disc is covered at the end, the
package resting on it; on rendered frames the package is also tracked by its colours from
where it starts, placed on the table through the camera's pinhole model, and a track ending
outside the tolerance vetoes a partly covered disc (a near miss). A shaking camera is undone by
phase correlation, dim light by one gain for the clip. ``lift_clear`` (the bin pick): whether
the package left its place and is seen lifted by the lift height (`detect_lift`). Other targets
(``reach_goal``) return an undecided verdict (success None) rather than a guess.

Version 8 (a disc mostly covered while the package is tracked too far off to cover it is
undecided) on the 84 push_closeup calibration episodes (scripted at noise 0.3, 0.8 and 1.0,
every cell of bench/vision_panels.py's grid, seeds 30000-30003, 2026-11-27): 80 decided, 80
agreeing; the 4 it leaves undecided are successes whose track an occluder or distractors threw
0.16 to 0.26 m off (version 7 called them successes). It keeps a policy that parks the arm over
the goal, the package far away, from being called a success.

Versions 5 and 6 (undecided within the tracker's precision of the tolerance; a covered disc
pixel is one that changed colour), on bench/vision_panels.py's push panel (7 cells x 8 seeds,
a state and a vision policy, 112 episodes): version 6 agrees on 91 of 95 decided (balanced
0.978; 17 undecided, 8 of them among the simulator's 12 failures, mostly the vision policy's
near misses), version 5 on 89 of 95 (0.967); version 4 decided all 112 and agreed on 103
(balanced 0.845), three of its errors packages 0.051 m from the goal called successes.

Version 4 (the cover), on push_closeup's held-out panel (manifests/grids/push_heldout.yaml, 8
seeds, scripted at noise 0.3, 0.8 and 1.0, and a BC policy): 216 of 224 renders agree with the
simulator (version 3: 213); on the tokenizer's reconstructions of the 168 scripted episodes it
decides 144 and agrees on 138 (version 3: 111 of 138); the dim cell is undecided there, since
the tokenizer loses the disc. The earlier figures below are version 3's.

Measured against the simulator on the push manifest's overhead camera (128 x 128): 25 of 28
episodes agree at controller noise 0.5 and 0.8 (seeds 100-115 and 11-22); the misses are
lost tracks when the package's colours match the table's. Version 3 (a lost package is
searched for again): 56 of 56 on conveyor_push (scripted at noise 0.02 and 0.8, seeds
11-14, every stressor cell), 61 of 63 on push_closeup's side camera, and 12 decided, 9
agreeing, on tokenizer reconstructions of 12 push_closeup episodes (version 2: 9 and 4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from schemas.manifest import Camera, Evaluation

# Part of every evaluation's key: a changed detector re-judges. 2: sizes and heights from the
# camera's pose (side views), not from an overhead camera's height. 3: a lost package is
# searched for in a widening window (decoded frames), the largest blob of its colours.
# 4: the verdict is whether the goal disc is covered at the end (the package resting on it),
# not where the colour track ends; generated frames are judged against the real first frame's disc.
# 5: a partly covered disc whose track ends within the tracker's precision (TRACK_PRECISION_M)
# of the tolerance is undecided: neither cue can tell a millimetre's near miss from a success.
# 6: on rendered frames a disc pixel is visible only if it also keeps its first-frame colour
# (a package the appearance stressor made green covered the disc unseen).
# 7: lift_clear is judged too (`detect_lift.judge_lift`); push verdicts are unchanged.
# 8: on rendered frames a disc mostly covered (under half of it visible) whose package is tracked
# too far away to be what covers it (beyond the tolerance plus the package's half length plus the
# tracker's precision) is undecided: something else hides the disc (an arm parked over it: a
# poor policy fooled version 7).
DETECTOR_VERSION = 8
COVERED = 0.85  # below this share of the goal disc still visible at the end, it is covered
TABLE_TOP = 0.10  # tasks/sim/scene.py: the push table's top (m)
PACKAGE_HALF = (0.04, 0.03, 0.03)  # tasks/sim/scene.py: the package's half sizes (m)
# How far the package's final track lies from where the simulator has it: the median absolute
# error, 0.0149 m, over 84 push_closeup episodes (scripted at noise 0.3, 0.8 and 1.0, every cell
# of bench/vision_panels.py's grid, seeds 30000-30003, none of them a seed any bench evaluates),
# measured 2026-11-26. Inside the partly-covered band the tracks were within 0.025 m.
TRACK_PRECISION_M = 0.015
SAME_COLOUR = 0.15  # a rendered disc pixel left uncovered keeps its colour (renders repeat exactly)


@dataclass(frozen=True)
class Verdict:
    success: bool | None  # None: the detector cannot tell from these frames
    reason: str
    distance_m: float | None = None


def camera_axes(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(position, 3 x 3 world-from-camera rotation: columns right, up, backward), as
    tasks.sim.scene.look_quat places a MuJoCo camera (it looks along its -z)."""
    pos = np.asarray(camera.position, float)
    fwd = np.asarray(camera.look_at, float) - pos
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, (0.0, 0.0, 1.0))
    if np.linalg.norm(right) < 1e-6:
        right = np.cross(fwd, (1.0, 0.0, 0.0))
    right /= np.linalg.norm(right)
    return pos, np.column_stack([right, np.cross(-fwd, right), -fwd])


def focal_px(camera: Camera) -> float:
    return camera.resolution[1] / 2 / math.tan(math.radians(camera.fovy_deg) / 2)


def project(camera: Camera, points: np.ndarray) -> np.ndarray:
    """N x 3 world points -> N x 2 pixel coordinates (column, row; row 0 at the top)."""
    pos, rot = camera_axes(camera)
    local = (np.atleast_2d(points) - pos) @ rot
    f, (w, h) = focal_px(camera), camera.resolution
    depth = -local[:, 2]
    return np.column_stack([w / 2 + f * local[:, 0] / depth, h / 2 - f * local[:, 1] / depth])


def view_ray(camera: Camera, pixel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(camera position, world direction) of the ray seen at ``pixel`` (column, row)."""
    pos, rot = camera_axes(camera)
    f, (w, h) = focal_px(camera), camera.resolution
    return pos, rot @ np.array([(pixel[0] - w / 2) / f, -(pixel[1] - h / 2) / f, -1.0])


def on_plane(camera: Camera, pixel: np.ndarray, z: float) -> np.ndarray:
    """The world point at height z seen at ``pixel`` (column, row)."""
    pos, ray = view_ray(camera, pixel)
    return pos + ray * (z - pos[2]) / ray[2]


def depth(camera: Camera, point: np.ndarray) -> float:
    """Distance of a world point in front of the camera along its optical axis (m)."""
    pos, rot = camera_axes(camera)
    return float(-((np.asarray(point, float) - pos) @ rot)[2])


def disc_area_px(camera: Camera, radius: float, samples: int = 64) -> float:
    """Pixel area of a table disc of ``radius`` where the optical axis meets the table: its
    projected outline (an ellipse for a camera looking at the table from the side)."""
    w, h = camera.resolution
    centre = on_plane(camera, np.array([w / 2, h / 2]), TABLE_TOP)
    angle = np.linspace(0, 2 * math.pi, samples, endpoint=False)
    rim = centre + radius * np.column_stack([np.cos(angle), np.sin(angle), np.zeros(samples)])
    x, y = project(camera, rim).T
    return float(0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1))))


def seen_height(camera: Camera, point: np.ndarray) -> float:
    """Height of the package's visible centroid: its top face from above, lower from the side
    (top and front faces weighted by the areas the camera sees of them)."""
    pos, _ = camera_axes(camera)
    ray = np.asarray(point, float) - pos
    sin = min(1.0, abs(ray[2]) / max(float(np.linalg.norm(ray)), 1e-9))
    cos = math.sqrt(max(0.0, 1.0 - sin * sin))
    top = 4 * PACKAGE_HALF[0] * PACKAGE_HALF[1] * sin
    side = 4 * PACKAGE_HALF[1] * PACKAGE_HALF[2] * cos
    return TABLE_TOP + PACKAGE_HALF[2] * (1 + top / max(top + side, 1e-9))


def _green(frame: np.ndarray) -> np.ndarray:
    """Saturated green pixels. Relative thresholds: dim light darkens and desaturates the disc
    (about 64, 100, 70 at 80 lux)."""
    rgb = frame.astype(np.float32)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return (g - np.maximum(r, b) > 0.25 * g + 4) & (g > 0.3 * np.percentile(rgb, 99))


def _goal_mask(frame: np.ndarray, camera: Camera, tolerance: float) -> np.ndarray | None:
    """Pixels of the goal disc: the saturated green blob closest in area to the disc's
    projected size. None when no blob fits (dark frames, occluded goal)."""
    green = _green(frame)
    if not green.any():
        return None
    g = frame[..., 1].astype(np.float32)
    expected = disc_area_px(camera, tolerance)
    best, found = math.log(2.5), None
    # A green table (appearance jitter) joins the disc into one big blob; the unlit disc is
    # the brightest green, so also try only the brightest green pixels.
    for mask in (green, green & (g >= 0.8 * g[green].max())):
        labels, n = ndimage.label(mask)
        areas = ndimage.sum_labels(mask, labels, range(1, n + 1))
        ratio = np.abs(np.log(np.maximum(areas, 1) / expected))
        k = int(np.argmin(ratio))
        if ratio[k] < best:
            best, found = ratio[k], labels == k + 1
    return found


def _visible(frames: np.ndarray, mask: np.ndarray, last: int = 5, unchanged: bool = False) -> tuple[float, float]:
    """(share of the goal disc's pixels green in frames[0], the largest share still green in
    any of the last ``last`` frames, each moved by its shift from frames[0]). The largest:
    something passing in front of the goal (a forklift) covers it for a few frames only; a
    package resting on it covers it in all of them. ``unchanged`` (rendered frames): a pixel
    counts as the disc only if it also keeps its first-frame colour (within SAME_COLOUR of its
    brightest channel), so a package that happens to be green (the appearance stressor
    recolours it) still covers the disc. Generated frames drift in colour: green alone there."""
    rows, cols = np.nonzero(mask)
    h, w = mask.shape
    before = frames[0][rows, cols].astype(np.int16)
    allowed = SAME_COLOUR * before.max(axis=1) + 4
    shares = []
    for frame in frames[-last:]:
        dx, dy = image_shift(frames[0], frame)
        r = np.clip(np.round(rows + dy).astype(int), 0, h - 1)
        c = np.clip(np.round(cols + dx).astype(int), 0, w - 1)
        seen = _green(frame)[r, c]
        if unchanged:
            seen &= np.abs(frame[r, c].astype(np.int16) - before).max(axis=1) <= allowed
        shares.append(float(seen.mean()))
    return float(_green(frames[0])[rows, cols].mean()), max(shares)


def _exposed(frames: np.ndarray, level: float = 220.0) -> np.ndarray:
    """One gain for the whole clip, bringing the first frame's bright end (99th percentile)
    to ``level``: dim light scales colours down, and the thresholds below are in 8-bit units."""
    bright = float(np.percentile(frames[0], 99))
    if bright >= level or bright < 4:
        return frames
    return np.clip(frames.astype(np.float32) * (level / bright), 0, 255).astype(np.uint8)


def image_shift(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(dx, dy) pixels by which frame b's content sits moved from frame a's (phase correlation
    of the whole picture: a shaking camera moves everything, the robot only a part)."""
    import cv2

    gray = [cv2.cvtColor(np.ascontiguousarray(f), cv2.COLOR_RGB2GRAY).astype(np.float32) for f in (a, b)]
    window = cv2.createHanningWindow(gray[0].shape[::-1], cv2.CV_32F)
    (dx, dy), _ = cv2.phaseCorrelate(gray[0], gray[1], window)
    return np.array([dx, dy])


def _palette(frames: np.ndarray, start: np.ndarray, half_px: float, shift: np.ndarray) -> np.ndarray:
    """The package's colours: its footprint in the first frame, without the pixels that look
    the same at the end (an occluder over it, a patch it never left), when enough remain."""
    h, w = frames.shape[1:3]
    rows, cols = np.mgrid[0:h, 0:w]
    patch = np.hypot(cols - start[0], rows - start[1]) <= max(1.0, 0.6 * half_px)
    first = frames[0][patch].astype(np.float32)
    r = np.clip(np.round(rows[patch] + shift[1]).astype(int), 0, h - 1)
    c = np.clip(np.round(cols[patch] + shift[0]).astype(int), 0, w - 1)
    changed = np.linalg.norm(first - frames[-1][r, c].astype(np.float32), axis=1) > 40
    return first[changed] if changed.sum() >= max(3, 0.2 * len(first)) else first


def palette_hits(frame: np.ndarray, palette: np.ndarray, mask: np.ndarray, tolerance: float = 28.0) -> np.ndarray:
    """H x W bool: the pixels of ``mask`` within ``tolerance`` (RGB distance) of a palette colour."""
    out = np.zeros(frame.shape[:2], bool)
    pix = frame[mask].astype(np.float32)
    out[mask] = np.min(np.linalg.norm(pix[:, None, :] - palette[None], axis=2), axis=1) < tolerance
    return out


def _track(frames: np.ndarray, start: np.ndarray, half_px: float, palette: np.ndarray) -> tuple[np.ndarray, int]:
    """Follow the package from ``start`` by its colours; returns its last seen centre and in
    how many frames it was seen.

    Each frame is searched near the last sighting; the package is the largest blob of palette
    colours there, big enough for a part of it. A frame without it widens the next search by
    half, so a package lost for a while (an arm over it, or a decoder's colours drifting for a
    few frames) is found again where it went rather than left where it was last seen."""
    h, w = frames.shape[1:3]
    rows, cols = np.mgrid[0:h, 0:w]
    if not len(palette):
        return start, 0
    base = 1.6 * half_px + 3
    window, widest = base, float(np.hypot(h, w))
    need = max(2, int(0.15 * math.pi * half_px ** 2))
    at, seen = start.astype(float), 0
    for frame in frames:
        near = np.hypot(cols - at[0], rows - at[1]) <= window
        hit = palette_hits(frame, palette, near)
        labels, n = ndimage.label(hit)
        sizes = ndimage.sum_labels(hit, labels, range(1, n + 1)) if n else np.zeros(0)
        if n and sizes.max() >= need:
            blob = labels == int(np.argmax(sizes)) + 1
            at = np.array([cols[blob].mean(), rows[blob].mean()])
            seen += 1
            window = base
        else:
            window = min(widest, 1.5 * window)
    return at, seen


def track_package(frames: np.ndarray, camera: Camera, package_start: np.ndarray) -> np.ndarray:
    """The package's centre in every frame as `judge_push` tracks it: F x 2 pixel coordinates
    (column, row) in each frame's own picture, NaN in a frame where it was not seen.

    The same steps as the verdict's track (one exposure gain for the clip, the start projected
    from ``package_start``, the first frame's palette, `_track`), read out frame by frame: frame
    t's entry is where `_track` over frames 0..t sees it at t (quadratic in F; fine for clips)."""
    frames = _exposed(frames)
    top = seen_height(camera, np.array([package_start[0], package_start[1], TABLE_TOP + PACKAGE_HALF[2]]))
    start = np.array([package_start[0], package_start[1], top])
    start_px = project(camera, start[None])[0]
    half_px = min(PACKAGE_HALF[:2]) * focal_px(camera) / depth(camera, start)
    palette = _palette(frames, start_px, half_px, image_shift(frames[0], frames[-1]))
    out = np.full((len(frames), 2), np.nan)
    seen = 0
    for t in range(len(frames)):
        at, now = _track(frames[:t + 1], start_px, half_px, palette)
        if now > seen:
            out[t] = at
        seen = now
    return out


def judge_push(frames: np.ndarray, camera: Camera, evaluation: Evaluation, package_start: np.ndarray,
               reference: np.ndarray | None = None) -> Verdict:
    """frames: F x H x W x 3 uint8 from ``camera`` (world-mounted); package_start: the
    package's xyz at the first frame (known: the world model starts from the real scene);
    reference: the real first frame that generated ``frames`` start from, where the goal is
    looked for (a tokenizer's reconstruction of a dim frame can lose the disc); by default
    frames[0]."""
    if camera.mount != "world":
        return Verdict(None, f"camera {camera.name} is not world-mounted")
    tol = evaluation.goal_tolerance_m
    goal = _goal_mask(frames[0] if reference is None else reference, camera, tol)
    if goal is None:
        return Verdict(None, "goal marker not found in the first frame")
    first, last = _visible(frames, goal, unchanged=reference is None)  # in the frames' own light
    frames = _exposed(frames)
    if first < 0.5:  # a tokenizer that cannot draw this light loses the disc in its reconstruction
        return Verdict(None, f"goal marker not drawn in the frames ({first:.0%} of it green in the first)")
    uncovered = last / first
    top = seen_height(camera, np.array([package_start[0], package_start[1], TABLE_TOP + PACKAGE_HALF[2]]))
    start = np.array([package_start[0], package_start[1], top])
    start_px = project(camera, start[None])[0]
    half_px = min(PACKAGE_HALF[:2]) * focal_px(camera) / depth(camera, start)
    shift = image_shift(frames[0], frames[-1])
    end_px, seen = _track(frames, start_px, half_px, _palette(frames, start_px, half_px, shift))
    gap, tracked = None, "package not tracked"
    if seen >= max(1, len(frames) // 4):
        rows, cols = np.nonzero(goal)
        goal_xyz = on_plane(camera, np.array([cols.mean(), rows.mean()]), TABLE_TOP)
        package = on_plane(camera, end_px - shift, top)  # back into the first frame's picture
        gap = float(np.linalg.norm(package[:2] - goal_xyz[:2]))
        tracked = f"package tracked {gap:.3f} m from it"
    # On rendered frames a track that ends outside the tolerance vetoes a disc only partly
    # covered (a near miss hides some of it too). Generated frames are judged by the disc
    # alone: a world model's package drifts in colour and its track is lost or misplaced.
    # A partly covered disc is a success or a near miss by the track, unless the track ends
    # within its own precision of the tolerance: then neither cue can tell (undecided).
    partly = reference is None and gap is not None and COVERED > uncovered >= 0.5
    near_miss = partly and gap > tol + TRACK_PRECISION_M
    if uncovered >= COVERED:
        return Verdict(False, f"goal marker uncovered at the end ({uncovered:.0%} of it visible); {tracked}", gap)
    # The disc's radius is the tolerance: a package whose centre ends farther than that plus its
    # own half length cannot overlap it at all, so the track and a disc mostly covered contradict
    # each other (a disc only partly covered with such a track is a near miss, below).
    if (reference is None and gap is not None and uncovered < 0.5
            and gap > tol + max(PACKAGE_HALF[:2]) + TRACK_PRECISION_M):
        return Verdict(None, f"undecided: goal marker covered at the end ({uncovered:.0%} of it visible), but "
                             f"{tracked}, too far to be what covers it", gap)
    if partly and abs(gap - tol) <= TRACK_PRECISION_M:
        return Verdict(None, f"undecided: goal marker partly covered at the end ({uncovered:.0%} of it visible) and "
                             f"{tracked}, within the tracker's precision ({TRACK_PRECISION_M} m) of the tolerance "
                             f"({tol} m)", gap)
    if near_miss:
        return Verdict(False, f"goal marker partly covered at the end ({uncovered:.0%} of it visible), but "
                              f"{tracked} (tolerance {tol} m)", gap)
    return Verdict(True, f"goal marker covered at the end ({uncovered:.0%} of it visible); {tracked}", gap)


def judge_frames(frames: np.ndarray, camera: Camera, evaluation: Evaluation, package_start: np.ndarray,
                 reference: np.ndarray | None = None) -> Verdict:
    """The detector for the evaluation's target; undecided where none is built. ``reference``:
    the real first frame, when ``frames`` are generated from it (see `judge_push`)."""
    if evaluation.target == "push_to_goal":
        return judge_push(frames, camera, evaluation, package_start, reference)
    if evaluation.target == "lift_clear":
        if reference is not None:  # generated frames drift in colour, which its "left its place" test reads
            return Verdict(None, "the lift detector is measured on rendered frames only, not on generated ones")
        from tasks.panels.detect_lift import judge_lift  # (it builds on this module's helpers)

        return judge_lift(frames, camera, evaluation, package_start)
    return Verdict(None, f"no frame detector for target {evaluation.target!r} yet")

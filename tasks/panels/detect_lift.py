"""The frame detector for ``lift_clear`` (the bin pick): was the package lifted clear, judged
from a world-mounted camera's frames alone.

The simulator calls a pick a success when the package ends at least ``lift_height_m`` above
where it rested, its lowest corner above the bin's rim, touching only the robot. From pixels:
1. The package's colours: those of a disc at its projected start in the first frame that a ring
   around it (the bin floor, a wall, an occluder across it) does not show (`package_palette`).
   If at least ``STAYED`` of its first-frame pixels are still there at the end, once the picture
   is aligned on its surroundings (a shaking camera; `stayed_share`), it never left: a failure.
2. Otherwise it is looked for in the last tenth of the frames: among the pixels that changed
   since the first frame, a blob of its colours of about a package's size at that distance that
   does not run out of the picture (an arm link of the same colour does). Its centre's viewing
   ray, met with the vertical through where the package started, gives its lift (`lift_seen`).
   There is no reading where the ray also meets the floor in the bin or near it (resting at the
   bin's far side looks like a low lift from the front), nor for a blob no larger than
   ``GROUND_MAX`` times a package resting where the ray meets the floor outside the bin (knocked
   out, or lifted and half hidden by the gripper).
3. The last ``SETTLED`` sightings must all give readings that agree within ``LIFT_PRECISION_M``
   (the simulator judges the end; a package still falling is undecided), and their median is
   compared with ``lift_height_m``: within ``LIFT_PRECISION_M`` of it, or with the package not
   found at the end (behind the gripper, tipped out of sight, lost in dim light), the detector
   says undecided. So failures are decided only when the package never left its place; a
   package moved within the bin, knocked out or dropped is undecided.

Measured 2026-11-27 against the simulator on `bin_pick` episodes of every cell of
`bench/vision_panels.py`'s grid (front camera, 128 px); the figures are in docs/evaluation.md
("The frame detector judges lifts too"). ``LIFT_PRECISION_M`` is the 90th percentile of the lift
reading's error (0.094 m) on the 54 scripted episodes at seeds 30000-30003 whose package was
found lifted or moved; the vision policy's successful lifts of 0.108-0.138 m read 0.0 to 0.13.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from schemas.manifest import Camera, Evaluation
from tasks.panels import detect

BIN_CENTRE = np.array([0.45, 0.0])  # tasks/sim/scene.py: the bin's centre on the floor (m)
BIN_INNER = 0.13  # tasks/sim/scene.py: half the bin's inner width (m)
BIN_FLOOR = 0.01  # tasks/sim/scene.py: the bin floor's thickness (m), above the floor outside it
STAYED = 0.5  # share of the package's first-frame pixels unchanged at the end: it never left
SAME = 20.0  # RGB distance under which a pixel is unchanged from the first frame
COLOUR = 28.0  # RGB distance to the package's palette (as detect._track)
LIFT_PRECISION_M = 0.1  # lifts this near the lift height are undecided
SIZE_RANGE = (0.25, 2.5)  # a blob of this many times a package's expected pixel area is the package
GROUND_MAX = 1.5  # a blob at most this many times a package resting where its ray meets the floor may rest there
RING = (2.5, 3.5)  # the package's surroundings in the first frame: this many projected half sizes out
SETTLED = 5  # the last sightings whose lifts must agree (within LIFT_PRECISION_M)
SHAKE = 0.04  # share of the width a shaking camera may move the picture between two frames


def _area(camera: Camera, point: np.ndarray) -> float:
    """Expected pixel area of the package at ``point`` (one long side face, as a side view shows it)."""
    f = detect.focal_px(camera)
    return 4 * detect.PACKAGE_HALF[0] * detect.PACKAGE_HALF[2] * (f / max(detect.depth(camera, point), 1e-6)) ** 2


def lift_seen(camera: Camera, pixel: np.ndarray, start: np.ndarray,
              size: float | None = None) -> tuple[float | None, float]:
    """(lift above ``start`` in m, expected pixel area of the package there) of a package seen
    at ``pixel``, ``size`` pixels large. Its height is read on the vertical through the start.
    A ray that also meets the floor in the bin, or within ``LIFT_PRECISION_M`` of it, gives no
    reading (None): resting there and a low lift look alike from the front (a lift of 0.108 m
    read 0.0 to 0.13 m). Nor does a blob no larger than ``GROUND_MAX`` times a package resting where
    the ray meets the floor outside the bin: a package knocked out and one lifted but half
    hidden by the gripper look alike."""
    pos, ray = detect.view_ray(camera, pixel)
    s = float((start[:2] - pos[:2]) @ ray[:2] / max(float(ray[:2] @ ray[:2]), 1e-12))
    point = pos + s * ray
    lift, area = float(point[2] - start[2]), _area(camera, point)
    if ray[2] < -1e-9:
        floor = detect.on_plane(camera, pixel, start[2] - BIN_FLOOR)  # resting outside the bin sits this much lower
        if np.all(np.abs(floor[:2] - BIN_CENTRE) <= BIN_INNER + LIFT_PRECISION_M):
            return None, area  # in the bin, or near enough that a low lift looks the same
        if size is not None and size <= GROUND_MAX * _area(camera, floor):
            return None, area  # as large as a package knocked out of the bin resting there
    return lift, area


def package_palette(first: np.ndarray, start_px: np.ndarray, half_px: float) -> np.ndarray:
    """The package's colours in the first frame: those of a disc at its projected centre that a
    ring around it (its surroundings: the bin floor, a wall, an occluder across it) does not
    show. Empty when the package's colours are its surroundings'."""
    h, w = first.shape[:2]
    rows, cols = np.mgrid[0:h, 0:w]
    r = np.hypot(cols - start_px[0], rows - start_px[1])
    inner = first[r <= max(1.0, 0.6 * half_px)].astype(np.float32)
    ring = first[(r >= RING[0] * half_px) & (r <= RING[1] * half_px)].astype(np.float32)
    if not len(inner) or not len(ring):
        return inner
    near = np.min(np.linalg.norm(inner[:, None, :] - ring[None], axis=2), axis=1)
    return inner[near >= COLOUR]


def stayed_share(frames: np.ndarray, mine: np.ndarray, around: np.ndarray, reach: int) -> float:
    """Share of the package's first-frame pixels (``mine``) that the last frame still shows, once
    the picture is aligned on the package's surroundings (``around``): a shaking camera moves
    everything a few pixels, within ``reach``. Aligning on the package itself would also match a
    package of one colour lifted less than its own height."""
    h, w = frames.shape[1:3]

    def moved(mask: np.ndarray, dy: int, dx: int) -> np.ndarray:
        r, c = np.nonzero(mask)
        last = frames[-1][np.clip(r + dy, 0, h - 1), np.clip(c + dx, 0, w - 1)].astype(np.float32)
        return np.linalg.norm(frames[0][r, c].astype(np.float32) - last, axis=1)

    offsets = [(dy, dx) for dy in range(-reach, reach + 1) for dx in range(-reach, reach + 1)]
    misfit = np.array([float(np.median(moved(around, dy, dx))) for dy, dx in offsets])  # an arm over part of it
    # Of the offsets that fit the surroundings about as well as the best, the smallest move.
    fits = [o for o, m in zip(offsets, misfit) if m <= misfit.min() + 2.0]
    dy, dx = min(fits, key=lambda o: o[0] ** 2 + o[1] ** 2)
    return float(np.mean(moved(mine, dy, dx) < SAME))


def _lift_at(frame: np.ndarray, first: np.ndarray, palette: np.ndarray, camera: Camera,
             start: np.ndarray) -> tuple[bool, float | None]:
    """(found, lift) of the package in one frame, from the largest changed blob of its colours
    and size; the lift is None where resting and lifted cannot be told apart (`lift_seen`)."""
    h, w = frame.shape[:2]
    moved = np.linalg.norm(frame.astype(np.float32) - first.astype(np.float32), axis=2) > SAME
    hit = detect.palette_hits(frame, palette, moved, COLOUR)
    labels, n = ndimage.label(hit)
    if not n:
        return False, None
    sizes = ndimage.sum_labels(hit, labels, range(1, n + 1))
    boxes = ndimage.find_objects(labels)
    for k in np.argsort(sizes)[::-1]:
        top, left = boxes[k][0], boxes[k][1]
        if top.start == 0 or left.start == 0 or top.stop == h or left.stop == w:
            continue  # it runs out of the picture: an arm link coming into view, not a package in it
        row, col = ndimage.center_of_mass(hit, labels, k + 1)
        lift, area = lift_seen(camera, np.array([col, row]), start, float(sizes[k]))
        if SIZE_RANGE[0] * area <= sizes[k] <= SIZE_RANGE[1] * area:
            return True, lift
    return False, None


def judge_lift(frames: np.ndarray, camera: Camera, evaluation: Evaluation, package_start: np.ndarray) -> detect.Verdict:
    """frames: F x H x W x 3 uint8 from ``camera`` (world-mounted); package_start: the package's
    xyz at the first frame. See the module docstring."""
    if camera.mount != "world":
        return detect.Verdict(None, f"camera {camera.name} is not world-mounted")
    frames = detect._exposed(frames)
    count, h, w = frames.shape[:3]
    start = np.asarray(package_start, float)
    start_px = detect.project(camera, start[None])[0]
    half_px = min(detect.PACKAGE_HALF[:2]) * detect.focal_px(camera) / detect.depth(camera, start)
    palette = package_palette(frames[0], start_px, half_px)
    rows, cols = np.mgrid[0:h, 0:w]
    r = np.hypot(cols - start_px[0], rows - start_px[1])
    patch = r <= max(1.0, 0.8 * half_px)
    mine = detect.palette_hits(frames[0], palette, patch, COLOUR) if len(palette) else np.zeros_like(patch)
    if mine.sum() < 3:
        return detect.Verdict(None, "package not told from its surroundings where it starts")
    around = (r >= RING[0] * half_px) & (r <= RING[1] * half_px)
    stayed = stayed_share(frames, mine, around, max(1, round(SHAKE * w)))
    if stayed >= STAYED:
        return detect.Verdict(False, f"package never left its place ({stayed:.0%} of it unchanged at the end)")
    tail, need = max(3, count // 10), evaluation.lift_height_m
    found = [lift for ok, lift in (_lift_at(frames[t], frames[0], palette, camera, start)
                                   for t in range(count - tail, count)) if ok]
    if len(found) < max(1, tail // 2):
        return detect.Verdict(None, f"undecided: package left its place but was found in {len(found)} of the last "
                                    f"{tail} frames")
    last = found[-SETTLED:]  # the simulator judges the end: the package must have settled by then
    if any(lift is None for lift in last):
        return detect.Verdict(None, "undecided: package seen where it could rest in the bin or be lifted about "
                                    f"{need} m")
    if max(last) - min(last) > LIFT_PRECISION_M:
        return detect.Verdict(None, f"undecided: package still moving at the end (seen {min(last):.3f} to "
                                    f"{max(last):.3f} m above where it rested in the last {len(last)} sightings)")
    lift = float(np.median(last))
    seen = f"package seen {lift:.3f} m above where it rested (need {need} m)"
    if abs(lift - need) < LIFT_PRECISION_M:
        return detect.Verdict(None, f"undecided: {seen}, within {LIFT_PRECISION_M} m of it")
    return detect.Verdict(lift > need, seen)

"""Finding the package by colour on the simulator's own renders, pixels to centimetres, the
epipolar check, and the per-horizon table on hand-made frames."""

import math

import numpy as np
import pytest

import tasks.sim  # noqa: F401
import mujoco
from tasks.manifests import load
from tasks.sim.episode import rollout
from tasks.sim.render import MultiCameraRenderer
from tasks.sim.scene import build_scene
from tasks.tokenize.data import square
from tasks.world import physics
from tasks.world.geometry import PinholeCamera, fundamental_matrix, orb_matches, sampson_distances, sampson_error
from tasks.world.heldout import render_truth
from tests.support import MANIFESTS

SIZE = 64  # the world model's frames
SEEDS = (10000, 10001, 10002, 10003)  # held-out seeds, as the physics flow uses them


@pytest.fixture(scope="module")
def push():
    return load(MANIFESTS / "conveyor_push.yaml").model_copy(update={"horizon_s": 3.0})


@pytest.fixture(scope="module")
def truths(push):
    return {seed: render_truth(push, seed, "overhead") for seed in SEEDS}


def _truth_centroids(masks: np.ndarray, full: int) -> np.ndarray:
    """Segmentation centroids at full resolution, mapped to the SIZE grid (pixel centres)."""
    return (physics.centroids(masks) + 0.5) * SIZE / full - 0.5


def test_render_truth_is_the_rollout(push, truths):
    ep = rollout(push, SEEDS[0])
    truth = truths[SEEDS[0]]
    assert np.array_equal(truth.frames, ep.frames["overhead"])
    assert np.allclose(truth.action, ep.action) and truth.masks[0].sum() > 20
    # The package starts at rest on the table and is pushed about 25 cm towards the goal.
    assert truth.top_z == pytest.approx(0.161, abs=1e-3)
    assert np.linalg.norm(truth.package_xyz[-1, :2] - truth.package_xyz[0, :2]) > 0.15


def test_colour_finds_the_package_where_the_segmentation_does(truths):
    """Fitted on even frames, scored on odd ones: the colour centroid within 1.5 px of the
    segmentation's (64 x 64) and IoU above 0.7 on most frames where the package shows."""
    close, good, close_any, shown_any = [], [], [], 0
    for truth in truths.values():
        frames, cover = square(truth.frames, SIZE), physics.coverage(truth.masks, SIZE)
        model = physics.fit_colour_model(frames[::2], cover[::2])
        assert model is not None and model.fit_iou > 0.7
        found = physics.locate(frames[1::2], model)
        truth_xy = _truth_centroids(truth.masks[1::2], truth.frames.shape[1])
        err = np.linalg.norm(physics.centroids(found) - truth_xy, axis=1)
        area = (cover[1::2] > 0.5).sum((1, 2))
        full_view = area >= 0.5 * (cover[0] > 0.5).sum()
        close += list(np.nan_to_num(err[full_view], nan=99) < 1.5)
        good += [physics.mask_iou(f, c > 0.5) > 0.7 for f, c, v in zip(found, cover[1::2], full_view) if v]
        shown_any += int((area > 0).sum())
        close_any += list(np.nan_to_num(err[area > 0], nan=99) < 1.5)
    # Measured 2026-11-23 on these seeds (3 s): 100% / 100% mostly in view. On seeds 10000-10019 (5 s):
    # 100% / 99.7% mostly in view (298 frames), 93.7% within 1.5 px with any of it in view (1388 frames).
    assert np.mean(close) >= 0.95 and np.mean(good) >= 0.9, (np.mean(close), np.mean(good))
    assert np.mean(close_any) >= 0.85 and shown_any > 100


def test_a_frame_of_motion_is_measurable(push, truths):
    """While the package is pushed (about 0.5 px a frame at 64 x 64), a prediction one frame
    late is off by a measurable amount, well above the detector's jitter on a resting
    package; four frames late, by about the distance the package travelled."""
    camera = PinholeCamera.from_manifest(push.cameras[0]).square(SIZE)
    late1, late4, travelled4, still = [], [], [], []
    for truth in truths.values():
        frames, cover = square(truth.frames, SIZE), physics.coverage(truth.masks, SIZE)
        xy = physics.centroids(physics.locate(frames, physics.fit_colour_model(frames, cover)))
        projected = camera.project(truth.package_xyz + [0, 0, 0.03])  # the top face's centre
        step = np.linalg.norm(np.diff(truth.package_xyz[:, :2], axis=0), axis=1)
        moving, resting = np.flatnonzero(step[:-4] > 0.004), np.flatnonzero(step[:-4] < 1e-4)  # 12 cm/s
        late1 += list(np.linalg.norm(xy[moving + 1] - xy[moving], axis=1))
        late4 += list(np.linalg.norm(xy[moving + 4] - xy[moving], axis=1))
        travelled4 += list(np.linalg.norm(projected[moving + 4] - projected[moving], axis=1))
        still += list(np.linalg.norm(xy[resting + 1] - xy[resting], axis=1))
    late1, late4, travelled4, still = (np.nanmean(v) for v in (late1, late4, travelled4, still))
    # Measured 2026-11-23: one frame late 1.15 px, four 2.28 px (travelled 1.96), at rest 0.07 px.
    assert late1 > 0.4 and late1 > 4 * still, (late1, still)
    assert late4 == pytest.approx(travelled4, rel=0.3), (late4, travelled4)


def test_pixels_to_centimetres_on_a_package_moved_by_a_known_distance(push):
    """Place the package (the arm at rest) at known offsets, render, find it by colour and
    back-project: the distances moved come back within a centimetre at 64 x 64."""
    scene = build_scene(push, SEEDS[0])
    model, data = scene.model, mujoco.MjData(scene.model)
    data.qpos[:] = scene.initial_qpos
    body = model.body(scene.objects[0])
    adr = model.jnt_qposadr[body.jntadr[0]]
    offsets = np.array([[0.0, 0.0], [0.0, 0.10], [0.08, 0.06], [-0.1, 0.2]])
    frames, masks, where = [], [], []
    with MultiCameraRenderer(model, {"overhead": (128, 128)}) as renderer:
        for dx, dy in offsets:
            data.qpos[adr:adr + 3] = scene.initial_qpos[adr:adr + 3] + [dx, dy, 0.0]
            mujoco.mj_forward(model, data)
            frames.append(renderer.render(data, "overhead"))
            masks.append(renderer.segment(data, "overhead") == model.geom(f"{scene.objects[0]}_geom").id)
            where.append(data.xpos[body.id].copy())
    camera = PinholeCamera.from_manifest(push.cameras[0])
    top = where[0][2] + scene.target_half[2]
    for size, tol_cm in ((128, 0.6), (SIZE, 1.5)):
        small = square(np.array(frames), size)
        colour = physics.fit_colour_model(small, physics.coverage(np.array(masks), size))
        on_plane = camera.square(size).to_plane(physics.centroids(physics.locate(small, colour)), top)
        moved = 100 * np.linalg.norm(on_plane[1:, :2] - on_plane[0, :2], axis=1)
        assert moved == pytest.approx(100 * np.linalg.norm(offsets[1:], axis=1), abs=tol_cm), (size, moved)


def test_camera_projection_round_trips_and_follows_the_resize(push):
    cam = PinholeCamera.from_manifest(push.cameras[0])
    assert cam.focal_px == pytest.approx(64 / math.tan(math.radians(22.5)))
    pts = np.array([[0.45, 0.0, 0.1], [0.5, -0.1, 0.16], [0.3, 0.2, 0.0]])
    uv = cam.project(pts)
    assert uv[0] == pytest.approx([63.5, 63.5])  # the look-at point is the image centre
    back = np.stack([cam.to_plane(uv[i:i + 1], pts[i, 2])[0] for i in range(3)])
    assert np.allclose(back, pts)
    assert np.allclose(cam.square(32).project(pts), (uv + 0.5) / 4 - 0.5)
    wide = PinholeCamera.from_fovy(160, 96, 70, [0, 0, 1], np.eye(3))
    cropped = wide.square(48)  # the centre 96 x 96, halved
    p = np.array([[0.1, 0.05, 0.0]])
    assert np.allclose(cropped.project(p), (wide.project(p) - [32, 0] + 0.5) / 2 - 0.5)


def test_projection_matches_the_renderer(push, truths):
    truth = truths[SEEDS[0]]
    cam = PinholeCamera.from_manifest(push.cameras[0])
    top_face = truth.package_xyz[0] + [0, 0, 0.03]
    assert np.linalg.norm(cam.project(top_face)[0] - physics.centroids(truth.masks[:1])[0]) < 0.5


def test_cameras_from_the_manifest_sit_where_mujoco_puts_them():
    scenario = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    scene = build_scene(scenario, SEEDS[0])
    data = mujoco.MjData(scene.model)
    mujoco.mj_forward(scene.model, data)
    for cam in scenario.cameras[:2]:
        ours = PinholeCamera.from_manifest(cam)
        theirs = PinholeCamera.from_mujoco(scene.model, data, cam.name, *cam.resolution)
        assert np.allclose(ours.position, theirs.position) and np.allclose(ours.rotation, theirs.rotation, atol=1e-6)
        assert ours.focal_px == pytest.approx(theirs.focal_px)
    with pytest.raises(ValueError, match="rides on the wrist"):
        PinholeCamera.from_manifest(scenario.cameras[2])


# -- the epipolar check -------------------------------------------------------------------
@pytest.fixture(scope="module")
def stereo():
    """The bin pick's front_left camera and a second one 20 cm beside it, lit normally."""
    base = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    left = base.cameras[0]
    right = left.model_copy(update={"name": "beside", "position": (1.1, 0.35, 0.75)})
    scenario = base.model_copy(update={"cameras": (left, right), "horizon_s": 1.0,
                                       "stressors": tuple(s for s in base.stressors if s.kind != "dim_light")})
    ep = rollout(scenario, SEEDS[0])
    # A wrong pose: the second camera believed to look 10 cm higher (a 5 degree pitch error).
    tilted = PinholeCamera.from_manifest(right.model_copy(update={"look_at": (0.45, 0.0, 0.2)}))
    return (ep.frames[left.name], ep.frames["beside"], PinholeCamera.from_manifest(left),
            PinholeCamera.from_manifest(right), tilted)


def test_fundamental_matrix_is_exact_on_projected_points(stereo):
    _, _, a, b, _ = stereo
    pts = np.random.default_rng(0).uniform([0.2, -0.3, 0.0], [0.7, 0.3, 0.3], (50, 3))
    assert sampson_distances(fundamental_matrix(a, b), a.project(pts), b.project(pts)).max() < 1e-6
    assert sampson_distances(fundamental_matrix(b, a), b.project(pts), a.project(pts)).max() < 1e-6


def test_sampson_error_is_small_for_true_poses_and_large_for_a_wrong_one(stereo):
    left, right, a, b, wrong = stereo
    for size in (128, SIZE):
        true_d, wrong_d = [], []
        for j in range(0, len(left), 6):
            fa, fb = square(left[j:j + 1], size)[0], square(right[j:j + 1], size)[0]
            pa, pb = orb_matches(fa, fb)
            true_d.append(sampson_distances(fundamental_matrix(a.square(size), b.square(size)), pa, pb))
            wrong_d.append(sampson_distances(fundamental_matrix(a.square(size), wrong.square(size)), pa, pb))
        true_d, wrong_d = np.concatenate(true_d), np.concatenate(wrong_d)
        assert len(true_d) > 50
        assert np.median(true_d) < 1.0 and np.median(wrong_d) > 4 * np.median(true_d), (size, true_d, wrong_d)
    one = sampson_error(square(left[:1], SIZE)[0], square(right[:1], SIZE)[0], a.square(SIZE), b.square(SIZE))
    assert one["matches"] > 10 and one["median_px"] < 1.5


# -- the table on hand-made frames ----------------------------------------------------------
def _square_frames(xs, size=32, side=4) -> tuple[np.ndarray, np.ndarray]:
    """A red square (side px) at column x, row 10, on grey: frames and exact coverage masks."""
    frames = np.full((len(xs), size, size, 3), 90, np.uint8)
    masks = np.zeros((len(xs), size, size), bool)
    for i, x in enumerate(xs):
        frames[i, 10:10 + side, x:x + side] = (220, 30, 30)
        masks[i, 10:10 + side, x:x + side] = True
    return frames, masks


def test_mask_iou_and_centroids_exact():
    a = np.zeros((6, 6), bool)
    b = np.zeros((6, 6), bool)
    a[1:3, 1:4] = True  # 6 px
    b[2:4, 2:5] = True  # 6 px, 2 shared
    assert physics.mask_iou(a, b) == pytest.approx(2 / 10)
    assert physics.mask_iou(a, a) == 1.0 and math.isnan(physics.mask_iou(a & False, b & False))
    assert physics.mask_iou(a, np.zeros_like(a)) == 0.0
    assert physics.centroids(np.stack([a, b, a & False]))[:2].tolist() == [[2.0, 1.5], [3.0, 2.5]]
    assert np.isnan(physics.centroids(a[None] & False)).all()


def test_colour_fit_leaves_out_frames_showing_a_sliver():
    """Frames where an occluder (grey) hides all but a 1 px sliver of the square do not count
    in a decoded-frame fit's IoU; by default they do, and a blurred sliver drags it down."""
    frames, masks = _square_frames([6, 6, 6, 6])
    frames[2:, 10:14, 7:10] = 90  # frames 2 and 3: only column 6 of the square shows
    masks[2:, 10:14, 7:10] = False
    frames[2:, 10:14, 6] = (110, 80, 80)  # and it is blurred into the grey, as a decoder leaves it
    kept = physics.fit_colour_model(frames, masks.astype(float), min_visible=physics.MIN_VISIBLE)
    every = physics.fit_colour_model(frames, masks.astype(float))
    assert kept.fit_iou == 1.0 and every.fit_iou < 0.6


def test_floor_is_copy_last_frame_exactly():
    """A square moving 1 px per frame: the floor (the last context frame held) is off by h px
    at horizon h, has copy-last-frame's PSNR, and the ceiling (the truth itself) is perfect."""
    context_x, xs = 5, [6, 7, 8, 9, 10, 11, 12, 13]
    true, masks = _square_frames(xs)
    last, _ = _square_frames([context_x])
    colour = physics.fit_colour_model(true, masks.astype(float))
    assert colour.threshold == physics.THRESHOLDS[0] and colour.fit_iou == 1.0
    camera = PinholeCamera.from_fovy(32, 32, 45.0, [0, 0, 1.0], np.eye(3))  # 1 m above the plane, looking down
    shifted, _ = _square_frames([x + 2 for x in xs])
    window = physics.Window(key="w", true=true, outputs={"model": shifted, "shuffled": shifted, "ceiling": true},
                            context_last=last[0], camera=camera, plane_z=0.0, moved=True,
                            true_colour=colour, decoded_colour=colour)
    rows = {(r["horizon"], r["method"]): r for r in physics.horizon_table([window])}
    copy_last = np.repeat(last, len(xs), axis=0)
    metres_per_px = 1.0 / camera.focal_px
    for h in range(1, len(xs) + 1):
        floor = rows[h, "floor"]
        assert floor["pos_err_px"] == pytest.approx(h)
        assert floor["pos_err_cm"] == pytest.approx(100 * h * metres_per_px)
        assert floor["psnr"] == pytest.approx(physics.psnr_frames(true[h - 1:h], copy_last[h - 1:h])[0])
        assert floor["ssim"] == pytest.approx(physics.ssim_frames(true[h - 1:h], copy_last[h - 1:h])[0])
        assert floor["iou"] == pytest.approx(max(0, 4 - h) / (4 + h))  # overlap of two 4 x 4 squares h apart
        assert rows[h, "model"]["pos_err_px"] == pytest.approx(2.0) and rows[h, "model"]["iou"] == pytest.approx(2 / 6)
        ceiling = rows[h, "ceiling"]
        assert ceiling["pos_err_px"] == 0.0 and ceiling["iou"] == 1.0 and ceiling["ssim"] == pytest.approx(1.0)
        assert ceiling["found"] == 1.0 and ceiling["tracked"] == 1 and ceiling["windows"] == 1
    assert physics.check_beats_floor(list(rows.values()))["passed"] is True  # 2 px < h px from h = 4 on
    assert physics.check_psnr_between(list(rows.values()))["passed"] is True
    assert physics.check_actions_matter(list(rows.values()))["passed"] is False  # shuffled == model here


def test_a_window_where_nothing_moved_counts_for_pixels_only():
    true, masks = _square_frames([6] * 4)
    colour = physics.fit_colour_model(true, masks.astype(float))
    window = physics.Window(key="still", true=true, outputs={"model": true, "shuffled": true, "ceiling": true},
                            context_last=true[0], moved=False, true_colour=colour, decoded_colour=colour)
    rows = physics.horizon_table([window])
    assert all(r["pos_err_px"] is None and r["tracked"] == 0 and r["windows"] == 1 for r in rows)
    assert all(r["psnr"] > 100 for r in rows)


def test_shuffled_actions_come_from_other_windows():
    actions = np.arange(5 * 6 * 2, dtype=np.float32).reshape(5, 6, 2)
    out = physics.shuffle_actions(actions, 3, seed=1)
    assert np.array_equal(out[:, :3], actions[:, :3])  # context rows stay
    for i in range(5):
        donors = [j for j in range(5) if np.array_equal(out[i, 3:], actions[j, 3:])]
        assert donors and donors[0] != i
    single = physics.shuffle_actions(actions[:1], 2)
    assert np.array_equal(single[0, 2:], actions[0, 2:][::-1])


# -- windows and decoding, with an oracle for a world model ----------------------------------
class Oracle:
    """Stands in for WorldModel.rollout: returns each window's true future codes, in the order
    `heldout.predict` asks for them, and keeps the action rows it was given."""

    def __init__(self, futures: list[np.ndarray], action_dim: int = 8):
        self.futures, self.calls, self.i = futures, [], 0
        self.config = type("Config", (), {"action_dim": action_dim, "action_conditioned": True})()

    def eval(self):
        return self

    def rollout(self, context, n, text=None, actions=None):
        import torch

        self.calls.append((context.shape, n, len(text), actions.numpy().copy()))
        out = np.stack([self.futures[(self.i + k) % len(self.futures)] for k in range(context.shape[0])])
        self.i += context.shape[0]
        return torch.from_numpy(out)


def test_predict_windows_line_up_with_the_episode(push, truths):
    import torch

    from models.tokenizer import VideoTokenizer, preset
    from tasks.world import heldout

    torch.manual_seed(0)
    tokenizer = VideoTokenizer(preset("tiny-dv4x8x8")).eval()
    camera = PinholeCamera.from_manifest(push.cameras[0])
    episodes = [heldout.prepare(f"seed{s}", truths[s], camera, tokenizer, SIZE, 8, "push") for s in SEEDS[:2]]
    context, horizon, stride = 3, 2, 5
    spans = [(e, s) for e in episodes for s in heldout.window_starts(e.codes.shape[0], context, horizon, stride)]
    oracle = Oracle([e.codes[s + context:s + context + horizon] for e, s in spans])
    windows = heldout.predict(oracle, tokenizer, episodes, context, horizon, stride, batch=3)
    assert len(windows) == len(spans) == 8  # 23 latent frames: starts 0, 5, 10, 15 in each episode
    for w, (e, s) in zip(windows, spans):
        last = 4 * (s + context - 1)
        assert w.info["last_context_frame"] == last and np.array_equal(w.true, e.frames[last + 1:last + 9])
        assert np.array_equal(w.context_last, e.recon[last])
        assert np.array_equal(w.outputs["ceiling"], e.recon[last + 1:last + 9])
        # Perfect codes decode (after the true history) to the reconstruction: the model output is the ceiling.
        assert np.abs(w.outputs["model"].astype(int) - w.outputs["ceiling"]).max() <= 1
        moved = np.linalg.norm(e.package_xyz[last + 1:last + 9, :2] - e.package_xyz[last, :2], axis=1).max()
        assert w.moved == bool(moved >= 0.02)
    true_rows = np.concatenate([c[3] for c in oracle.calls[:3]])
    shuffled_rows = np.concatenate([c[3] for c in oracle.calls[3:]])
    assert true_rows.shape == (8, context - 1 + horizon, 32)
    for rows, (e, s) in zip(true_rows, spans):
        assert np.array_equal(rows, e.actions[s:s + context - 1 + horizon])
    assert np.array_equal(shuffled_rows[:, :context - 1], true_rows[:, :context - 1])  # the context's own actions
    assert not any(np.array_equal(a, b) for a, b in zip(shuffled_rows[:, context - 1:], true_rows[:, context - 1:]))
    assert any(w.moved for w in windows) and not all(w.moved for w in windows)


def test_push_closeup_keeps_the_package_in_view_and_moving(truths):
    """The manifest the physics alignment is measured on: from the side opposite the arm the
    package is never hidden (its mask keeps most of its area on every frame), and it crosses a
    good part of the frame while pushed, a few pixels per frame (so copy-last-frame is a real
    floor at 4 frames); on conveyor_push's overhead camera the arm covers it while it pushes."""
    closeup = load(MANIFESTS / "push_closeup.yaml")
    truth = render_truth(closeup, 10000, "side")
    area = truth.masks.reshape(len(truth.masks), -1).sum(1)
    assert area.min() >= 0.6 * area.max() > 0
    x = physics.centroids(truth.masks)[:, 0]
    steps = np.abs(np.diff(x))
    assert x.max() - x.min() > 25  # px of 64
    assert np.sort(steps)[-8:].min() > 1.5  # the push: at least 8 frames moving > 1.5 px each

    overhead = truths[10000]  # conveyor_push's overhead camera, the same held-out seed
    covered = overhead.masks.reshape(len(overhead.masks), -1).sum(1)
    assert covered.min() < 0.5 * covered[0]

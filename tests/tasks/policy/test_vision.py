"""The vision policy: what it observes (cameras and proprioception, never object state),
demonstrations and DAgger labels from the scripted expert, training, checkpoints, refusals."""

import numpy as np
import pytest
import torch

import mujoco
from tasks.manifests import load
from tasks.policy.bc import TrainConfig
from tasks.policy.specs import PolicySpecError, load_policy
from tasks.policy.vision import VisionPolicy, collect
from tasks.policy.vision_obs import ObservationSpec, Observer, parse_cameras, proprio
from tasks.policy.vision_train import dagger, load_checkpoint, random_shift, save_checkpoint, train_vision
from tasks.sim.control import ArmController
from tasks.sim.scene import build_scene

from tests.support import MANIFESTS

PUSH = load(MANIFESTS / "push_closeup.yaml").model_copy(update={"horizon_s": 1.0})
SPEC = ObservationSpec(cameras=("side",), image_size=32)


def _moved_package(scene, shift):
    data = mujoco.MjData(scene.model)
    data.qpos[:] = scene.initial_qpos
    body = scene.model.body(scene.objects[0])
    qadr = scene.model.jnt_qposadr[scene.model.body_jntadr[body.id]]
    data.qpos[qadr: qadr + 2] += shift
    mujoco.mj_forward(scene.model, data)
    return data


def test_proprioception_ignores_the_package_and_the_camera_sees_it():
    scene = build_scene(PUSH, 3)
    arm = ArmController(scene, 3, noise=0.0)
    here, there = _moved_package(scene, [0.0, 0.0]), _moved_package(scene, [0.06, -0.04])
    arm.reset(here)
    assert np.array_equal(proprio(here, arm), proprio(there, arm))
    observer = Observer(scene, SPEC)
    try:
        a = observer.frames(here)
        observer.next_frame = [0]  # a new frame is due
        b = observer.frames(there)
    finally:
        observer.close()
    assert a.shape == (1, 3, 32, 32) and a.dtype == np.uint8
    assert np.abs(a.astype(int) - b.astype(int)).sum() > 0


def test_a_camera_frame_is_held_until_the_next_is_due():
    scene = build_scene(PUSH, 3)
    data = _moved_package(scene, [0.0, 0.0])
    observer = Observer(scene, SPEC)
    try:
        first = observer.frames(data)
        data.qpos[:] += 0.01
        mujoco.mj_forward(scene.model, data)
        data.time = 0.05  # side films at 10 fps: the next frame is due at 0.1 s
        assert np.array_equal(observer.frames(data), first)
        data.time = 0.1
        assert not np.array_equal(observer.frames(data), first)
    finally:
        observer.close()


def test_observation_specs_are_checked_against_the_manifest():
    assert ObservationSpec(cameras=("wrist",)).mismatch(PUSH).startswith("the policy observes camera(s) wrist")
    assert "64x64" in ObservationSpec(cameras=("side",), image_size=96).mismatch(PUSH)
    assert SPEC.mismatch(PUSH) is None
    assert parse_cameras("front_left, wrist") == ("front_left", "wrist")
    for bad in ("", "a,,b", "a,a"):
        with pytest.raises(ValueError, match="distinct cameras"):
            parse_cameras(bad)


@pytest.fixture(scope="module")
def demos():
    return collect(PUSH, [1, 2], SPEC, successes_only=False)


def test_demonstrations_record_what_the_expert_saw_and_commanded(demos):
    steps = round(PUSH.horizon_s * 50)
    assert demos.frames.shape == (2 * steps, 1, 3, 32, 32) and demos.proprio.shape[0] == 2 * steps
    assert demos.act.shape == (2 * steps, 5) and set(demos.round) == {0}
    assert np.all(np.linalg.norm(demos.act[:, :3], axis=1) < 0.05)  # moves, not positions


def test_demonstrations_see_the_camera_at_the_manifests_fps(demos):
    """Collection renders the observed camera at its own fps (side: 10 fps, a new frame every 5
    of the 50 Hz steps), as evaluation does; not slowed to save render time."""
    steps, every = round(PUSH.horizon_s * 50), round(50 / PUSH.cameras[0].fps)
    for k in range(2):
        frames = demos.frames[demos.episode == k]
        changed = [i for i in range(1, steps) if not np.array_equal(frames[i], frames[i - 1])]
        assert set(changed) <= set(range(every, steps, every))  # held between frame times
        assert len(changed) >= steps // every // 2  # and new at most (measured: 8 of 9 on seed 1); 1 fps: none


def test_training_fits_and_a_checkpoint_acts_the_same_after_loading(demos, tmp_path):
    config = TrainConfig(steps=60, batch_size=32, lr=3e-3)
    model, history = train_vision(demos, SPEC, config)
    assert history[-1]["smoothed_loss"] < history[0]["loss"]
    again, _ = train_vision(demos, SPEC, config)
    assert all(torch.equal(a, b) for a, b in zip(model.state_dict().values(), again.state_dict().values()))
    save_checkpoint(model, SPEC, tmp_path / "ck", PUSH, config, {"checkpoint_id": "c" * 64})
    loaded, spec, meta = load_checkpoint(tmp_path / "ck")
    assert spec == SPEC and meta["observe"]["cameras"] == ["side"]
    x, p = torch.from_numpy(demos.frames[:4]), torch.from_numpy(demos.proprio[:4])
    with torch.inference_mode():
        assert torch.allclose(model(x, p), loaded(x, p))
    policy = load_policy(f"vision:{tmp_path / 'ck'}")
    assert isinstance(policy, VisionPolicy) and policy.name == "vision:" + "c" * 12
    with pytest.raises(PolicySpecError, match="not a vision-policy checkpoint"):
        load_policy(f"vision:{tmp_path}")



def test_random_shift_moves_each_picture_whole_and_repeats_its_edges():
    frames = torch.randint(0, 256, (6, 2, 3, 8, 8), dtype=torch.uint8)
    moved = random_shift(frames, 2, torch.Generator().manual_seed(3))
    assert moved.shape == frames.shape and moved.dtype == torch.uint8
    assert torch.equal(moved, random_shift(frames, 2, torch.Generator().manual_seed(3)))
    found = set()
    for i in range(6):
        for c in range(2):  # each (sample, camera) is its picture moved by one (dy, dx), all channels alike
            fits = [(dy, dx) for dy in range(-2, 3) for dx in range(-2, 3)
                    if torch.equal(moved[i, c], frames[i, c][:, (torch.arange(8) + dy).clamp(0, 7)]
                                   [:, :, (torch.arange(8) + dx).clamp(0, 7)])]
            assert fits, (i, c)
            found.add(fits[0])
    assert len(found) > 3  # drawn, not one move for all


def test_shift_augmentation_trains_other_weights_and_is_seeded(demos):
    plain = TrainConfig(steps=20, batch_size=32, lr=3e-3)
    shifted = plain.model_copy(update={"shift": 3})
    a, history = train_vision(demos, SPEC, shifted)
    b, _ = train_vision(demos, SPEC, shifted)
    c, _ = train_vision(demos, SPEC, plain)
    assert all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values()))
    assert not all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), c.state_dict().values()))
    other = plain.model_copy(update={"seed": plain.seed + 1})
    d, _ = train_vision(demos, SPEC, other)  # another seed: other initial weights and minibatches
    assert not all(torch.equal(x, y) for x, y in zip(c.state_dict().values(), d.state_dict().values()))
    few = {"steps": 4}  # from the same weights, other minibatches
    e, _ = train_vision(demos, SPEC, plain.model_copy(update=few), start=c)
    f, _ = train_vision(demos, SPEC, other.model_copy(update=few), start=c)
    assert not all(torch.equal(x, y) for x, y in zip(e.state_dict().values(), f.state_dict().values()))
    assert np.isfinite(history[-1]["loss"])
    with pytest.raises(ValueError, match="shift augmentation needs the policy's own convolutions"):
        train_vision(demos, SPEC, shifted, tokenizer=_tokenizer())

def test_dagger_labels_the_learners_own_states_with_the_experts_moves(demos):
    model, _ = train_vision(demos, SPEC, TrainConfig(steps=5, batch_size=16))
    grown, aggregate, history = dagger(PUSH, SPEC, demos, model, [[7]], TrainConfig(steps=4, batch_size=16),
                                       offset=5, gate=None)
    added = aggregate.round == 1
    assert added.sum() == round(PUSH.horizon_s * 50) and len(aggregate.act) == len(demos.act) + added.sum()
    assert aggregate.seeds == (1, 2, 7) and set(aggregate.episode[added]) == {2}
    assert [row["round"] for row in history] and history[0]["step"] == 6
    # A barely trained learner does not follow the expert: its states are its own, not a demonstration's.
    assert not np.allclose(aggregate.proprio[added][-1], demos.proprio[len(demos.act) // 2 - 1])
    assert np.all(np.isfinite(aggregate.act[added]))


def test_gated_dagger_keeps_only_the_steps_where_the_expert_took_over(demos, monkeypatch):
    """HG-DAgger: the expert acts, and labels, only where the learner's move is off its own by
    more than the gate (in the demonstrations' spreads) or sets the grip otherwise."""
    import tasks.policy.vision as vision

    model, _ = train_vision(demos, SPEC, TrainConfig(steps=5, batch_size=16))
    learner, steps = VisionPolicy(model, SPEC), round(PUSH.horizon_s * 50)
    counts = {}
    monkeypatch.setattr(vision, "RESYNC", False)  # the expert keeps its own phases, as when it demonstrates
    every = collect(PUSH, [7], SPEC, learner=learner, round_=1, gate=0.0, counts=counts)
    monkeypatch.undo()
    assert counts == {"steps": steps, "interventions": steps} and len(every.act) == steps
    # With the expert's every move made, the episode is the noiseless expert's own from that seed.
    noiseless = PUSH.model_copy(update={"task": PUSH.task.model_copy(update={"controller_noise": 0.0})})
    expert = collect(noiseless, [7], SPEC, successes_only=False)
    assert np.allclose(every.act, expert.act, atol=1e-6) and np.allclose(every.proprio, expert.proprio, atol=1e-5)
    counts = {}
    none = collect(PUSH, [7], SPEC, learner=learner, round_=1, gate=1e9, counts=counts)
    # Only a grip set otherwise than the expert's could be taken over; a push holds it closed.
    assert counts == {"steps": steps, "interventions": 0} and len(none.act) == 0
    same, _, history = dagger(PUSH, SPEC, demos, model, [[7]], TrainConfig(steps=4, batch_size=16), gate=1e9,
                              loss=0.25)  # a round the expert never took over trains nothing
    assert same is model and history == [{"step": 4, "loss": 0.25, "round": 1, "learner_success": 0.0,
                                          "interventions": 0.0}]


def test_an_explicit_cpu_device_trains_the_very_same_weights(demos):
    config = TrainConfig(steps=8, batch_size=16)
    plain, _ = train_vision(demos, SPEC, config)
    on_cpu, _ = train_vision(demos, SPEC, config, device="cpu")
    assert all(torch.equal(a, b) for a, b in zip(plain.state_dict().values(), on_cpu.state_dict().values()))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU on this machine (CI never has one)")
def test_a_vision_policy_trained_on_the_gpu_acts_the_same_on_the_cpu(demos, tmp_path):
    config = TrainConfig(steps=20, batch_size=16)
    model, history = train_vision(demos, SPEC, config, device="cuda")
    assert next(model.parameters()).device.type == "cuda" and np.isfinite(history[-1]["loss"])
    save_checkpoint(model, SPEC, tmp_path / "ck", PUSH, config, {"checkpoint_id": "d" * 64})
    loaded, _, _ = load_checkpoint(tmp_path / "ck")
    x, p = torch.from_numpy(demos.frames[:4]), torch.from_numpy(demos.proprio[:4])
    with torch.inference_mode():
        assert torch.allclose(model(x.cuda(), p.cuda()).cpu(), loaded(x, p), atol=1e-4)
    # The learner drives the simulator from the GPU too (a DAgger round).
    _, aggregate, _ = dagger(PUSH, SPEC, demos, model, [[7]], TrainConfig(steps=2, batch_size=16), device="cuda")
    assert (aggregate.round == 1).sum() == round(PUSH.horizon_s * 50)


def _tokenizer(seed: int = 0):
    from models.tokenizer import VideoTokenizer, preset

    torch.manual_seed(seed)
    return VideoTokenizer(preset("tiny-dv4x8x8")).eval()


@pytest.mark.parametrize("layer", ["latent", "hidden"])
def test_a_policy_sees_through_a_frozen_tokenizer_encoder(demos, tmp_path, layer):
    """Issue 28's second encoder: the tokenizer's, frozen. Training moves only the head; the
    checkpoint carries the encoder's weights, so it acts the same loaded; DAgger keeps it."""
    tokenizer = _tokenizer()
    config = TrainConfig(steps=40, batch_size=32, lr=3e-3)
    model, history = train_vision(demos, SPEC, config, tokenizer=tokenizer, layer=layer)
    assert model.config.encoder == "tokenizer" and model.config.tokenizer_layer == layer
    assert history[-1]["smoothed_loss"] < history[0]["loss"]
    for enc in model.encoders:
        assert all(torch.equal(a, b) for a, b in zip(enc.encoder.state_dict().values(),
                                                     tokenizer.encoder.state_dict().values()))
    # The cached encoder output (float16) gives what the frames give, within its rounding.
    x, p = torch.from_numpy(demos.frames[:8]), torch.from_numpy(demos.proprio[:8])
    with torch.inference_mode():
        direct = model.forward_normalised(x, p)
        cached = model.forward_normalised(x, p, model.frozen(x).half())
    assert torch.allclose(direct, cached, atol=2e-2)
    save_checkpoint(model, SPEC, tmp_path / "ck", PUSH, config, {"checkpoint_id": "e" * 64})
    loaded, _, _ = load_checkpoint(tmp_path / "ck")
    assert loaded.config.tokenizer == tokenizer.config
    with torch.inference_mode():
        assert torch.allclose(model(x, p), loaded(x, p))
    # Acting, a frame held between camera frames is encoded once; the moves are the network's.
    assert not np.array_equal(demos.frames[0], demos.frames[7])
    learner = VisionPolicy(model, SPEC).controller(build_scene(PUSH, 3), 3)
    try:
        for i in (0, 0, 7, 7, 0):
            with torch.inference_mode():
                want = model(x[i:i + 1], p[i:i + 1])[0].numpy()
            assert np.allclose(learner.act(demos.frames[i], demos.proprio[i]), want, atol=1e-5)
    finally:
        learner.close()
    grown, _, _ = dagger(PUSH, SPEC, demos, model, [[7]], TrainConfig(steps=3, batch_size=16))
    assert grown.config == model.config
    assert torch.equal(grown.encoders[0].encoder.conv_in.conv.weight, tokenizer.encoder.conv_in.conv.weight)


def test_a_tokenizer_encoder_must_fit_the_frames():
    from models.vision_policy import VisionPolicyNet, preset

    with pytest.raises(ValueError, match="not a multiple of the tokenizer's spatial compression 8"):
        preset("tiny", 1, 36, 20, _tokenizer().config)
    net = VisionPolicyNet(preset("tiny", 1, 32, 20, _tokenizer().config))
    with pytest.raises(ValueError, match="not the one this policy was built for"):
        net.load_tokenizer(type(_tokenizer())(_tokenizer().config.model_copy(update={"name": "other"})))

"""Policies through the simulator's controller seam: the scripted one bit for bit, and behaviour cloning."""

import numpy as np
import pytest
import torch

from schemas.panel import contract_hash
from tasks.manifests import load
from tasks.policy.base import ScriptedPolicy
from tasks.policy.bc import (BCController, BCPolicy, TrainConfig, collect, load_checkpoint,
                             save_checkpoint, success_rate, train_bc)
from tasks.policy.features import arm_features
from tasks.policy.specs import PolicySpecError, load_policy
from tasks.sim.episode import rollout
from tasks.sim.scene import build_scene

from tests.support import MANIFESTS

PUSH = load(MANIFESTS / "conveyor_push.yaml")
# Demonstrations and held-out seeds for the learning test (figures measured with these, below).
TRAIN_SEEDS, HELD_OUT = range(11, 21), (1000, 1001, 1002)


def _small(manifest, **update):
    cams = tuple(c.model_copy(update={"resolution": (24, 24), "fps": 4}) for c in manifest.cameras)
    return manifest.model_copy(update={"cameras": cams, **update})


def _same(a, b) -> None:
    for name in ("time", "joint_pos", "joint_vel", "action", "object_pose", "success_flag", "estop"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert all(np.array_equal(a.frames[c], b.frames[c]) for c in a.frames)
    assert (a.success, a.reason) == (b.success, b.reason)


@pytest.mark.parametrize("name", ["conveyor_push", "mobile_rig_aisle"])
def test_scripted_policy_through_the_seam_reproduces_rollout(name):
    manifest = _small(load(MANIFESTS / f"{name}.yaml"), horizon_s=2.0)
    _same(rollout(manifest, 5), rollout(manifest, 5, controller=ScriptedPolicy().controller))
    noise = manifest.task.controller_noise
    _same(rollout(manifest, 5), rollout(manifest, 5, controller=ScriptedPolicy(noise).controller))


def test_scripted_noise_is_the_policys_not_the_manifests():
    manifest = _small(PUSH, horizon_s=1.0)
    noisy = manifest.model_copy(update={"task": manifest.task.model_copy(update={"controller_noise": 0.6})})
    _same(rollout(noisy, 3), rollout(manifest, 3, controller=ScriptedPolicy(0.6).controller))
    assert not np.array_equal(rollout(manifest, 3).action, rollout(noisy, 3).action)


def test_policy_names_parse():
    assert load_policy("scripted").name == "scripted" and load_policy("scripted:0.8").name == "scripted@0.8"
    for bad, why in (("scripted:2", "noise must be in"), ("bc", "name a checkpoint"), ("bc:/nowhere", "not a behaviour"),
                     ("random", "unknown kind")):
        with pytest.raises(PolicySpecError, match=why):
            load_policy(bad)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    demos = collect(PUSH, TRAIN_SEEDS)
    model, history = train_bc(demos, TrainConfig(steps=1500, seed=0))
    folder = tmp_path_factory.mktemp("bc")
    save_checkpoint(model, folder, PUSH, TrainConfig(steps=1500), {"checkpoint_id": "c" * 24})
    return demos, model, history, folder


def test_demonstrations_are_what_the_scripted_controller_saw_and_did(trained):
    demos = trained[0]
    assert demos.successes == (True,) * len(TRAIN_SEEDS)
    assert demos.obs.shape[0] == demos.act.shape[0] == 250 * len(TRAIN_SEEDS)
    # At most MAX_STEP (12 mm) plus the manifest's small noise; push keeps the fingers closed.
    assert np.linalg.norm(demos.act[:, :3], axis=1).max() < 0.013 and set(np.unique(demos.act[:, 4])) == {1.0}
    # The first observation of an episode is the features of the scene as built.
    scene = build_scene(PUSH, TRAIN_SEEDS[0])
    ctrl = BCController(trained[1], scene, TRAIN_SEEDS[0])
    from tasks.sim.episode import Simulation

    sim = Simulation(scene, TRAIN_SEEDS[0])
    ctrl.reset(sim.data)
    assert np.allclose(arm_features(sim.data, ctrl.arm), demos.obs[0], atol=1e-6)


def test_bc_learns_and_succeeds_on_held_out_seeds(trained):
    _, model, history, folder = trained
    assert history[-1]["smoothed_loss"] < 0.2 * history[0]["loss"]
    policy = BCPolicy.from_checkpoint(folder)
    assert policy.contract is not None and policy.meta["contract_hash"] == contract_hash(PUSH)
    rate, outcomes = success_rate(PUSH, policy, HELD_OUT)
    # Measured: 2 of 3 with these 10 demonstrations and 1500 steps (30 and 3000: 10 of 10).
    assert rate > 0, outcomes


def test_checkpoint_round_trip_and_numpy_forward_match_torch(trained):
    _, model, _, folder = trained
    loaded, meta = load_checkpoint(folder)
    assert meta["checkpoint_id"] == "c" * 24 and meta["bc"]["obs_size"] == model.config.obs_size
    obs = torch.randn(7, model.config.obs_size)
    with torch.no_grad():
        assert torch.equal(loaded(obs), model(obs))
        want = model(obs).double().numpy()
    ctrl = BCController(loaded, build_scene(PUSH, 1), 1)
    got = np.stack([ctrl.act(o) for o in obs.numpy()])
    assert np.allclose(got, want, atol=1e-5)


def test_training_is_seeded(trained):
    demos = trained[0]
    small = type(demos)(demos.obs[:300], demos.act[:300], demos.episode[:300], demos.seeds, demos.successes)
    a, _ = train_bc(small, TrainConfig(steps=20, seed=3))
    b, _ = train_bc(small, TrainConfig(steps=20, seed=3))
    c, _ = train_bc(small, TrainConfig(steps=20, seed=4))
    assert all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values()))
    assert not torch.equal(a.net[0].weight, c.net[0].weight)


def test_bc_refuses_a_base():
    with pytest.raises(ValueError, match="drives arms"):
        collect(load(MANIFESTS / "mobile_rig_aisle.yaml"), [0])

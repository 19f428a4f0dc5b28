"""The world-model plug point with an untrained tiny tokenizer and world model: shapes, sizes,
actions reaching the model, and clear errors. (Skill is the physics evaluation's business.)"""

import numpy as np
import pytest
import torch

from models.tokenizer import VideoTokenizer
from models.tokenizer import preset as tokenizer_preset
from models.world_model import WorldModel, preset
from tasks.panels.world import WorldModelRequest, WorldModelUnavailable, world_model_rollout
from tasks.tokenize.tokens import save_checkpoint as save_tokenizer
from tasks.world.checkpoints import save_checkpoint

SIZE = 32


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    torch.manual_seed(0)
    root = tmp_path_factory.mktemp("wm")
    tokenizer = VideoTokenizer(tokenizer_preset("tiny-dv4x8x8"))
    save_tokenizer(tokenizer, root / "tok")
    c = tokenizer.config
    model = WorldModel(preset("tiny-wm", codebook_size=c.codebook_size, temporal_compression=c.temporal_compression,
                              max_height=SIZE // 8, max_width=SIZE // 8)).add_action_conditioning()
    with torch.no_grad():  # wake the zero-initialised action encoder so actions change the output
        torch.nn.init.normal_(model.action_encoder.net[2].weight, std=0.5)
        model.copy_gain.zero_()  # untrained, the copy path would make every rollout repeat its context
    save_checkpoint(model, root / "wm", {"tokenizer": "tok", "size": SIZE})
    return root


def _request(frames=13, actions=None, height=48, width=64):
    rng = np.random.default_rng(0)
    context = rng.integers(0, 255, (1, height, width, 3), dtype=np.uint8)
    actions = rng.normal(0, 0.01, (40, 5)) if actions is None else actions
    return WorldModelRequest(camera="overhead", context=context, actions=actions, control_hz=50, fps=30,
                             frames=frames, text="push the package")


def test_rollout_has_the_cameras_size_and_length(checkpoint):
    out = world_model_rollout(checkpoint / "wm", _request(), root=checkpoint)
    assert out.shape == (13, 48, 64, 3) and out.dtype == np.uint8
    # The square the model saw is the centre 48 x 48; what lies outside it stays black.
    assert not out[:, :, :8].any() and not out[:, :, 56:].any() and out[:, :, 8:56].any()
    again = world_model_rollout(checkpoint / "wm", _request(), root=checkpoint)
    assert np.array_equal(out, again)  # greedy decoding: the same request, the same frames


def test_actions_reach_the_model(checkpoint):
    still = world_model_rollout(checkpoint / "wm", _request(actions=np.zeros((40, 5))), root=checkpoint)
    moved = world_model_rollout(checkpoint / "wm", _request(actions=np.full((40, 5), 0.5)), root=checkpoint)
    assert np.array_equal(still[0], moved[0]) and not np.array_equal(still[1:], moved[1:])


def test_rollout_aligns_actions_with_the_checkpoints_totals(checkpoint, tmp_path, monkeypatch):
    """A model post-trained with action totals gets them in its rollout rows too."""
    from tasks.world.checkpoints import load_checkpoint
    from tasks.world.data import align_actions

    model = load_checkpoint(checkpoint / "wm")
    model.config = model.config.model_copy(update={"action_totals": 3})
    save_checkpoint(model, tmp_path / "wm", {"tokenizer": str(checkpoint / "tok"), "size": SIZE})
    seen = []
    real = WorldModel.rollout
    monkeypatch.setattr(WorldModel, "rollout",
                        lambda self, *a, **kw: seen.append(kw["actions"]) or real(self, *a, **kw))
    request = _request()
    world_model_rollout(tmp_path / "wm", request, root=checkpoint)
    frame_time = np.arange(1 + 4 * 3) / request.fps
    want = align_actions(np.arange(40) / 50, request.actions, frame_time, 4, 4, 8, totals=3)
    assert np.array_equal(seen[0][0].numpy(), want) and want[..., 5::8].any()


def test_not_a_world_model_checkpoint(tmp_path):
    with pytest.raises(WorldModelUnavailable, match="not a world-model checkpoint"):
        world_model_rollout(tmp_path, _request())


def test_sampled_rollouts_differ_by_seed_and_repeat_with_it(checkpoint):
    a, b = (world_model_rollout(checkpoint / "wm", _request(), root=checkpoint, temperature=1.0, seed=s) for s in (0, 1))
    again = world_model_rollout(checkpoint / "wm", _request(), root=checkpoint, temperature=1.0, seed=0)
    assert np.array_equal(a, again) and not np.array_equal(a[1:], b[1:])


def test_the_device_changes_where_it_computes_not_what(checkpoint, monkeypatch):
    cpu = world_model_rollout(checkpoint / "wm", _request(), root=checkpoint, device="cpu")
    monkeypatch.setenv("WORLDLINE_DEVICE", "cpu")  # what a rollout without a device uses
    assert np.array_equal(cpu, world_model_rollout(checkpoint / "wm", _request(), root=checkpoint))
    if torch.cuda.is_available():
        # On the GPU: the same shapes, and frame 0 (the tokenizer's reconstruction of the context)
        # within float rounding. Later frames are argmax picks of an untrained model, which
        # rounding may flip, so they are not compared.
        gpu = world_model_rollout(checkpoint / "wm", _request(), root=checkpoint, device="cuda")
        assert gpu.shape == cpu.shape and np.abs(gpu[0].astype(int) - cpu[0].astype(int)).max() <= 2


# -- the diffusion world model behind the same seam -------------------------------------------------
@pytest.fixture(scope="module")
def diffusion_checkpoint(tmp_path_factory):
    """An untrained tiny continuous tokenizer and action-conditioned diffusion world model, saved
    as flows/train.py saves them (config key diffusion_world_model), and a discrete tokenizer."""
    from models.diffusion_world import DiffusionWorldModel
    from models.diffusion_world import preset as diffusion_preset
    from tasks.world.diffusion import save_checkpoint as save_diffusion

    torch.manual_seed(0)
    root = tmp_path_factory.mktemp("dwm")
    tokenizer = VideoTokenizer(tokenizer_preset("tiny-cv4x8x8"))
    save_tokenizer(tokenizer, root / "tok")
    save_tokenizer(VideoTokenizer(tokenizer_preset("tiny-dv4x8x8")), root / "discrete")
    c = tokenizer.config
    model = DiffusionWorldModel(diffusion_preset("tiny-dwm", latent_channels=c.latent_channels, max_frames=4,
                                                 temporal_compression=c.temporal_compression,
                                                 max_height=SIZE // 8, max_width=SIZE // 8)).add_action_conditioning()
    with torch.no_grad():  # wake the zero-initialised action encoder and the AdaLN-Zero head
        for p in [*model.action_encoder.parameters(), *model.final_ada.parameters(), *model.head.parameters()]:
            torch.nn.init.normal_(p, std=0.5)
    save_diffusion(model, root / "wm", {"tokenizer": "tok", "size": SIZE, "phase": "posttrain"})
    save_diffusion(model, root / "wrong", {"tokenizer": "discrete", "size": SIZE, "phase": "posttrain"})
    return root


def test_a_diffusion_checkpoint_rolls_out_through_the_same_seam(diffusion_checkpoint, monkeypatch):
    from models.diffusion_world import DiffusionWorldModel
    from tasks.panels import world

    root = diffusion_checkpoint
    out = world_model_rollout(root / "wm", _request(), root=root)
    assert out.shape == (13, 48, 64, 3) and out.dtype == np.uint8  # 1 + 3 latent frames of 4, as the AR model's
    assert not out[:, :, :8].any() and out[:, :, 8:56].any()
    assert np.array_equal(out, world_model_rollout(root / "wm", _request(), root=root))  # seed 0 both times
    other = world_model_rollout(root / "wm", _request(), root=root, seed=1)
    assert np.array_equal(out[0], other[0]) and not np.array_equal(out[1:], other[1:])  # the noise, from the seed
    moved = world_model_rollout(root / "wm", _request(actions=np.full((40, 5), 0.5)), root=root)
    assert not np.array_equal(out[1:], moved[1:])  # the actions reach it

    seen = []
    real = DiffusionWorldModel.rollout
    monkeypatch.setattr(DiffusionWorldModel, "rollout", lambda self, *a, **kw: seen.append(kw) or real(self, *a, **kw))
    world_model_rollout(root / "wm", _request(), root=root)
    world_model_rollout(root / "wm", _request(), root=root, sampler_steps=2)
    assert [kw["steps"] for kw in seen] == [world.SAMPLER_STEPS, 2] and world.SAMPLER_STEPS == 8
    assert seen[0]["actions"].shape == (1, 3, 32) and seen[0]["text"] == ["push the package"]


def test_a_diffusion_checkpoint_with_a_discrete_tokenizer_is_named(diffusion_checkpoint):
    with pytest.raises(WorldModelUnavailable, match="its tokenizer is discrete; a diffusion world model reads a "
                                                    "continuous"):
        world_model_rollout(diffusion_checkpoint / "wrong", _request(), root=diffusion_checkpoint)


def test_closed_loop_refuses_a_diffusion_world_model_in_one_line(diffusion_checkpoint):
    from tasks.panels.closed_loop import ClosedLoopRequest, closed_loop

    request = ClosedLoopRequest(camera="overhead", context=_request().context, control_hz=50, fps=30, frames=5)
    with pytest.raises(WorldModelUnavailable, match="a diffusion world model; closed loop drives autoregressive"):
        closed_loop(diffusion_checkpoint / "wm", request, lambda frame, t: np.zeros(5), diffusion_checkpoint)

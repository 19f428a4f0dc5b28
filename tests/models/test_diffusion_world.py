"""The diffusion world model: shapes, AdaLN-Zero at init, context flags, the zero-initialised
action encoder, text conditioning, the Euler sampler (context untouched, seeded, any step count)
and rollouts that slide past the window."""

import pytest
import torch

from models.diffusion_world import (
    PRESETS, DiffusionWorldConfig, DiffusionWorldModel, context_flags, post_trainable, preset,
)

torch.set_num_threads(1)
C = 4  # few latent channels keep these tests fast; the flow uses the tokenizer's


def _model(name="tiny-dwm", seed=0, **overrides) -> DiffusionWorldModel:
    torch.manual_seed(seed)
    overrides = {"latent_channels": C, "max_height": 4, "max_width": 4, "max_frames": 4, **overrides}
    return DiffusionWorldModel(preset(name, **overrides)).eval()


def _awake(model, seed=1):
    """Give the zero-initialised layers (AdaLN gates, head, action encoder) weights, as training would."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            if not p.any():
                p.copy_(torch.randn(p.shape, generator=gen) * 0.1)
    return model


def _latents(b=2, t=4, seed=0):
    return torch.randn(b, C, t, 4, 4, generator=torch.Generator().manual_seed(seed)).clamp(-1, 1)


def _actions(model, b=2, rows=3, seed=2):
    return torch.randn(b, rows, model.config.action_features, generator=torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_shapes_parameter_counts_and_adaln_zero(name):
    model = _model(name)
    x = _latents()
    with torch.no_grad():
        v = model(x, 0.5, 1, ["push the package", "pick it"])
    assert v.shape == x.shape and v.dtype == torch.float32
    assert not v.any()  # AdaLN-Zero: a fresh model predicts zero velocity
    assert 1e5 < sum(p.numel() for p in DiffusionWorldModel(PRESETS[name]).parameters()) < 2e6  # a CPU model
    with torch.no_grad():
        v = _awake(model)(x, torch.tensor([0.2, 0.9]), 1, None)
    assert v.shape == x.shape and v.abs().mean() > 0


def test_refuses_what_does_not_fit():
    model = _model()
    with pytest.raises(ValueError, match="exceed"):
        model(_latents(t=5), 0.5, 1)
    with pytest.raises(ValueError, match="multiple of the patch"):
        model(torch.zeros(1, C, 2, 3, 4), 0.5, 1)
    with pytest.raises(ValueError, match="without action conditioning"):
        model(_latents(), 0.5, 1, actions=torch.zeros(2, 3, model.config.action_features))
    with pytest.raises(ValueError, match="context flags"):
        model(_latents(), 0.5, torch.ones(2, 3, dtype=torch.bool))
    with pytest.raises(ValueError, match="width"):
        DiffusionWorldConfig(width=66, heads=4)
    with pytest.raises(ValueError, match="temporal_patch"):
        DiffusionWorldConfig(max_frames=5, temporal_patch=2)
    with pytest.raises(ValueError, match="unknown diffusion world model preset"):
        preset("huge-dwm")


def test_context_flags_time_and_text_condition_the_velocity():
    model = _awake(_model())
    x = _latents()
    with torch.no_grad():
        base = model(x, 0.5, 2, ["push the package", "pick it"])
        assert torch.equal(base, model(x, 0.5, context_flags(2, 2, 4, "cpu"), ["push the package", "pick it"]))
        assert not torch.allclose(base, model(x, 0.5, 1, ["push the package", "pick it"]))
        assert not torch.allclose(base, model(x, 0.1, 2, ["push the package", "pick it"]))
        assert not torch.allclose(base, model(x, 0.5, 2, ["stack the cubes", "pick it"]))
        assert torch.equal(model(x, 0.5, 2, ["", ""]), model(x, 0.5, 2, None))  # no words: the no-text vector
        # Full attention: every frame's velocity reads every other frame, context included.
        changed = x.clone()
        changed[:, :, 0] += 1
        assert not torch.allclose(base[:, :, 3], model(changed, 0.5, 2, ["push the package", "pick it"])[:, :, 3])


def test_zero_initialised_action_encoder_changes_nothing_until_trained():
    model = _awake(_model())
    x, acts = _latents(), _actions(model)
    post = post_trainable(model, action_scale=[2.0] * 8).eval()
    assert post.config.action_conditioned and post.config.action_scale == (2.0,) * 8
    assert model.action_encoder is None and not model.config.action_conditioned  # the original is untouched
    with torch.no_grad():
        before = model(x, 0.5, 1, ["push"] * 2)
        assert torch.equal(post(x, 0.5, 1, ["push"] * 2, acts), before)
        assert torch.equal(post(x, 0.5, 1, ["push"] * 2), before)
        torch.nn.init.normal_(post.action_encoder.net[2].weight, std=0.5)
        moved = post(x, 0.5, 1, ["push"] * 2, acts)
        assert not torch.allclose(moved, before)
        # Frame 0 has no action leading into it; frame j + 1 reads row j only.
        later = acts.clone()
        later[:, 2] += 1
        longer = torch.cat([acts, acts[:, :1]], dim=1)  # a row past the window: ignored
        assert torch.equal(post(x, 0.5, 1, ["push"] * 2, longer), moved)
        again = post(x, 0.5, 1, ["push"] * 2, later)
        assert not torch.allclose(again, moved)
    with pytest.raises(ValueError, match="actions"):
        post(x, 0.5, 1, None, acts[:, :2])


def test_sampler_keeps_the_context_and_is_seeded():
    model = _awake(_model())
    context = _latents(t=2)
    one = model.sample(context, 2, ["push"] * 2, steps=1, generator=torch.Generator().manual_seed(0))
    eight = model.sample(context, 2, ["push"] * 2, steps=8, generator=torch.Generator().manual_seed(0))
    assert one.shape == eight.shape == (2, C, 4, 4, 4)
    assert torch.equal(one[:, :, :2], context) and torch.equal(eight[:, :, :2], context)
    assert not torch.allclose(one, eight)
    again = model.sample(context, 2, ["push"] * 2, steps=8, generator=torch.Generator().manual_seed(0))
    other = model.sample(context, 2, ["push"] * 2, steps=8, generator=torch.Generator().manual_seed(1))
    assert torch.equal(again, eight) and not torch.allclose(other, eight)
    # A fresh model predicts zero velocity: the sample is its starting noise, whatever the step count.
    fresh = _model().sample(context, 2, None, steps=3, generator=torch.Generator().manual_seed(0))
    noise = torch.randn(2, C, 2, 4, 4, generator=torch.Generator().manual_seed(0))
    assert torch.equal(fresh[:, :, 2:], noise)
    with pytest.raises(ValueError, match="exceed max_frames"):
        model.sample(context, 3)
    with pytest.raises(ValueError, match="action rows"):
        post_trainable(model).sample(context, 2, actions=torch.zeros(2, 2, model.config.action_features))


def test_temporal_patches_pad_the_window():
    model = _awake(_model(temporal_patch=2))
    x = _latents()
    with torch.no_grad():
        assert model(x, 0.5, 1).shape == x.shape
    with pytest.raises(ValueError, match="multiple of the patch"):
        model(x[:, :, :3], 0.5, 1)
    # 3 frames: one more future frame fills the last temporal patch and is dropped
    out = model.sample(x[:, :, :1], 2, None, steps=2, generator=torch.Generator().manual_seed(0))
    assert out.shape == (2, C, 3, 4, 4) and torch.equal(out[:, :, :1], x[:, :, :1])
    assert model.rollout(x[:, :, :1], 6, steps=1, generator=torch.Generator().manual_seed(0)).shape == (2, C, 6, 4, 4)


def test_rollout_slides_the_window_past_max_frames():
    model = post_trainable(_awake(_model()), None).eval()
    torch.nn.init.normal_(model.action_encoder.net[2].weight, std=0.5)
    context, acts = _latents(t=2), _actions(model, rows=2 - 1 + 5)
    out = model.rollout(context, 5, ["push"] * 2, acts, steps=2, generator=torch.Generator().manual_seed(0))
    assert out.shape == (2, C, 5, 4, 4)
    # The same as chaining samples by hand: keep the latest 2 frames, fill the 4-frame window.
    gen = torch.Generator().manual_seed(0)
    first = model.sample(context, 2, ["push"] * 2, acts[:, :3], 2, gen)  # frames 0..3
    second = model.sample(first[:, :, 2:], 2, ["push"] * 2, acts[:, 2:5], 2, gen)  # frames 2..5
    third = model.sample(second[:, :, 2:], 1, ["push"] * 2, acts[:, 4:6], 2, gen)  # frames 4..6
    assert torch.equal(out, torch.cat([first[:, :, 2:], second[:, :, 2:], third[:, :, 2:]], dim=2))
    one_by_one = model.rollout(context, 3, ["push"] * 2, acts, steps=1, generator=torch.Generator(), keep=3)
    assert one_by_one.shape == (2, C, 3, 4, 4)
    with pytest.raises(ValueError, match="action rows"):
        model.rollout(context, 6, ["push"] * 2, acts)

"""The world model: shapes, block causality, text and action conditioning, the zero-initialised
action encoder, seeding, rollouts, and that a tiny model can fit one sequence."""

import math

import pytest
import torch
import torch.nn.functional as F

from models.world_model import (
    PRESETS, WorldModel, WorldModelConfig, action_scale, next_frame_loss, post_trainable, preset, text_ids,
)

torch.set_num_threads(1)
K = 64  # a small codebook keeps these tests fast; the flow uses the tokenizer's


def _model(name="tiny-wm", seed=0, **overrides) -> WorldModel:
    torch.manual_seed(seed)
    return WorldModel(preset(name, codebook_size=K, max_height=4, max_width=4, **overrides)).eval()


def _codes(b=2, t=5, seed=0):
    return torch.randint(0, K, (b, t, 4, 4), generator=torch.Generator().manual_seed(seed))


def _actions(model, b=2, t=5, seed=1):
    return torch.randn(b, t, model.config.action_features, generator=torch.Generator().manual_seed(seed))


def _wake(model):
    """Give the zero-initialised action encoder's last layer weights so actions matter."""
    with torch.no_grad():
        torch.nn.init.normal_(model.action_encoder.net[2].weight, std=0.5)
    return model


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_shapes_and_parameter_counts(name):
    model = _model(name)
    codes = _codes()
    with torch.no_grad():
        logits = model(codes, ["push the package", "pick it"])
    assert logits.shape == (2, 5, 4, 4, K) and logits.dtype == torch.float32
    full = WorldModel(PRESETS[name])
    assert 1e5 < sum(p.numel() for p in full.parameters()) < 2e6  # a CPU model
    # At init: near uniform over K codes, plus the copy path's log K on each position's current code, so a
    # code that repeats has even odds and one that changes about 1 / 2K.
    assert PRESETS[name].copy_path
    static = codes[:, :1].expand_as(codes).contiguous()
    with torch.no_grad():
        assert math.isclose(next_frame_loss(model(static, None), static).item(), math.log(2), rel_tol=0.15)
        plain = WorldModel(model.config.model_copy(update={"copy_path": False}))
        assert math.isclose(next_frame_loss(plain(codes, None), codes).item(), math.log(K), rel_tol=0.1)


def test_change_weight_counts_codes_that_change_more():
    codes = torch.zeros(1, 3, 2, 2, dtype=torch.long)
    codes[0, 2, 0, 0] = 1  # one code changes between frames 1 and 2
    logits = torch.zeros(1, 3, 2, 2, 2)
    logits[..., 0] = 5.0  # confident that nothing changes: wrong on that one code only
    plain, weighted = next_frame_loss(logits, codes), next_frame_loss(logits, codes, change_weight=7.0)
    wrong, right = F.cross_entropy(torch.tensor([[5.0, 0.0]]), torch.tensor([1])), F.cross_entropy(
        torch.tensor([[5.0, 0.0]]), torch.tensor([0]))
    assert math.isclose(plain.item(), (wrong + 7 * right).item() / 8, rel_tol=1e-5)
    assert math.isclose(weighted.item(), (8 * wrong + 7 * right).item() / 15, rel_tol=1e-5)
    assert torch.equal(next_frame_loss(logits, codes, 0.0), plain)


def test_refuses_codes_beyond_its_window_and_actions_without_the_encoder():
    model = _model()
    with pytest.raises(ValueError, match="exceed max_frames"):
        model(_codes(t=model.config.max_frames + 1))
    with pytest.raises(ValueError, match="without action conditioning"):
        model(_codes(), actions=torch.zeros(2, 5, model.config.action_features))
    with pytest.raises(ValueError, match="width"):
        WorldModelConfig(width=66, heads=4)
    with pytest.raises(ValueError, match="unknown world model preset"):
        preset("huge-wm")


@pytest.mark.parametrize("j", [0, 2, 3])
def test_block_causality(j):
    """Changing latent frames j+1.. leaves the logits of positions <= j unchanged (and changes later ones)."""
    model = _wake(post_trainable(_model()))
    codes, actions = _codes(), _actions(model)
    later = codes.clone()
    later[:, j + 1:] = (later[:, j + 1:] + 1) % K
    later_actions = actions.clone()
    later_actions[:, j + 1:] += 1  # row j leads into frame j + 1: position j may see it, not later rows
    with torch.no_grad():
        base = model(codes, ["a box"] * 2, actions)
        changed = model(later, ["a box"] * 2, later_actions)
    assert torch.allclose(base[:, :j + 1], changed[:, :j + 1], atol=1e-6)
    assert not torch.allclose(base[:, j + 1:], changed[:, j + 1:], atol=1e-3)


def test_text_conditions_every_frame():
    model = _model()
    codes = _codes()
    with torch.no_grad():
        none = model(codes)
        push, pick = model(codes, ["push the package"] * 2), model(codes, ["pick the package"] * 2)
        again = model(codes, ["Push, the PACKAGE!"] * 2)  # the same bag of words
    for a, b in ((none, push), (push, pick)):
        assert (a - b).abs().amax(dim=(0, 2, 3, 4)).min() > 1e-4  # every position moves
    assert torch.equal(push, again)


def test_text_ids_are_a_stable_padded_bag_of_words():
    config = preset("tiny-wm", text_tokens=4)
    ids = text_ids(["push the box", "the the push", "", "a b c d e f"], config)
    assert ids.shape == (4, 4) and ids.dtype == torch.int64
    assert ids[0, 0] == ids[1, 1] and ids[0, 1] == ids[1, 0] and (ids[1, 2:] == 0).all()  # distinct words only
    assert (ids[2] == 0).all() and (ids[3] != 0).all()  # empty text is all padding; long text is cut
    assert ((ids >= 0) & (ids < config.text_vocab)).all()
    assert ids[0].tolist() == text_ids(["push the box"], config)[0].tolist()


def test_zero_initialised_action_encoder_reproduces_the_pretrained_logits_exactly():
    pre = _model()
    post = post_trainable(pre)
    assert pre.action_encoder is None and not pre.config.action_conditioned
    assert post.config.action_conditioned and post.action_encoder is not None
    codes, texts = _codes(), ["lift the package", "push it"]
    with torch.no_grad():
        assert torch.equal(post(codes, texts, _actions(post)), pre(codes, texts))
        assert torch.equal(post(codes, texts, _actions(post, t=4)), pre(codes, texts))
    # ... and the encoder can learn: its zero layer has a gradient.
    loss = next_frame_loss(post(codes, texts, _actions(post)), codes)
    loss.backward()
    assert post.action_encoder.net[2].weight.grad.abs().sum() > 0


def test_action_scale_is_the_rms_of_each_value_and_divides_before_the_encoder():
    t, d = PRESETS["tiny-wm"].temporal_compression, PRESETS["tiny-wm"].action_dim
    rows = torch.zeros(6, t, d)
    rows[:, :, 0] = 0.003 * torch.tensor([1.0, -1.0]).repeat(3)[:, None]
    rows[:, :, 1] = 1.0  # a gripper held closed
    scale = action_scale([rows[:4].reshape(4, t * d).numpy(), rows[4:].reshape(2, t * d)], d, t)
    assert scale[0] == pytest.approx(0.003) and scale[1] == 1.0 and scale[2:] == (1.0,) * (d - 2)  # padding: 1
    assert action_scale([None], d, t) == (1.0,) * d
    plain, scaled = _wake(post_trainable(_model())), post_trainable(_model(), scale)
    scaled.action_encoder.load_state_dict(plain.action_encoder.state_dict())
    assert scaled.config.action_scale == scale and "scale" not in scaled.state_dict()  # in config.json instead
    codes, actions = _codes(), _actions(plain)
    divided = actions / torch.tensor(scale, dtype=torch.float32).repeat(t)
    with torch.no_grad():
        assert torch.allclose(scaled(codes, None, actions), plain(codes, None, divided), atol=1e-5)
    with pytest.raises(ValueError, match="positive finite"):
        preset("tiny-wm", action_scale=(1.0, 0.0) + (1.0,) * (d - 2))
    with pytest.raises(ValueError, match="positive finite"):
        preset("tiny-wm", action_scale=(1.0,))


def test_actions_change_the_prediction_from_their_step_on():
    model = _wake(post_trainable(_model()))
    codes, actions = _codes(), _actions(model)
    other = actions.clone()
    other[:, 2] = -other[:, 2]
    with torch.no_grad():
        a, b = model(codes, None, actions), model(codes, None, other)
        short = model(codes, None, actions[:, :4])
    assert torch.equal(a[:, :2], b[:, :2]) and (a[:, 2:] - b[:, 2:]).abs().amax() > 1e-3
    assert torch.allclose(short[:, :4], a[:, :4], atol=1e-6)  # T' - 1 rows: the last position gets none


def test_seeded_models_are_identical():
    a, b, c = _model(seed=3), _model(seed=3), _model(seed=4)
    codes = _codes()
    assert all(torch.equal(p, q) for p, q in zip(a.state_dict().values(), b.state_dict().values()))
    with torch.no_grad():
        assert torch.equal(a(codes, ["x"] * 2), b(codes, ["x"] * 2))
        assert not torch.equal(a(codes, ["x"] * 2), c(codes, ["x"] * 2))


def test_rollout_shapes_range_argmax_and_sliding_window():
    model = _wake(post_trainable(_model(max_frames=4)))
    context = _codes(t=3)
    n = 4  # past max_frames: the window slides
    actions = _actions(model, t=3 - 1 + n)
    out = model.rollout(context, n, ["push"] * 2, actions)
    assert out.shape == (2, n, 4, 4) and out.dtype == torch.int64
    assert ((out >= 0) & (out < K)).all()
    with torch.no_grad():
        first = model(context, ["push"] * 2, actions[:, :3]).argmax(-1)[:, -1]
    assert torch.equal(out[:, 0], first)
    assert torch.equal(model.rollout(context, n, ["push"] * 2, actions), out)  # argmax is deterministic
    sampled = [model.rollout(context, 2, None, actions, temperature=1.0, generator=torch.Generator().manual_seed(5))
               for _ in range(2)]
    assert torch.equal(*sampled) and ((sampled[0] >= 0) & (sampled[0] < K)).all()
    with pytest.raises(ValueError, match="action rows"):
        model.rollout(context, n, None, actions[:, :3])


def test_a_tiny_model_overfits_one_sequence():
    model = _model().train()
    codes = _codes(b=1, t=4, seed=9)
    opt = torch.optim.AdamW(model.parameters(), lr=3e-3)
    for _ in range(60):
        loss = next_frame_loss(model(codes, ["one clip"]), codes)
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert loss.item() < 0.1 * math.log(K)


def test_patched_tokens_keep_the_code_grid_and_block_causality():
    """patch=2: a 2 x 2 block of codes per token; logits still ``B x T' x H' x W' x K`` and
    position j still sees frames <= j only."""
    model = _wake(post_trainable(_model(patch=2)))
    codes, actions = _codes(), _actions(model)
    later = codes.clone()
    later[:, 3:] = (later[:, 3:] + 1) % K
    with torch.no_grad():
        base = model(codes, ["a box"] * 2, actions)
        changed = model(later, ["a box"] * 2, actions)
    assert base.shape == (2, 5, 4, 4, K)
    assert torch.allclose(base[:, :3], changed[:, :3], atol=1e-6)
    assert not torch.allclose(base[:, 3:], changed[:, 3:], atol=1e-3)
    with pytest.raises(ValueError, match="multiple of patch"):
        preset("tiny-wm", max_height=6, max_width=6, patch=4)


def test_a_patched_model_learns_each_slot_of_its_block():
    """With patch=2 every code of a 2 x 2 block gets its own prediction: a model overfits a
    sequence whose frames are a fixed pattern shifted by one column each step (so the four
    slots of a token need four different answers), to argmax accuracy 1."""
    torch.manual_seed(0)
    model = WorldModel(preset("tiny-wm", codebook_size=K, max_height=4, max_width=4, patch=2))
    base = torch.arange(16).view(4, 4) * 3 % K
    codes = torch.stack([torch.roll(base, j, dims=1) for j in range(4)])[None]
    opt = torch.optim.AdamW(model.parameters(), lr=3e-3)
    for _ in range(300):
        loss = next_frame_loss(model(codes), codes)
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        predicted = model.eval()(codes)[:, :-1].argmax(-1)
    assert torch.equal(predicted, codes[:, 1:])

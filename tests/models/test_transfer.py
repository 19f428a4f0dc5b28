"""The transfer model: shapes, control weights, the prompt, the reference clip, causality over time, seeding."""

import pytest
import torch

from models.transfer import (ALL_CONTROLS, PRESETS, PROMPTS, REFERENCE_BINS, REFERENCE_FEATURES, TransferConfig,
                              TransferNet, palette_features, preset, reference_features)

torch.set_num_threads(1)


def _model(name="tiny", seed=0):
    torch.manual_seed(seed)
    return TransferNet(preset(name)).eval()


def _controls(model, frames=3, side=16, seed=0, batch=2):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(batch, model.config.control_channels, frames, side, side, generator=g) * 2 - 1


def _channels(config, control):
    """The slice of the stacked controls that belongs to ``control``."""
    start = sum(config.channels_of(c) for c in config.controls[:config.controls.index(control)])
    return slice(start, start + config.channels_of(control))


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_shapes_and_range(name):
    model = _model(name)
    side = 2 * model.config.multiple
    x = _controls(model, frames=2, side=side)
    with torch.no_grad():
        y = model(x, torch.tensor([0, len(PROMPTS) - 1]))
        forced = model(x, torch.tensor([0, 1]), torch.ones(2, len(model.config.controls)),
                       previous=torch.zeros(2, 3, 2, side, side))
    assert y.shape == forced.shape == (2, 3, 2, side, side)
    assert y.abs().max() <= 1


def test_config_refuses_what_does_not_fit():
    with pytest.raises(ValueError, match="divide"):
        TransferConfig(channels=(12, 16), groups=8)
    with pytest.raises(ValueError, match="repeat"):
        TransferConfig(controls=("edges", "edges"))
    with pytest.raises(ValueError, match="unknown prompt"):
        preset("tiny").prompt_index("sepia")
    with pytest.raises(ValueError, match="multiples"):
        _model()(torch.zeros(1, preset("tiny").control_channels, 1, 15, 16), torch.tensor([0]))


@pytest.mark.parametrize("control", ["edges", "blur", "depth", "segmentation"])
def test_a_zero_weight_removes_its_control(control):
    model = _model()
    config = model.config
    x = _controls(model)
    changed = x.clone()
    changed[:, _channels(config, control)] = torch.rand_like(changed[:, _channels(config, control)])
    weights = torch.ones(2, len(config.controls))
    weights[:, config.controls.index(control)] = 0
    prompts = torch.tensor([1, 2])
    with torch.no_grad():
        assert torch.equal(model(x, prompts, weights), model(changed, prompts, weights))
        assert not torch.allclose(model(x, prompts), model(changed, prompts))


def test_a_per_pixel_weight_map_removes_the_control_where_it_is_zero():
    """Edges weighted 0 on the left half: changing the edges there changes nothing at all."""
    model = _model()
    config = model.config
    x = _controls(model, frames=1, side=32)
    weights = torch.ones(2, len(config.controls), 1, 32, 32)
    weights[:, config.controls.index("edges"), :, :, :16] = 0
    changed = x.clone()
    changed[:, _channels(config, "edges"), :, :, :16] *= -1
    prompts = torch.tensor([0, 0])
    with torch.no_grad():
        assert torch.equal(model(x, prompts, weights), model(changed, prompts, weights))
        # Scalar weights of the same shape as a map broadcast the same way.
        flat = torch.ones(2, len(config.controls))
        assert torch.allclose(model(x, prompts, flat), model(x, prompts, torch.ones_like(weights)), atol=1e-6)


def test_the_prompt_changes_the_output():
    model = _model()
    with torch.no_grad():
        # FiLM layers start random (not zero), so an untrained model already answers the prompt.
        a = model(_controls(model), torch.tensor([0, 0]))
        b = model(_controls(model), torch.tensor([PROMPTS.index("dim")] * 2))
    assert (a - b).abs().mean() > 1e-3


@pytest.mark.parametrize("forced", [False, True])
def test_frame_t_depends_on_nothing_after_t(forced):
    model = _model()
    x = _controls(model, frames=5)
    later = x.clone()
    later[:, :, 3:] = torch.rand_like(later[:, :, 3:])
    previous = torch.rand(2, 3, 5, 16, 16) * 2 - 1
    prev_later = previous.clone()
    prev_later[:, :, 2:] = 0  # frame t sees previous frame t - 1 only: frames >= 2 feed frames >= 3
    prompts = torch.tensor([0, 3])
    with torch.no_grad():
        a = model(x, prompts, previous=previous if forced else None)
        b = model(later, prompts, previous=prev_later if forced else None)
    assert torch.equal(a[:, :, :3], b[:, :, :3])
    assert not torch.allclose(a[:, :, 3:], b[:, :, 3:])


def test_free_running_is_teacher_forcing_on_its_own_output():
    model = _model()
    x = _controls(model, frames=4)
    prompts = torch.tensor([1, 4])
    with torch.no_grad():
        own = model(x, prompts)
        assert torch.allclose(model(x, prompts, previous=own), own, atol=1e-5)


def test_same_seed_same_weights_and_output():
    x = _controls(_model())
    with torch.no_grad():
        assert torch.equal(_model(seed=3)(x, torch.tensor([0, 1])), _model(seed=3)(x, torch.tensor([0, 1])))
        assert not torch.equal(_model(seed=3)(x, torch.tensor([0, 1])), _model(seed=4)(x, torch.tensor([0, 1])))


def test_reference_features_are_the_clips_colour_statistics():
    frames = torch.full((1, 3, 2, 4, 4), -1.0)
    frames[:, 0] = 0.5  # red at 0.5 everywhere, green and blue at -1
    feats = reference_features(frames)
    assert feats.shape == (1, REFERENCE_FEATURES)
    assert torch.allclose(feats[0, :3], torch.tensor([0.5, -1.0, -1.0])) and torch.all(feats[0, 3:6] == 0)
    hist = feats[0, 6:].reshape(3, REFERENCE_BINS)
    assert torch.allclose(hist.sum(1), torch.ones(3))
    assert hist[0, 6] == 1 and hist[1, 0] == 1  # 0.5 falls in bin 6 of 8 over [-1, 1]
    # global statistics: the order of frames and pixels, and the clip's size, do not matter
    g = torch.Generator().manual_seed(0)
    clip = torch.rand(1, 3, 3, 8, 8, generator=g) * 2 - 1
    assert torch.allclose(reference_features(clip), reference_features(clip.flip(2).flip(3)), atol=1e-6)
    assert torch.allclose(reference_features(clip), reference_features(clip.repeat(1, 1, 1, 2, 2)), atol=1e-6)


def test_a_reference_clip_moves_the_output_and_a_missing_one_is_the_prompt_alone():
    config = preset("tiny").model_copy(update={"reference": True})
    torch.manual_seed(0)
    model = TransferNet(config).eval()
    x, prompts = _controls(model), torch.tensor([1, 1])
    warm = reference_features(torch.rand(2, 3, 2, 8, 8) * 0.5 + 0.5)
    cold = reference_features(torch.rand(2, 3, 2, 8, 8) * 0.5 - 1)
    none = torch.full((2, REFERENCE_FEATURES), float("nan"))
    with torch.no_grad():
        plain = model(x, prompts)
        assert (model(x, prompts, reference=warm) - model(x, prompts, reference=cold)).abs().mean() > 1e-3
        assert torch.equal(model(x, prompts, reference=none), plain)
        mixed = model(x, prompts, reference=torch.stack([warm[0], none[0]]))  # per clip
        assert torch.equal(mixed[1], plain[1]) and not torch.equal(mixed[0], plain[0])
        forced = model(x, prompts, previous=torch.zeros(2, 3, 3, 16, 16), reference=warm)
        assert torch.allclose(forced[:, :, 0], model(x[:, :, :1], prompts, reference=warm)[:, :, 0], atol=1e-5)
    with pytest.raises(ValueError, match="not trained with reference clips"):
        _model()(x, prompts, reference=warm)
    assert TransferConfig.model_validate({"name": "old", "channels": [8, 16], "groups": 4}).reference is False


def _affine(seed=0):
    config = preset("tiny").model_copy(update={"controls": ("edges", "frame"), "head": "affine"})
    torch.manual_seed(seed)
    return TransferNet(config).eval()


def test_the_affine_head_starts_as_the_source_frame_and_its_weight_scales_the_frame():
    model = _affine()
    x, prompts = _controls(model), torch.tensor([0, 3])
    frame = x[:, _channels(model.config, "frame")]
    with torch.no_grad():
        assert torch.allclose(model(x, prompts), frame, atol=1e-6)
        # weight 0.5 on the frame: half its brightness in [0, 1] units; 0: black (the offset alone)
        half = model(x, prompts, torch.tensor([[1.0, 0.5], [1.0, 0.0]]))
        assert torch.allclose(half[0], (frame[0] + 1) / 2 - 1, atol=1e-6)
        assert torch.allclose(half[1], torch.full_like(half[1], -1.0))
        # once trained, the gain and offset depend on the other controls and the prompt
        torch.nn.init.normal_(model.conv_out.weight, std=0.1)
        changed = x.clone()
        changed[:, _channels(model.config, "edges")] *= -1
        assert not torch.allclose(model(x, prompts), model(changed, prompts))
        assert not torch.allclose(model(x, prompts), model(x, torch.tensor([1, 4])))
        assert model(x, prompts).abs().max() <= 1


def test_the_affine_head_needs_the_frame_control():
    with pytest.raises(ValueError, match="must include 'frame'"):
        TransferConfig(head="affine")
    assert TransferConfig.model_validate({"name": "old", "channels": [8, 16], "groups": 4}).head == "direct"


def test_palette_features_are_each_class_mean_colour_and_whether_it_is_there():
    frames = torch.full((1, 3, 2, 2, 4), -1.0)
    frames[:, 0, :, :, 2:] = 0.5  # the right half red
    seg = torch.zeros(1, 2, 2, 4, dtype=torch.long)
    seg[..., 2:] = 2  # class 2 on the right half; class 1 nowhere
    rows = palette_features(frames, seg, 3).view(3, 4)
    assert torch.allclose(rows[0], torch.tensor([-1.0, -1.0, -1.0, 1.0]))
    assert torch.allclose(rows[1], torch.zeros(4))
    assert torch.allclose(rows[2], torch.tensor([0.5, -1.0, -1.0, 1.0]))


def _palette_model(seed=0):
    config = preset("tiny").model_copy(update={"controls": ALL_CONTROLS, "reference": True, "head": "affine",
                                               "palette": True})
    torch.manual_seed(seed)
    model = TransferNet(config).eval()
    torch.nn.init.normal_(model.conv_out.weight, std=0.1)  # as if trained: the head reads its inputs
    return model


def _segmented(model, frames=2, side=16):
    """Controls whose segmentation channels are a real one-hot map (class 1 left, class 3 right)."""
    x = _controls(model, frames=frames, side=side)
    seg = torch.zeros(2, model.config.seg_classes, frames, side, side)
    seg[:, 1, ..., :side // 2] = 1
    seg[:, 3, ..., side // 2:] = 1
    x[:, _channels(model.config, "segmentation")] = seg
    return x


def test_a_palette_model_draws_the_references_class_colours_over_the_segmentation():
    model = _palette_model()
    c = model.config
    x, prompts = _segmented(model), torch.tensor([3, 3])
    look = reference_features(torch.zeros(2, 3, 1, 4, 4))
    palette = torch.zeros(2, c.seg_classes, 4)
    palette[:, 1] = torch.tensor([0.9, -0.9, 0.0, 1.0])  # class 1 known and red; class 3 unknown
    row = torch.cat([look, palette.flatten(1)], 1)
    maps = model.palette_maps(x[:, :, 0], row)
    assert torch.allclose(maps[:, :3, :, :8], torch.tensor([0.9, -0.9, 0.0])[None, :, None, None].expand(2, 3, 16, 8))
    assert torch.all(maps[:, :4, :, 8:] == 0) and torch.all(maps[:, 3, :, :8] == 1)
    frame01 = (x[:, _channels(c, "frame"), 0] + 1) / 2
    source = frame01[..., :8].mean((2, 3))  # the source's class mean on the left, in [0, 1] units
    expected = (((torch.tensor([0.9, -0.9, 0.0]) + 1) / 2) / source - 1).clamp(-1, 3)
    assert torch.allclose(maps[:, 4:, 0, 0], expected, atol=1e-4)  # the gain, minus 1, that takes it there
    assert torch.all(maps[:, 4:, :, 8:] == 0)  # unknown on the right: no gain
    with torch.no_grad():
        other = row.clone()
        other[:, REFERENCE_FEATURES + 4:REFERENCE_FEATURES + 7] = -0.5
        assert not torch.allclose(model(x, prompts, reference=row), model(x, prompts, reference=other))
        # no palette (a clip without segmentation) is every class unknown; a NaN row the prompt alone
        unknown = torch.cat([look, torch.zeros(2, 4 * c.seg_classes)], 1)
        assert torch.equal(model(x, prompts, reference=look), model(x, prompts, reference=unknown))
        nan = torch.full((2, c.reference_size), float("nan"))
        assert torch.equal(model(x, prompts, reference=nan), model(x, prompts))
        # the segmentation's weight gates the palette too: at 0 the class colours are gone
        off = torch.ones(2, len(c.controls))
        off[:, c.controls.index("segmentation")] = 0
        assert torch.equal(model(x, prompts, off, reference=row), model(x, prompts, off, reference=other))
    with pytest.raises(ValueError, match="reference rows of 5 numbers"):
        model(x, prompts, reference=torch.zeros(2, 5))


def test_an_affine_output_pushed_past_black_still_learns():
    """The affine head clips to [0, 1]; in training the gradient passes the clip, so a look
    pushed below black (all pixels clipped) is not stuck there."""
    config = preset("tiny").model_copy(update={"controls": ALL_CONTROLS, "reference": True, "head": "affine"})
    model = TransferNet(config)
    with torch.no_grad():
        model.conv_out.bias[3:] = -5.0  # offset far below black
    x, prompts = _controls(model), torch.tensor([1, 1])
    out = model(x, prompts, previous=torch.zeros(2, 3, 3, 16, 16))
    assert torch.all(out == -1)  # black: every pixel clipped
    (out - 0.5).abs().mean().backward()
    assert model.conv_out.bias.grad[3:].abs().min() > 0  # and the offset is still told to rise
    with torch.no_grad():
        assert torch.equal(model(x, prompts), out.detach())  # the same values without gradients


def test_a_new_palette_model_applies_the_palettes_gain_to_the_source():
    config = preset("tiny").model_copy(update={"controls": ALL_CONTROLS, "reference": True, "head": "affine",
                                               "palette": True})
    torch.manual_seed(0)
    model = TransferNet(config).eval()  # untrained: the head's own gain and offset are 0
    x, prompts = _segmented(model), torch.tensor([3, 3])
    palette = torch.zeros(2, config.seg_classes, 4)
    palette[:, 1] = torch.tensor([0.2, -0.6, 0.0, 1.0])
    row = torch.cat([reference_features(torch.zeros(2, 3, 1, 4, 4)), palette.flatten(1)], 1)
    frame01 = (x[:, _channels(config, "frame")] + 1) / 2
    with torch.no_grad():
        out01 = (model(x, prompts, reference=row) + 1) / 2
        assert torch.allclose(out01[..., 8:], frame01[..., 8:], atol=1e-6)  # class 3, unknown: the source as is
        left = out01[..., :8].mean((2, 3, 4))  # class 1 takes the palette's colour (where nothing clips)
        assert torch.allclose(left[:, 1], torch.full((2,), 0.2), atol=0.02)
        assert torch.allclose(left[:, 2], torch.full((2,), 0.5), atol=0.02)


def test_a_clip_gain_is_one_gain_for_every_frame_of_the_clip():
    """palette_gain clip: the source's class means come from the whole clip, so the gain does not
    follow the frame's own mean as objects move (a frame-by-frame gain flickers); teacher-forced
    and free-running passes use the same means."""
    model = _palette_model()
    clip = TransferNet(model.config.model_copy(update={"palette_gain": "clip"})).eval()
    clip.load_state_dict(model.state_dict())
    c = model.config
    x, prompts = _segmented(model, frames=3), torch.tensor([3, 3])
    frame = _channels(c, "frame")
    x[:, frame, 1] = (x[:, frame, 1] + 1) * 0.5 - 1  # the middle frame's source is half as bright
    palette = torch.zeros(2, c.seg_classes, 4)
    palette[:, 1] = torch.tensor([0.2, -0.6, 0.0, 1.0])
    row = torch.cat([reference_features(torch.zeros(2, 3, 1, 4, 4)), palette.flatten(1)], 1)
    means = clip.source_means(x)
    frame01 = (x[:, frame] + 1) / 2
    assert torch.allclose(means[:, 1], frame01[..., :8].mean((2, 3, 4)), atol=1e-5)
    per_frame = [model.palette_maps(x[:, :, t], row)[:, 4:, 0, 0] for t in range(3)]
    steady = [model.palette_maps(x[:, :, t], row, means)[:, 4:, 0, 0] for t in range(3)]
    assert not torch.allclose(per_frame[0], per_frame[1], atol=1e-3)  # the frame's own mean moved
    assert torch.allclose(steady[0], steady[1]) and torch.allclose(steady[1], steady[2])
    with torch.no_grad():
        free = clip(x, prompts, reference=row)
        forced = clip(x, prompts, previous=free, reference=row)
        assert torch.allclose(free, forced, atol=1e-5)
        assert not torch.allclose(free, model(x, prompts, reference=row), atol=1e-3)
        # per-pixel weights shared by the frames (B x n x H x W) weigh the clip's means as each frame's
        w = torch.rand(2, len(c.controls), 16, 16)
        assert torch.allclose(clip(x, prompts, w, reference=row),
                              clip(x, prompts, w[:, :, None].expand(-1, -1, 3, -1, -1), reference=row), atol=1e-5)
    assert preset("small-palette").palette_gain == "clip" and TransferConfig().palette_gain == "frame"


def test_a_palette_needs_references_and_the_frame_and_segmentation_controls():
    with pytest.raises(ValueError, match="palette needs"):
        TransferConfig(controls=ALL_CONTROLS, head="affine", palette=True)
    with pytest.raises(ValueError, match="palette needs"):
        TransferConfig(controls=("edges", "frame"), reference=True, palette=True)
    assert preset("small-palette").reference_size == REFERENCE_FEATURES + 4 * preset("small-palette").seg_classes
    assert preset("small-palette").seg_groups == "objects" and preset("small").seg_groups == "grouped"
    with pytest.raises(ValueError, match="seg_groups 'objects' has 8 classes"):
        TransferConfig(seg_groups="objects")

"""The causal video tokenizer: Haar patching, causality, shapes, round trips, determinism, FSQ."""

import math

import pytest
import torch

from models.tokenizer import PRESETS, TokenizerConfig, VideoTokenizer, preset
from models.tokenizer_layers import FSQ, haar_patch, haar_unpatch

torch.set_num_threads(1)


def _video(frames=17, side=32, seed=0):
    return torch.rand(1, 3, frames, side, side, generator=torch.Generator().manual_seed(seed)) * 2 - 1


@pytest.mark.parametrize("levels", [(2, 1), (0, 1), (2, 0), (1, 2), (3, 1)])
def test_haar_is_exactly_invertible_and_causal(levels):
    lt, ls = levels
    x = _video(1 + 8 * 2)
    y = haar_patch(x, lt, ls)
    assert y.shape == (1, 3 * 2 ** lt * 4 ** ls, 1 + 16 // 2 ** lt, 32 // 2 ** ls, 32 // 2 ** ls)
    assert torch.allclose(haar_unpatch(y, lt, ls), x, atol=1e-5)
    later = x.clone()
    later[:, :, 1:] = 0
    assert torch.equal(haar_patch(later, lt, ls)[:, :, :1], y[:, :, :1])  # first frame alone


@pytest.mark.parametrize("name", sorted(n for n in PRESETS if n.startswith("tiny")))
def test_shapes_and_round_trip(name):
    torch.manual_seed(0)
    model = VideoTokenizer(preset(name)).eval()
    c = model.config
    x = _video(1 + 2 * c.temporal_compression)
    with torch.no_grad():
        recon, z = model(x)
        latents = model.encode(x)
        again = model.decode(latents)
    grid = c.latent_shape(x.shape[2], 32, 32)
    assert grid == (3, 4, 4)
    assert recon.shape == x.shape == again.shape
    assert z.shape == (1, c.code_channels, *grid) and z.abs().max() <= 1
    if c.variant == "discrete":
        assert latents.shape == (1, *grid) and latents.dtype == torch.int64
        assert torch.allclose(again, recon, atol=1e-5)  # codes carry everything the decoder sees
    else:
        assert latents.shape == (1, c.latent_channels, *grid)
        assert torch.allclose(again, recon, atol=1e-5)


@pytest.mark.parametrize("name", ["tiny-dv4x8x8", "tiny-cv4x8x8", "tiny-dv8x8x8", "small-dv4x4x4", "small-cv4x4x4"])
def test_causal_latents_and_reconstruction(name):
    """Changing frames after t leaves every latent frame that covers only frames <= t unchanged."""
    torch.manual_seed(1)
    model = VideoTokenizer(preset(name)).eval()
    t = model.config.temporal_compression
    x = _video(1 + 3 * t)
    with torch.no_grad():
        base, base_codes = model.encoder(x), model.encode(x)
        base_recon = model.decode(base_codes)
        for cut in (0, t, 2 * t):  # latent j covers input frames <= j t
            changed = x.clone()
            changed[:, :, cut + 1:] = torch.rand_like(changed[:, :, cut + 1:]) * 2 - 1
            j = cut // t
            assert torch.equal(model.encoder(changed)[:, :, :j + 1], base[:, :, :j + 1])
            assert not torch.equal(model.encoder(changed)[:, :, j + 1:], base[:, :, j + 1:])
            recon = model.decode(model.encode(changed))
            assert torch.allclose(recon[:, :, :cut + 1], base_recon[:, :, :cut + 1], atol=1e-6)


def test_first_latent_frame_is_an_image_code():
    torch.manual_seed(2)
    model = VideoTokenizer(preset("tiny-cv4x8x8")).eval()
    x = _video(9)
    with torch.no_grad():
        assert torch.allclose(model.encode(x[:, :, :1]), model.encode(x)[:, :, :1], atol=1e-6)


def test_same_seed_same_weights_and_outputs():
    def build(seed):
        torch.manual_seed(seed)
        return VideoTokenizer(preset("tiny-dv4x8x8")).eval()

    a, b, c = build(3), build(3), build(4)
    x = _video(9)
    with torch.no_grad():
        assert torch.equal(a.encode(x), b.encode(x)) and torch.equal(a(x)[0], b(x)[0])
        assert not torch.equal(a(x)[0], c(x)[0])


@pytest.mark.parametrize("levels", [(8, 5, 5, 5), (7, 5, 5, 5, 5), (8, 8, 8, 6, 5), (2, 3)])
def test_fsq_codes_cover_the_codebook_and_invert(levels):
    fsq = FSQ(levels)
    z = torch.randn(64, len(levels), 50) * 4
    zq, codes = fsq(z)
    assert codes.min() >= 0 and codes.max() < math.prod(levels) == fsq.codebook_size
    assert zq.abs().max() <= 1
    assert torch.allclose(fsq.from_codes(codes), zq, atol=1e-6)
    for i, n in enumerate(levels):  # every level is reachable and no other value appears
        assert len(torch.unique(zq[:, i])) == n
    every = torch.arange(fsq.codebook_size)
    assert torch.equal(fsq.codes(fsq.from_codes(every)), every)


def test_fsq_gradient_passes_straight_through():
    fsq = FSQ((8, 5, 5, 5))
    z = torch.randn(2, 4, 3, requires_grad=True)
    fsq(z)[0].sum().backward()
    assert z.grad is not None and z.grad.abs().sum() > 0


def test_bits_per_pixel_and_bad_sizes():
    d = preset("small-dv4x8x8")
    assert d.bits_per_pixel(17, 64, 64) == pytest.approx(5 * 64 * math.log2(1000) / (17 * 64 * 64))
    assert preset("small-cv4x8x8").bits_per_pixel(17, 64, 64) == pytest.approx(5 * 64 * 16 * 8 / (17 * 64 * 64))
    with pytest.raises(ValueError, match="1 \\+ 4k frames"):
        d.latent_shape(16, 64, 64)
    with pytest.raises(ValueError):
        TokenizerConfig(spatial_compression=8, channels=(16, 32))  # needs three levels
    with pytest.raises(ValueError, match="unknown tokenizer preset"):
        preset("huge")
    assert {"tiny-dv4x8x8", "tiny-cv4x8x8", "tiny-dv8x8x8", "tiny-cv8x8x8"} <= set(PRESETS)
    fine = preset("small-dv4x4x4")  # the world model's tokenizer for small objects: a 16 x 16 grid at 64
    assert fine.latent_shape(17, 64, 64) == (5, 16, 16)
    assert fine.bits_per_pixel(17, 64, 64) == pytest.approx(4 * d.bits_per_pixel(17, 64, 64))

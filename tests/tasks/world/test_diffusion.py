"""Diffusion world model training: windows, noising, the future-only loss, seeded training that
learns, post-training with actions, encoding with a continuous tokenizer, checkpoints, devices."""

import json

import numpy as np
import pytest
import torch

from models.diffusion_world import DiffusionWorldModel, preset
from models.tokenizer import VideoTokenizer
from models.tokenizer import preset as tokenizer_preset
from models.world_model import WorldModel
from models.world_model import preset as ar_preset
from tasks.checkpoint_files import CheckpointError
from tasks.device import Runtime
from tasks.world import checkpoints as ar_checkpoints
from tasks.world.diffusion import (
    DiffusionTrainConfig, LatentSequence, encode_latents, flow_matching_loss, flow_times, load_checkpoint,
    noised_window, posttrain, read_config, sample_windows, save_checkpoint, train_diffusion,
)

C = 4
F_ACT = 32  # action_features of the default config: 4 slots x 8 values


def _sequences(n=3, frames=6, with_actions=False):
    """Sequences whose frame j is frame 0 rolled by j columns: the next frame is predictable."""
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        first = rng.uniform(-1, 1, (C, 4, 4)).astype(np.float32)
        latents = np.stack([np.roll(first, j, axis=-1) for j in range(frames)])
        actions = rng.normal(size=(frames - 1, F_ACT)).astype(np.float32) if with_actions else None
        out.append(LatentSequence(key=f"s{i}", latents=latents, text=f"clip {i}", actions=actions))
    return out


def _model(seed=0, **overrides):
    torch.manual_seed(seed)
    return DiffusionWorldModel(preset("tiny-dwm", latent_channels=C, max_height=4, max_width=4, max_frames=4,
                                      **overrides))


def _same(a, b):
    return all(torch.equal(p, q) for p, q in zip(a.state_dict().values(), b.state_dict().values(), strict=True))


def test_windows_and_their_action_rows():
    seqs = _sequences(2, 6, with_actions=True)
    latents, texts, actions = sample_windows(seqs, 4, 5, torch.Generator().manual_seed(0), True)
    assert latents.shape == (5, C, 4, 4, 4) and latents.dtype == torch.float32 and actions.shape == (5, 3, F_ACT)
    for b in range(5):
        seq = next(s for s in seqs if s.text == texts[b])
        window = latents[b].transpose(0, 1).numpy()  # back to T' x C x H' x W'
        t0 = next(t for t in range(3) if np.array_equal(seq.latents[t:t + 4], window))
        assert np.array_equal(actions[b].numpy(), seq.actions[t0:t0 + 3])
    _, dropped, none = sample_windows(seqs, 4, 50, torch.Generator().manual_seed(0), text_dropout=0.5)
    assert none is None and 10 < dropped.count("") < 40
    with pytest.raises(ValueError, match="no actions"):
        sample_windows(_sequences(1), 4, 1, torch.Generator(), True)
    with pytest.raises(ValueError, match="no sequence has 7"):
        sample_windows(seqs, 7, 1, torch.Generator())


def test_noising_keeps_the_context_and_the_loss_skips_it():
    latents = torch.from_numpy(np.stack([s.latents for s in _sequences(3, 4)])).transpose(1, 2)
    inputs, s, flags, target = noised_window(latents, torch.Generator().manual_seed(0), "uniform", min_context=2)
    counts = flags.sum(1)
    assert ((counts >= 2) & (counts <= 3)).all() and (flags[:, :1]).all()
    keep = flags[:, None, :, None, None].expand_as(latents)
    assert torch.equal(inputs[keep], latents[keep]) and not torch.equal(inputs[~keep], latents[~keep])
    noise = target + latents  # the target velocity is noise - data ...
    ss = s.view(-1, 1, 1, 1, 1)
    assert torch.allclose(inputs[~keep], ((1 - ss) * latents + ss * noise).expand_as(latents)[~keep], atol=1e-6)
    wrong = target.clone()
    wrong[keep] += 5  # ... and errors on context frames cost nothing
    assert flow_matching_loss(wrong, target, flags).item() == 0.0
    assert flow_matching_loss(torch.zeros_like(target), target, flags).item() > 0.5
    t = flow_times(10000, torch.Generator().manual_seed(0))
    assert 0 < t.min() and t.max() < 1 and abs(t.mean().item() - 0.5) < 0.02 and t.std() < 0.25  # logit-normal
    with pytest.raises(ValueError, match="time sampling"):
        flow_times(2, torch.Generator(), "cosine")


def test_training_is_seeded():
    config = DiffusionTrainConfig(steps=6, batch_size=2, threads=1, log_every=3)
    a, b = _model(), _model()
    history = train_diffusion(a, _sequences(), config)
    train_diffusion(b, _sequences(), config)
    assert _same(a, b) and not _same(a, _model())
    c = _model()  # the same initial weights, another seed: other minibatches and noise, other weights
    train_diffusion(c, _sequences(), config.model_copy(update={"seed": config.seed + 1}))
    assert not _same(a, c)
    assert [h["step"] for h in history] == [3, 6] and set(history[0]) == {"step", "seconds", "loss", "lr"}
    budget = train_diffusion(_model(), _sequences(), config.model_copy(update={"seconds": 1e-6}))
    assert [h["step"] for h in budget] == [1]  # a budget ends training (and is logged)


def test_training_learns_then_samples():
    config = DiffusionTrainConfig(steps=150, batch_size=8, lr=3e-3, warmup_steps=10, threads=1, log_every=10)
    a = _model()
    history = train_diffusion(a, _sequences(), config)
    assert [h["step"] for h in history] == list(range(10, 151, 10))
    assert history[-1]["loss"] < 0.6 * history[0]["loss"]
    context = torch.from_numpy(_sequences()[0].latents[:2]).transpose(0, 1)[None]
    for steps in (1, 8):
        out = a.sample(context, 2, ["clip 0"], steps=steps, generator=torch.Generator().manual_seed(0))
        assert out.shape == (1, C, 4, 4, 4) and torch.isfinite(out).all()


def test_posttraining_starts_from_the_pretrained_model_and_reads_actions():
    pre = _model()
    train_diffusion(pre, _sequences(), DiffusionTrainConfig(steps=5, batch_size=2, threads=1, log_every=5))
    episodes = _sequences(2, 5, with_actions=True)
    config = DiffusionTrainConfig(steps=10, batch_size=2, threads=1, log_every=5)
    post, history = posttrain(pre, episodes, config)
    assert post.config.action_conditioned and pre.action_encoder is None and len(history) == 2
    rms = np.sqrt(np.mean(np.concatenate([e.actions for e in episodes]).reshape(-1, 8) ** 2, axis=0))
    assert np.allclose(post.config.action_scale, rms, rtol=1e-5)
    assert post.action_encoder.net[2].weight.abs().sum() > 0  # the encoder trained
    with pytest.raises(ValueError, match="no actions"):
        posttrain(pre, _sequences(1), config)


def test_encode_latents_with_a_continuous_tokenizer():
    torch.manual_seed(0)
    tokenizer = VideoTokenizer(tokenizer_preset("tiny-cv4x8x8"))
    frames = np.random.default_rng(0).integers(0, 256, (7, 20, 16, 3), dtype=np.uint8)  # 7 frames: 5 used
    latents = encode_latents(tokenizer, frames, 16)
    assert latents.shape == (2, 16, 2, 2) and latents.dtype == np.float32 and np.abs(latents).max() <= 1
    with pytest.raises(ValueError, match="continuous tokenizer"):
        encode_latents(VideoTokenizer(tokenizer_preset("tiny-dv4x8x8")), frames, 16)


def test_checkpoint_round_trip(tmp_path):
    model = _model()
    posttrain_model, _ = posttrain(model, _sequences(2, 5, with_actions=True),
                                   DiffusionTrainConfig(steps=3, batch_size=2, threads=1))
    for m, name in ((model, "pre"), (posttrain_model, "post")):
        save_checkpoint(m, tmp_path / name, {"phase": name})
        loaded = load_checkpoint(tmp_path / name)
        assert loaded.config == m.config and _same(loaded, m)
        body = json.loads((tmp_path / name / "config.json").read_text())
        assert body["phase"] == name and body["diffusion_world_model"]["name"] == "tiny-dwm"
        assert read_config(tmp_path / name)["phase"] == name
        context = torch.from_numpy(_sequences()[0].latents[:2]).transpose(0, 1)[None]
        acts = torch.zeros(1, 3, F_ACT) if m.config.action_conditioned else None
        samples = [x.sample(context, 2, ["clip"], acts, 2, torch.Generator().manual_seed(3))
                   for x in (m.eval(), loaded)]
        assert torch.equal(*samples)
    with pytest.raises(CheckpointError, match="world_model"):
        ar_checkpoints.load_checkpoint(tmp_path / "pre")  # config.json names the family
    ar_checkpoints.save_checkpoint(WorldModel(ar_preset("tiny-wm", codebook_size=8)), tmp_path / "ar")
    with pytest.raises(CheckpointError, match="no 'diffusion_world_model' mapping"):
        load_checkpoint(tmp_path / "ar")


def test_cpu_runtime_trains_where_asked():
    model = _model()
    history = train_diffusion(model, _sequences(), DiffusionTrainConfig(steps=2, batch_size=2, threads=1),
                              runtime=Runtime(device="cpu"))
    assert len(history) == 1 and next(model.parameters()).device.type == "cpu"


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_cuda_runtime_trains_and_samples_on_the_gpu():
    config = DiffusionTrainConfig(steps=4, batch_size=2, threads=1)
    gpu, cpu = _model(), _model()
    history = train_diffusion(gpu, _sequences(), config, runtime=Runtime(device="cuda"))
    train_diffusion(cpu, _sequences(), config, runtime=Runtime(device="cpu"))
    assert len(history) == 1 and next(gpu.parameters()).device.type == "cuda"
    for p, q in zip(gpu.state_dict().values(), cpu.state_dict().values(), strict=True):
        assert torch.allclose(p.cpu(), q, atol=1e-4)  # same windows and noise: CPU draws, fp32 on both
    context = torch.from_numpy(_sequences()[0].latents[:2]).transpose(0, 1)[None]
    out = gpu.sample(context, 2, ["clip"], steps=2, generator=torch.Generator().manual_seed(0))
    assert out.device.type == "cpu" and torch.allclose(
        out, cpu.sample(context, 2, ["clip"], steps=2, generator=torch.Generator().manual_seed(0)), atol=1e-3)
    assert gpu.rollout(context.cuda(), 5, ["clip"], steps=1).device.type == "cuda"
    bf16 = _model()
    train_diffusion(bf16, _sequences(), config, runtime=Runtime(device="cuda", precision="bf16"))
    assert all(torch.isfinite(p).all() for p in bf16.parameters())

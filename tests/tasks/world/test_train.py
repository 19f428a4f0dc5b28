"""World model training loops, windows and checkpoints, without Prefect."""

import numpy as np
import pytest
import torch

from models.world_model import WorldModel, next_frame_loss, post_trainable, preset
from tasks.world import checkpoints
from tasks.world.data import CodeSequence
from tasks.world.train import (WorldTrainConfig, own_inputs, posttrain, sample_windows, teacher_forced,
                               train_world_model, window_length)

K = 32


def _sequences(n=3, frames=6, with_actions=False):
    """Sequences whose frame j is frame 0 shifted by j codes: the next frame is predictable."""
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        first = rng.integers(0, K, (4, 4))
        codes = np.stack([(first + j) % K for j in range(frames)]).astype(np.int64)
        actions = np.arange((frames - 1) * 32, dtype=np.float32).reshape(frames - 1, 32) if with_actions else None
        out.append(CodeSequence(key=f"s{i}", codes=codes, text=f"clip {i}", actions=actions))
    return out


def _model(seed=0):
    torch.manual_seed(seed)
    return WorldModel(preset("tiny-wm", codebook_size=K, max_height=4, max_width=4, max_frames=4))


def test_windows_and_their_action_rows():
    seqs = _sequences(2, 6, with_actions=True)
    assert window_length(seqs, 4) == 4 and window_length(seqs, 16) == 6
    codes, texts, actions = sample_windows(seqs, 4, 5, torch.Generator().manual_seed(0), True)
    assert codes.shape == (5, 4, 4, 4) and codes.dtype == torch.int64 and actions.shape == (5, 3, 32)
    for b in range(5):
        seq = next(s for s in seqs if s.text == texts[b])
        t0 = int(np.flatnonzero([(seq.codes[t:t + 4] == codes[b].numpy()).all() for t in range(3)])[0])
        assert np.array_equal(actions[b].numpy(), seq.actions[t0:t0 + 3])
    _, dropped, none = sample_windows(seqs, 4, 50, torch.Generator().manual_seed(0), text_dropout=0.5)
    assert none is None and 10 < dropped.count("") < 40
    with pytest.raises(ValueError, match="2 latent frames"):
        window_length([CodeSequence("one", np.zeros((1, 4, 4), np.int64), "")], 4)
    with pytest.raises(ValueError, match="no actions"):
        sample_windows(_sequences(1), 4, 1, torch.Generator(), True)


def test_training_is_seeded_and_learns():
    config = WorldTrainConfig(steps=40, batch_size=4, lr=3e-3, warmup_steps=5, threads=1, log_every=10)
    a, b = _model(), _model()
    history = train_world_model(a, _sequences(), config)
    train_world_model(b, _sequences(), config)
    assert all(torch.equal(p, q) for p, q in zip(a.state_dict().values(), b.state_dict().values()))
    c = _model()  # the same initial weights, another seed: other minibatches, other weights
    train_world_model(c, _sequences(), config.model_copy(update={"seed": config.seed + 1}))
    assert not all(torch.equal(p, q) for p, q in zip(a.state_dict().values(), c.state_dict().values()))
    assert [h["step"] for h in history] == [10, 20, 30, 40]
    assert history[-1]["loss"] < 0.5 * np.log(K) and history[-1]["accuracy"] > history[0]["accuracy"]
    assert history[-1]["copy_accuracy"] == 0.0  # every frame differs from the last: copying never works
    budget = train_world_model(_model(), _sequences(), config.model_copy(update={"seconds": 1e-6}))
    assert [h["step"] for h in budget] == [1]  # a budget ends training (and is logged)


def test_own_inputs_are_the_models_rollout_from_the_first_frame():
    model = post_trainable(_model(), None)
    torch.nn.init.normal_(model.action_encoder.net[-1].weight, std=0.5)  # actions must matter
    codes, texts, actions = sample_windows(_sequences(4, 6, with_actions=True), 4, 6,
                                           torch.Generator().manual_seed(0), True)
    everything = own_inputs(model, codes, texts, actions, 1.0, torch.Generator().manual_seed(1))
    rolled = model.rollout(codes[:, :1], 3, texts, actions)
    assert torch.equal(everything[:, 0], codes[:, 0]) and torch.equal(everything[:, 1:], rolled)
    assert not torch.equal(everything, codes)  # an untrained model's frames are not the truth
    assert own_inputs(model, codes, texts, actions, 0.0, torch.Generator()) is codes
    some = own_inputs(model, codes, texts, actions, 0.5, torch.Generator().manual_seed(1))
    picked = (torch.rand(6, generator=torch.Generator().manual_seed(1)) < 0.5).tolist()
    assert any(picked) and not all(picked)  # the draw the trainer makes: a mixed batch
    for b in range(6):
        assert torch.equal(some[b], everything[b] if picked[b] else codes[b])
    assert model.training  # left as it was found
    model.eval()
    own_inputs(model, codes, texts, actions, 1.0, torch.Generator())
    assert not model.training


def test_self_conditioned_training_learns():
    config = WorldTrainConfig(steps=40, batch_size=4, lr=3e-3, warmup_steps=5, threads=1, log_every=10,
                              self_condition=0.5)
    history = train_world_model(_model(), _sequences(), config)
    assert history[-1]["loss"] < 0.5 * np.log(K) and history[-1]["accuracy"] > history[0]["accuracy"]


def test_teacher_forced_scores_show_a_model_that_learnt_its_sequences():
    seqs = _sequences()
    rng = np.random.default_rng(1)
    noise = [CodeSequence(key=f"n{i}", codes=rng.integers(0, K, (6, 4, 4)), text=f"clip {i}") for i in range(3)]
    model = _model()
    before = teacher_forced(model, seqs, 4)
    assert before["windows"] == 3 * 2  # windows at 0 and 2 of each 6-frame sequence
    train_world_model(model, seqs, WorldTrainConfig(steps=60, batch_size=4, lr=3e-3, warmup_steps=5, threads=1))
    learnt, other = teacher_forced(model, seqs, 4, stride=1), teacher_forced(model, noise, 4, stride=1)
    assert learnt["windows"] == other["windows"] == 9 and not model.training
    assert learnt["loss"] < 0.5 * before["loss"] and learnt["loss"] < 0.5 * other["loss"]
    # every code moves by one in these sequences: copying the last frame would score 0
    assert learnt["changed_accuracy"] == learnt["accuracy"] > 0.9 > other["changed_accuracy"]
    with pytest.raises(ValueError, match="no sequence has 8 latent frames"):
        teacher_forced(model, seqs, 8)


def test_posttraining_starts_from_the_pretrained_model_and_round_trips(tmp_path):
    config = WorldTrainConfig(steps=3, batch_size=2, threads=1, log_every=1)
    pre = _model()
    train_world_model(pre, _sequences(), config)
    episodes = _sequences(2, with_actions=True)
    codes = torch.from_numpy(episodes[0].codes[:4])[None]
    acts = torch.from_numpy(episodes[0].actions[:3])[None]
    with torch.no_grad():
        before = next_frame_loss(pre(codes, ["clip 0"]), codes).item()
    post, history = posttrain(pre, episodes, config.model_copy(update={"steps": 1, "lr": 1e-12, "warmup_steps": 0}))
    with torch.no_grad():
        after = next_frame_loss(post(codes, ["clip 0"], acts), codes).item()
    assert post.config.action_conditioned and pre.action_encoder is None and len(history) == 1
    assert abs(after - before) < 1e-4  # a step at a negligible rate: still the pre-trained model

    for model in (pre, post):
        folder = tmp_path / model.config.name / str(model.config.action_conditioned)
        weights, config_file = checkpoints.save_checkpoint(model, folder, {"phase": "x"})
        loaded = checkpoints.load_checkpoint(folder)
        assert loaded.config == model.config and checkpoints.read_config(folder)["phase"] == "x"
        args = (codes, ["clip 0"], acts if model.config.action_conditioned else None)
        with torch.no_grad():
            assert torch.equal(loaded(*args), model(*args))
    batch = checkpoints.checkpoint_lineage("ckpt", folder, tmp_path, [("ep", "trained_on"), ("pre", "posttrained_from"),
                                                                      ("ep", "trained_on")],
                                           history, "sr", None, {"model": "world_model", "phase": "posttrain"})
    assert batch.artifacts[0].uri == f"{post.config.name}/True/model.safetensors"
    assert batch.artifacts[0].attrs["config_uri"].endswith("config.json")
    assert [(e.parent_id, e.relation) for e in batch.edges] == [("ep", "trained_on"), ("pre", "posttrained_from")]
    assert sorted(m.name for m in batch.metrics) == ["train_accuracy", "train_loss"]


def _pushed(n, frames, seed):
    """Episodes whose every code moves by +1 or -1 each latent step as the action says, with
    end-effector-sized actions (3 mm a step, as the push controller's), a noisy second value
    and a gripper value held at 1."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        codes, actions = [rng.integers(0, K, (4, 4))], []
        for _ in range(frames - 1):
            d = int(rng.choice([-1, 1]))
            a = np.zeros((4, 8), np.float32)
            a[:, 0], a[:, 1], a[:, 4] = 0.003 * d + rng.normal(0, 5e-4, 4), rng.normal(0, 2e-3, 4), 1.0
            actions.append(a.reshape(-1))
            codes.append((codes[-1] + d) % K)
        out.append(CodeSequence(key=f"e{i}", codes=np.stack(codes).astype(np.int64), text="push", actions=np.stack(actions)))
    return out


def _accuracy(model, episodes, flip=False):
    hits = []
    with torch.no_grad():
        for e in episodes:
            codes, acts = torch.from_numpy(e.codes[:4])[None], torch.from_numpy(e.actions[:3])[None].clone()
            if flip:
                acts[..., 0::8] *= -1
            hits.append((model(codes, [e.text], acts)[:, :-1].argmax(-1) == codes[:, 1:]).float().mean().item())
    return float(np.mean(hits))


def test_posttraining_learns_millimetre_actions():
    """Post-training divides each action value by its RMS over the episodes; without that, the
    3 mm steps vanish under the encoder's initial weights and the model stays at chance."""
    config = WorldTrainConfig(steps=60, batch_size=8, lr=3e-3, warmup_steps=5, threads=1, log_every=30)
    train, test = _pushed(8, 12, 0), _pushed(4, 4, 1)
    pre = _model()
    post, _ = posttrain(pre, train, config)
    assert post.config.action_scale[0] == pytest.approx(0.003, rel=0.1) and post.config.action_scale[4] == 1.0
    assert _accuracy(post, test) > 0.9 and _accuracy(post, test, flip=True) < 0.1
    torch.manual_seed(config.seed)
    unscaled = post_trainable(pre)
    train_world_model(unscaled, train, config)
    assert _accuracy(unscaled, test) < 0.7


def test_posttraining_records_action_totals():
    """The layout the episodes were aligned with travels in the checkpoint's config, so a rollout
    aligns its actions the same way."""
    config = WorldTrainConfig(steps=1, batch_size=2, threads=1, action_totals=3)
    post, _ = posttrain(_model(), _pushed(2, 4, 0), config)
    assert post.config.action_totals == 3 and post.config.action_conditioned
    plain, _ = posttrain(_model(), _pushed(2, 4, 0), config.model_copy(update={"action_totals": 0}))
    assert plain.config.action_totals == 0


def test_a_compiled_model_is_not_recompiled_for_every_caption(monkeypatch):
    """Captions differ per clip and episode; a compiled model fed the strings guards on each value
    and recompiles (seen on a GPU: the recompile limit hit within a few steps). Word ids go in."""
    from tasks.device import Runtime

    compiled, real = [], torch.compile

    def counting(model, **_):
        def backend(graph, example_inputs):
            compiled.append(graph)
            return graph.forward
        return real(model, backend=backend)

    monkeypatch.setattr(torch, "compile", counting)
    torch._dynamo.reset()
    sequences = [CodeSequence(key=f"s{i}", codes=s.codes, text=f"a clip with caption number {i}")
                 for i, s in enumerate(_sequences(n=6))]
    config = WorldTrainConfig(steps=6, batch_size=1, text_dropout=0.0, threads=1)
    train_world_model(_model(), sequences, config, runtime=Runtime(device="cpu", compile=True))
    torch._dynamo.reset()
    assert 1 <= len(compiled) <= 2, f"{len(compiled)} graphs compiled for 6 captions"

"""Latent sequences for the diffusion world model: continuous token shards decoded as the
tokenizer's own decode_row decodes them, episodes encoded with a continuous tokenizer (and cached
beside the codes cache), and the discrete inputs refused."""

import numpy as np
import pytest
import torch

from models.tokenizer import VideoTokenizer
from models.tokenizer import preset as tokenizer_preset
from schemas import paths
from tasks.tokenize import tokens
from tasks.tokenize.data import Clip
from tasks.tokenize.train import to_tensor
from tasks.world import data, latents
from tasks.world.diffusion import LatentSequence
from tests.support import scene_frames
from tests.tasks.world.test_data import episode  # noqa: F401  (the hand-made episode folder)

torch.set_num_threads(1)


def _continuous(seed: int = 0) -> VideoTokenizer:
    torch.manual_seed(seed)
    return VideoTokenizer(tokenizer_preset("tiny-cv4x8x8")).eval()


def test_continuous_token_shards_load_as_the_tokenizer_decodes_them(tmp_path):
    tokenizer = _continuous()
    frames = np.stack(scene_frames(3, 32, 32, 9))
    rows = [tokens.encode_clip(tokenizer, Clip(clip_id=f"c{i}", shard_uri="shards/gone.parquet",
                                              frames=np.ascontiguousarray(frames[:, :, ::-1]) if i else frames))
            for i in range(2)]
    target, _ = tokens.token_shard_path(tmp_path, "c" * 24, 0)
    tokens.write_token_shard(rows, target)
    seqs = latents.load_latent_sequences([target.parent], tmp_path)
    assert [type(s) for s in seqs] == [LatentSequence] * 2 and [s.key for s in seqs] == ["c0", "c1"]
    c = tokenizer.config.latent_channels
    assert seqs[0].latents.shape == (3, c, 4, 4) and seqs[0].latents.dtype == np.float32  # T' x C x H' x W'
    assert seqs[0].text == "" and seqs[0].info["size"] == 32 and seqs[0].actions is None
    for seq, row in zip(seqs, tokens.read_token_shard(target).to_pylist()):
        # decode_row's own latents (1 x C x T' x H' x W'), frames first here
        raw = np.frombuffer(row["latents"], dtype=np.uint8).reshape(row["channels"], *row["grid"])
        expected = (raw.astype(np.float32) / 127.5 - 1).transpose(1, 0, 2, 3)
        assert np.array_equal(seq.latents, expected)
        with torch.no_grad():
            via_model = tokenizer.decode(torch.from_numpy(seq.latents).transpose(0, 1)[None])
        assert torch.equal(via_model, tokens.decode_row(tokenizer, row))
    # 8-bit storage: within a quantisation step of the tokenizer's own latents
    with torch.no_grad():
        own = tokenizer.encode(to_tensor(frames)[None])[0]
    assert np.abs(seqs[0].latents - own.transpose(0, 1).numpy()).max() <= 1 / 127.5 + 1e-6

    discrete = VideoTokenizer(tokenizer_preset("tiny-dv4x8x8")).eval()
    tokens.write_token_shard([tokens.encode_clip(discrete, Clip(clip_id="d", shard_uri="s", frames=frames))], target)
    with pytest.raises(ValueError, match="discrete codes; the diffusion world model needs a continuous"):
        latents.load_latent_sequences([target], tmp_path)


def test_episodes_encode_to_latents_with_actions_and_a_cache_of_their_own(episode, tmp_path,  # noqa: F811
                                                                         monkeypatch):
    tokenizer = _continuous()
    seq = latents.load_latent_episode(episode, "overhead", tokenizer, 32, tokenizer_id="t" * 24, cache_root=tmp_path)
    assert seq.latents.shape == (5, tokenizer.config.latent_channels, 4, 4) and seq.latents.dtype == np.float32
    assert seq.actions.shape == (4, 4 * 8) and seq.text == "push; stressors: distractors, occluder"
    assert seq.key == "episode_000000/overhead" and seq.info["frames"] == 17 and seq.info["seed"] == 5
    codes = data.load_episode(episode, "overhead", VideoTokenizer(tokenizer_preset("tiny-dv4x8x8")).eval(), 32)
    assert np.array_equal(seq.actions, codes.actions)  # the same alignment as the codes'
    (cached,) = (tmp_path / "cache").rglob("*.npz")
    assert cached.parent == (tmp_path / paths.EPISODE_LATENTS_FILE.format(
        tokenizer_id="t" * 24, video_sha256="0" * 64, size=32)).parent
    assert "episode_latents" in cached.as_posix()

    def no_encoding(*args, **kwargs):
        raise AssertionError("a cached video was encoded again")

    monkeypatch.setattr(latents, "encode_latents", no_encoding)
    again = latents.load_latent_episodes([episode], tokenizer, 32, tokenizer_id="t" * 24, cache_root=tmp_path)
    assert len(again) == 1 and np.array_equal(again[0].latents, seq.latents)
    monkeypatch.undo()
    with pytest.raises(ValueError, match="needs a continuous tokenizer"):
        latents.load_latent_episode(episode, "overhead", VideoTokenizer(tokenizer_preset("tiny-dv4x8x8")), 32)

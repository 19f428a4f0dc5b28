"""World model data: actions aligned to latent steps, episodes encoded (and cached), token shards with captions."""

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch

from models.tokenizer import VideoTokenizer
from models.tokenizer import preset as tokenizer_preset
from schemas import paths
from schemas.errors import TamperedArtifact
from tasks.curate.shards import SHARD_SCHEMA
from tasks.tokenize import tokens
from tasks.world import data
from tasks.world.data import align_actions
from tasks.video import write_mp4
from tests.support import scene_frames

torch.set_num_threads(1)


def test_align_actions_by_timestamps():
    """50 Hz control, 30 fps, 4 frames per latent step, 9 frames (3 latent frames).

    Step k starts at k/50 s and leads into the first frame rendered after it (frame f at f/30 s):
    k: 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14
    f: 1 1 2 2 3 4 4 5 5 6  7  7  8  8  9   (step 5 starts at 0.1 s, when frame 3 is rendered: frame 4)
    Transition 0 covers frames 1-4, transition 1 frames 5-8; frame 9 is not covered.
    """
    k = np.arange(15)
    action = np.stack([k, -k], axis=1).astype(float)  # 2 values per step, padded to 3
    out = align_actions(k / 50.0, action, np.arange(9) / 30.0, 4, 3, 3)
    assert out.shape == (2, 12) and out.dtype == np.float32
    expected = {  # (transition, slot) -> steps averaged
        (0, 0): [0, 1], (0, 1): [2, 3], (0, 2): [4], (0, 3): [5, 6],
        (1, 0): [7, 8], (1, 1): [9], (1, 2): [10, 11], (1, 3): [12, 13],
    }
    for (j, s), steps in expected.items():
        m = float(np.mean(steps))
        assert out[j, 3 * s:3 * s + 3].tolist() == [m, -m, 0.0], (j, s)


def test_align_actions_leaves_uncovered_slots_zero_and_checks_sizes():
    # 10 Hz control against 30 fps: only every third frame has a step leading into it.
    out = align_actions(np.arange(3) / 10.0, np.ones((3, 1)), np.arange(9) / 30.0, 4, 3, 2)
    # steps at 0, 0.1, 0.2 s lead into frames 1, 4, 7.
    assert out[:, ::2].tolist() == [[1, 0, 0, 1], [0, 0, 1, 0]] and not out[:, 1::2].any()
    assert align_actions(np.arange(3) / 10.0, np.ones((3, 1)), np.arange(1) / 30.0, 4, 1, 2).shape == (0, 8)
    with pytest.raises(ValueError, match="at most"):
        align_actions(np.arange(3) / 10.0, np.ones((3, 4)), np.arange(9) / 30.0, 4, 3, 2)
    with pytest.raises(ValueError, match="does not match"):
        align_actions(np.arange(3) / 10.0, np.ones((2, 1)), np.arange(9) / 30.0, 4, 3, 2)


def test_episode_text():
    assert data.episode_text("push the box", ["occluder", "dim_light", "occluder"]) == \
        "push the box; stressors: dim_light, occluder"
    assert data.episode_text("push the box", []) == "push the box"


@pytest.fixture(scope="module")
def episode(tmp_path_factory):
    """A hand-made episode folder as `worldline simulate` writes it: 19 frames at 30 fps of one
    camera, 32 control steps at 50 Hz with 3 action values, meta.json."""
    folder = tmp_path_factory.mktemp("episodes") / "episode_000000"
    write_mp4(folder / "overhead.mp4", scene_frames(1, 48, 40, 19), 30)
    k = np.arange(32)
    table = pa.table({"step": pa.array(k), "time": pa.array(k / 50.0),
                      "action": pa.array([[float(i), 1.0, -1.0] for i in k], pa.list_(pa.float64()))})
    pq.write_table(table, folder / "steps.parquet")
    (folder / "meta.json").write_text(json.dumps({"manifest_hash": "ab" * 32, "index": 0, "seed": 5, "success": True,
                                                  "reason": "package at goal", "steps": 32, "control_hz": 50.0,
                                                  "stressors": {"occluder": {}, "distractors": {}},
                                                  "cameras": ["overhead"], "task": "push"}))
    return folder


def test_load_episode_encodes_aligns_and_caches(episode, tmp_path, monkeypatch):
    torch.manual_seed(0)
    tokenizer = VideoTokenizer(tokenizer_preset("tiny-dv4x8x8")).eval()
    assert data.episode_dirs(episode.parent) == [episode] and data.episode_dirs(episode) == [episode]
    seq = data.load_episode(episode, "overhead", tokenizer, 32, tokenizer_id="t" * 24, cache_root=tmp_path)
    assert seq.codes.shape == (5, 4, 4) and seq.codes.dtype == np.int64  # 19 frames -> 17 used -> 5 latent
    assert ((seq.codes >= 0) & (seq.codes < 1000)).all()
    assert seq.actions.shape == (4, 4 * 8) and seq.text == "push; stressors: distractors, occluder"
    assert seq.info["frames"] == 17 and seq.info["fps"] == 30.0 and seq.info["seed"] == 5
    # Slot 0 of transition 0 (frame 1): steps 0 and 1 -> mean action [0.5, 1, -1], padded to 8.
    assert seq.actions[0, :8].tolist() == [0.5, 1.0, -1.0, 0, 0, 0, 0, 0]
    (cached,) = (tmp_path / "cache").rglob("*.npz")
    assert cached.parent == (tmp_path / paths.EPISODE_CODES_FILE.format(
        tokenizer_id="t" * 24, video_sha256="0" * 64, size=32)).parent
    def no_encoding(*args, **kwargs):
        raise AssertionError("a cached video was encoded again")

    monkeypatch.setattr(data, "encode_frames", no_encoding)
    again = data.load_episode(episode, "overhead", tokenizer, 32, text="lift", tokenizer_id="t" * 24,
                              cache_root=tmp_path)
    assert np.array_equal(again.codes, seq.codes) and again.text == "lift"
    monkeypatch.undo()
    assert len(data.load_episodes([episode], tokenizer, 32)) == 1
    with pytest.raises(FileNotFoundError, match="no camera 'wrist'"):
        data.load_episode(episode, "wrist", tokenizer, 32)
    (episode / "overhead.mp4").unlink()  # a camera the episode was recorded with, deleted since
    with pytest.raises(TamperedArtifact, match=r"overhead\.mp4: missing, though the episode was recorded with it"):
        data.load_episode(episode, "overhead", tokenizer, 32)


def test_load_token_sequences_with_captions(tmp_path):
    shard_rel = "shards/abc/lt240p/2-5s/part-00000.parquet"
    (tmp_path / shard_rel).parent.mkdir(parents=True)
    base = {name: None for name in SHARD_SCHEMA.names} | {
        "source_id": "s", "source_uri": "v.mp4", "start_frame": 0, "end_frame": 9, "start_s": 0.0, "end_s": 0.3,
        "fps": 30.0, "width": 32, "height": 32, "duration_s": 0.3, "scores": [], "tags": []}
    pq.write_table(pa.Table.from_pylist([base | {"clip_id": "c1", "caption": "A push clip."}], schema=SHARD_SCHEMA),
                   tmp_path / shard_rel)
    rows = [{"clip_id": cid, "source_shard": src, "variant": "discrete", "frames": 9, "size": 32, "grid": [3, 4, 4],
             "channels": 4, "codebook_size": 1000, "codes": list(range(i, i + 48)), "latents": None}
            for i, (cid, src) in enumerate([("c1", shard_rel), ("c2", "shards/gone.parquet")])]
    target, _ = tokens.token_shard_path(tmp_path, "f" * 24, 0)
    tokens.write_token_shard(rows, target)
    seqs = data.load_token_sequences([target.parent], tmp_path)
    assert [(s.key, s.text, s.codes.shape) for s in seqs] == [("c1", "A push clip.", (3, 4, 4)), ("c2", "", (3, 4, 4))]
    assert seqs[1].codes[0, 0].tolist() == [1, 2, 3, 4] and seqs[0].actions is None
    continuous = rows[0] | {"variant": "continuous", "codes": None, "latents": b"\0" * 48, "codebook_size": None}
    tokens.write_token_shard([continuous], target)
    with pytest.raises(ValueError, match="discrete"):
        data.load_token_sequences([target], tmp_path)


def test_align_actions_totals_hold_the_running_sum_since_the_start():
    """With totals, each slot also holds the running sum of the first values over every step up to
    its frame (the commanded hand's offset), also where no step leads into the slot itself."""
    k = np.arange(3)
    action = np.stack([k + 1.0, 10 * (k + 1.0)], axis=1)  # steps at 0, 0.1, 0.2 s lead into frames 1, 4, 7
    out = align_actions(k / 10.0, action, np.arange(9) / 30.0, 4, 3, 4, totals=1).reshape(2, 4, 4)
    assert out[..., 2].tolist() == [[1, 1, 1, 3], [3, 3, 6, 6]]
    assert out[..., :2].reshape(-1, 2).tolist() == align_actions(
        k / 10.0, action, np.arange(9) / 30.0, 4, 3, 4).reshape(2, 4, 4)[..., :2].reshape(-1, 2).tolist()
    assert not out[..., 3].any()
    with pytest.raises(ValueError, match=r"\+ 2 totals"):
        align_actions(k / 10.0, action, np.arange(9) / 30.0, 4, 3, 3, totals=2)
    with pytest.raises(ValueError, match="totals 3"):
        align_actions(k / 10.0, action, np.arange(9) / 30.0, 4, 3, 8, totals=3)

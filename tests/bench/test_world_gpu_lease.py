"""bench/world_gpu_lease.sh on the CPU: variants trained from a packed bundle come back as tar files
that hold loadable checkpoints, and a variant's own post_steps wins over the time cap."""

import io
import json
import os
import subprocess
import sys
import tarfile

import numpy as np
import torch

from tasks.world import checkpoints
from tests.support import REPO

K, T = 32, 4  # codebook, temporal compression


def _bundle(path):
    rng = np.random.default_rng(0)

    def row(key, frames, actions):
        codes = torch.from_numpy(rng.integers(0, K, (frames, 4, 4)).astype(np.int16))
        acts = torch.from_numpy(rng.normal(0, 1e-3, (frames - 1, T * 8)).astype(np.float32)) if actions else None
        return {"key": key, "codes": codes, "text": "push", "actions": acts,
                "info": {"source": 0, "index": 0, "folder": f"episodes/x/{key}"}}

    torch.save({"tokenizer_id": "tok", "tokenizer": "checkpoints/tok", "size": 16, "grid": [4, 4], "codebook_size": K,
                "temporal_compression": T, "camera": None, "action_totals": 0, "episode_folders": [],
                "pretrain": [row(f"c{i}", 6, False) for i in range(3)],
                "posttrain": [row(f"e{i}", 6, True) for i in range(3)]}, path)


def test_variants_come_back_as_loadable_checkpoints(tmp_path):
    _bundle(tmp_path / "bundle.pt")
    env = {**os.environ, "PYTHON": sys.executable, "DEVICE": "cpu", "BUNDLE": str(tmp_path / "bundle.pt"),
           "OUT": str(tmp_path / "out"), "WORK": str(tmp_path / "work"), "SECONDS_CAP": "600", "OMP_NUM_THREADS": "1"}
    run = subprocess.run(["bash", "bench/world_gpu_lease.sh", "name=a preset=tiny-wm pre_steps=2 post_steps=3",
                          "name=b preset=tiny-wm pre_steps=2 post_steps=2 window=3"],
                         cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    for name, steps, window in (("a", 3, 4), ("b", 2, 3)):
        with tarfile.open(tmp_path / "out" / f"{name}.tar") as tar:
            assert sorted(tar.getnames()) == [f"{name}/posttrain/config.json", f"{name}/posttrain/model.safetensors",
                                              f"{name}/result.json"]
            result = json.load(io.TextIOWrapper(tar.extractfile(f"{name}/result.json")))
            tar.extractall(tmp_path / "back", filter="data")
        assert result["post_steps_done"] == steps and result["spec"]["seconds"] == 600
        model = checkpoints.load_checkpoint(tmp_path / "back" / name / "posttrain")
        assert model.config.codebook_size == K and model.config.max_frames == window


def test_a_call_without_variants_is_refused():
    run = subprocess.run(["bash", "bench/world_gpu_lease.sh"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "usage" in run.stderr


def test_a_failed_training_fails_the_call_and_returns_nothing(tmp_path):
    _bundle(tmp_path / "bundle.pt")
    env = {**os.environ, "PYTHON": sys.executable, "DEVICE": "cpu", "BUNDLE": str(tmp_path / "bundle.pt"),
           "OUT": str(tmp_path / "out"), "WORK": str(tmp_path / "work"), "OMP_NUM_THREADS": "1"}
    run = subprocess.run(["bash", "bench/world_gpu_lease.sh", "name=a preset=tiny-wm bogus=1"], cwd=REPO, env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode != 0 and "unknown key 'bogus'" in run.stdout + run.stderr
    assert "a: not finished" in run.stderr and not (tmp_path / "out" / "a.tar").exists()

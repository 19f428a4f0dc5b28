"""bench/world_gpu.py train: a variant with ``init`` goes on post-training a checkpoint, keeping
its architecture and action scale, and refuses a bundle packed with another tokenizer."""

import json
import subprocess
import sys

import torch

from tasks.world import checkpoints
from tests.bench.test_world_gpu_lease import _bundle
from tests.support import REPO


def _train(bundle, out, spec):
    return subprocess.run([sys.executable, "bench/world_gpu.py", "train", str(bundle), "--out", str(out),
                           "--device", "cpu", "--threads", "1", "--variant", spec],
                          cwd=REPO, capture_output=True, text=True, timeout=600)


def test_a_variant_goes_on_training_a_checkpoint(tmp_path):
    _bundle(tmp_path / "bundle.pt")
    first = _train(tmp_path / "bundle.pt", tmp_path / "out", "name=a preset=tiny-wm pre_steps=2 post_steps=3")
    assert first.returncode == 0, first.stderr[-2000:]
    start = tmp_path / "out" / "a" / "posttrain"
    more = _train(tmp_path / "bundle.pt", tmp_path / "out", f"name=b init={start} post_steps=2 lr=1e-4")
    assert more.returncode == 0, more.stderr[-2000:]
    folder = tmp_path / "out" / "b" / "posttrain"
    config = checkpoints.read_config(folder)
    assert config["continued_from"] == str(start) and config["train"]["lr"] == 1e-4 and config["checkpoint_id"] == "b"
    a, b = checkpoints.load_checkpoint(start), checkpoints.load_checkpoint(folder)
    assert a.config == b.config  # the same architecture and action scale
    assert not all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values()))
    assert json.loads((tmp_path / "out" / "b" / "result.json").read_text())["post_steps_done"] == 2

    other = tmp_path / "other.pt"
    bundle = torch.load(tmp_path / "bundle.pt", weights_only=True)
    torch.save({**bundle, "tokenizer_id": "another"}, other)
    refused = _train(other, tmp_path / "out2", f"name=c init={start} post_steps=2")
    assert refused.returncode != 0 and "tokenizer tok, the bundle's is another" in refused.stderr

"""Where models run: device choice, checkpoints that load anywhere, the same results on the CPU."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from models.tokenizer import VideoTokenizer, preset
from models.world_model import WorldModel, WorldModelConfig
from tasks.checkpoint_files import load_weights, write_checkpoint
from tasks.device import DeviceError, Runtime, cpu_state, prepare, resolve
from tasks.tokenize.train import TrainConfig, train_tokenizer

GPU = torch.cuda.is_available()


def clips(n: int = 3, t: int = 9, size: int = 32) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (size + 8, size + 8, 3), dtype=np.uint8)
    return [np.stack([np.roll(base, k + j, axis=1)[:size, :size] for j in range(t)]) for k in range(n)]


def test_device_names_are_checked_and_cuda_without_a_gpu_says_so(monkeypatch):
    assert resolve("cpu") == torch.device("cpu")
    assert resolve("auto").type == ("cuda" if GPU else "cpu")
    with pytest.raises(ValueError, match="expected auto, cpu, cuda or cuda:N"):
        Runtime(device="tpu")
    monkeypatch.setenv("WORLDLINE_DEVICE", "cpu")
    assert Runtime().device == "cpu"
    if not GPU:
        with pytest.raises(DeviceError, match="no CUDA GPU is visible"):
            resolve("cuda")
        with pytest.raises(DeviceError, match="bf16 runs only on a CUDA device"):
            prepare(torch.nn.Linear(2, 2), Runtime(device="cpu", precision="bf16"))


def test_the_runtime_never_changes_what_is_computed_on_the_cpu():
    # Passing an explicit CPU runtime trains the very same weights as before it existed.
    config = TrainConfig(preset="tiny-dv4x8x8", steps=3, batch_size=2, size=32, log_every=1, threads=1)
    runs = []
    for runtime in (None, Runtime(device="cpu", tf32=True)):
        torch.manual_seed(0)
        model = VideoTokenizer(preset("tiny-dv4x8x8"))
        history = train_tokenizer(model, clips(), config, runtime=runtime)
        runs.append((history[-1]["loss"], cpu_state(model)))
    assert runs[0][0] == runs[1][0]
    assert all(torch.equal(runs[0][1][k], runs[1][1][k]) for k in runs[0][1])


def test_inputs_on_any_device_come_back_on_theirs(tmp_path):
    model = VideoTokenizer(preset("tiny-dv4x8x8")).eval()
    x = torch.zeros(1, 3, 5, 32, 32)
    codes = model.encode(x)
    assert codes.device == x.device and model.decode(codes).device == x.device
    wm = WorldModel(WorldModelConfig(name="t", width=32, layers=1, heads=2, codebook_size=64, max_frames=4)).eval()
    out = wm.rollout(torch.zeros(1, 1, 4, 4, dtype=torch.long), 2)
    assert out.shape == (1, 2, 4, 4) and out.device == torch.device("cpu")


def test_checkpoints_are_written_from_cpu_copies(tmp_path):
    model = VideoTokenizer(preset("tiny-dv4x8x8"))
    write_checkpoint(model, tmp_path, "tokenizer")
    loaded = load_weights(VideoTokenizer(preset("tiny-dv4x8x8")), tmp_path)
    assert all(p.device.type == "cpu" for p in loaded.parameters())


@pytest.mark.skipif(not GPU, reason="no CUDA GPU on this machine (CI never has one)")
def test_a_checkpoint_trained_on_the_gpu_loads_and_runs_on_the_cpu(tmp_path):
    config = TrainConfig(preset="tiny-dv4x8x8", steps=2, batch_size=2, size=32, log_every=1)
    model = VideoTokenizer(preset("tiny-dv4x8x8"))
    train_tokenizer(model, clips(), config, runtime=Runtime(device="cuda"))
    assert next(model.parameters()).device.type == "cuda"
    write_checkpoint(model, tmp_path, "tokenizer")
    cpu = load_weights(VideoTokenizer(preset("tiny-dv4x8x8")), tmp_path)
    x = torch.from_numpy(clips(1)[0][:5]).float().div(127.5).sub(1).movedim(-1, 0)[None]
    on_gpu = model.eval().decode(model.encode(x))
    assert torch.allclose(cpu.decode(cpu.encode(x)), on_gpu, atol=1e-3)

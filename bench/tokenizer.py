"""Rate-distortion of the video tokenizers against H.264 on held-out simulator clips.

    .venv/bin/python bench/tokenizer.py [--budget-min 30] [--variants small-dv4x8x8,small-cv4x8x8]
        [--device auto|cpu|cuda] [--compile] [--precision bf16] [--tf32]

Renders a manifest's episodes (--manifest, default ``mobile_rig_aisle``; every camera) with MuJoCo (training seeds manifest.seed + i, held-out
seeds 1000 + i), downscales them to --size, trains each variant for --budget-min minutes of
training time (evaluation pauses the clock) and prints, per variant and per x264 CRF: bits per
pixel, PSNR and SSIM on the held-out clips (--clip-frames frames each), H.264's PSNR and SSIM
interpolated (linearly in log bpp) to each variant's bpp, PSNR against training time, and
encode / decode frames per second. Bits: discrete = latent tokens x log2(codebook size);
continuous = latent values x 8 bits (latents are stored as 8-bit and decoded from that);
H.264 (4:2:0 as usual, and 4:4:4, since chroma subsampling alone
costs these colourful 64x64 frames about 29 dB) = the whole Annex-B stream (SPS, PPS and x264's option SEI included), and, for
reference, its slice NAL units alone. Frames are rendered once and cached under --out.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from models.tokenizer import VideoTokenizer, preset  # noqa: E402
from tasks.device import Runtime  # noqa: E402
from tasks.tokenize.train import TrainConfig, to_tensor, train_tokenizer  # noqa: E402

MANIFEST = Path(__file__).resolve().parents[1] / "manifests" / "mobile_rig_aisle.yaml"
CRFS = (10, 16, 20, 24, 28, 32, 36, 40, 44, 48, 51)


def render(out: Path, train: int, heldout: int, size: int, manifest_path: Path = MANIFEST
           ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Every camera of ``train`` episodes (seeds manifest.seed + i) and ``heldout`` ones (seeds 1000 + i)."""
    cache = out / f"sim_frames_{manifest_path.stem}_{train}_{heldout}_{size}.npz"
    if cache.exists():
        data = np.load(cache)
        return ([data[k] for k in data.files if k.startswith("train_")],
                [data[k] for k in data.files if k.startswith("heldout_")])
    from tasks import manifests
    from tasks.sim.episode import rollout

    manifest = manifests.load(manifest_path)
    arrays = {}
    for name, seeds in (("train", [manifest.seed + i for i in range(train)]),
                        ("heldout", [1000 + i for i in range(heldout)])):
        for i, seed in enumerate(seeds):
            t0 = time.perf_counter()
            for camera, frames in sorted(rollout(manifest, seed).frames.items()):
                arrays[f"{name}_{i:04d}_{camera}"] = resize(frames, size)
            print(f"rendered {name} seed {seed}: {frames.shape} in {time.perf_counter() - t0:.1f}s", flush=True)
    out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(cache, **arrays)
    return render(out, train, heldout, size, manifest_path)


def resize(frames: np.ndarray, size: int) -> np.ndarray:
    x = torch.from_numpy(frames).permute(0, 3, 1, 2).float()
    y = F.interpolate(x, size=(size, size), mode="area")
    return y.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).numpy()


def windows(episodes: list[np.ndarray], frames: int) -> np.ndarray:
    """Non-overlapping windows of each held-out episode: N x T x H x W x 3 uint8."""
    return np.stack([e[s:s + frames] for e in episodes for s in range(0, e.shape[0] - frames + 1, frames)])


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean SSIM (Wang et al. 2004: 11x11 Gaussian, sigma 1.5) over frames and RGB channels of uint8 arrays."""
    from tasks.world.physics import ssim_frames

    return float(ssim_frames(a.reshape(-1, *a.shape[-3:]), b.reshape(-1, *b.shape[-3:])).mean())


def psnr_u8(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over clips of per-clip PSNR; a, b: N x T x H x W x 3 uint8."""
    mse = ((a.astype(np.float64) - b.astype(np.float64)) ** 2).reshape(len(a), -1).mean(1)
    return float(np.mean(10 * np.log10(255.0 ** 2 / np.maximum(mse, 1e-10))))


# --- H.264 --------------------------------------------------------------------------------

def _nal_split(data: bytes) -> list[bytes]:
    starts = []
    i = data.find(b"\x00\x00\x01")
    while i >= 0:
        starts.append(i + 3)
        i = data.find(b"\x00\x00\x01", i + 3)
    return [data[s:(e - 3 if e else None)] for s, e in zip(starts, starts[1:] + [None])]


def h264_roundtrip(clip: np.ndarray, crf: int, pix_fmt: str = "yuv420p") -> tuple[np.ndarray, int, int]:
    """(decoded frames, whole stream bytes, slice-only bytes) for one clip, x264 preset medium."""
    import av

    buf = io.BytesIO()
    with av.open(buf, "w", format="h264") as out:
        stream = out.add_stream("libx264", rate=30)
        stream.height, stream.width = clip.shape[1:3]
        stream.pix_fmt = pix_fmt
        stream.options = {"crf": str(crf), "preset": "medium", "threads": "1"}
        for image in clip:
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24")):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    data = buf.getvalue()
    slices = sum(len(n) + 3 for n in _nal_split(data) if n and (n[0] & 0x1F) in (1, 5))
    with av.open(io.BytesIO(data), "r", format="h264") as inp:
        frames = np.stack([f.to_ndarray(format="rgb24") for f in inp.decode(video=0)])
    return frames, len(data), slices


def h264_curve(clips: np.ndarray, pix_fmt: str) -> list[dict]:
    pixels = clips.shape[0] * clips.shape[1] * clips.shape[2] * clips.shape[3]
    rows = []
    for crf in CRFS:
        decoded, whole, slices = [], 0, 0
        for clip in clips:
            frames, n, s = h264_roundtrip(clip, crf, pix_fmt)
            decoded.append(frames)
            whole, slices = whole + n, slices + s
        decoded = np.stack(decoded)
        rows.append({"pix_fmt": pix_fmt, "crf": crf, "bpp": 8 * whole / pixels, "bpp_slices": 8 * slices / pixels,
                     "psnr": psnr_u8(clips, decoded), "ssim": ssim(clips, decoded)})
    return rows


def interpolate(rows: list[dict], bpp: float, key: str, bpp_key: str = "bpp") -> float | None:
    """``key`` of H.264 at ``bpp``, linear in log bpp between the neighbouring CRFs; None outside the curve."""
    pts = sorted((r[bpp_key], r[key]) for r in rows)
    for (b0, v0), (b1, v1) in zip(pts, pts[1:]):
        if b0 <= bpp <= b1:
            w = 0.0 if b1 == b0 else (math.log(bpp) - math.log(b0)) / (math.log(b1) - math.log(b0))
            return v0 + w * (v1 - v0)
    return None


# --- tokenizers ---------------------------------------------------------------------------

@torch.no_grad()
def roundtrip(model: VideoTokenizer, clips: np.ndarray, batch: int = 4) -> np.ndarray:
    """Encode, store (continuous latents as 8-bit), decode: N x T x H x W x 3 uint8."""
    out = []
    for i in range(0, len(clips), batch):
        x = to_tensor(clips[i:i + batch])
        latents = model.encode(x)
        if model.config.variant == "continuous":
            latents = torch.round((latents.clamp(-1, 1) + 1) * 127.5) / 127.5 - 1
        y = model.decode(latents)
        out.append(y.clamp(-1, 1).add(1).mul(127.5).round().to(torch.uint8).movedim(1, -1).numpy())
    return np.concatenate(out)


@torch.no_grad()
def speed(model: VideoTokenizer, clips: np.ndarray, repeats: int = 3) -> tuple[float, float]:
    """Encode and decode frames per second, one clip at a time (best of ``repeats``)."""
    x = to_tensor(clips[:1])
    enc, dec = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        latents = model.encode(x)
        t1 = time.perf_counter()
        model.decode(latents)
        t2 = time.perf_counter()
        enc.append(t1 - t0)
        dec.append(t2 - t1)
    frames = x.shape[2]
    return frames / min(enc), frames / min(dec)


def run_variant(name: str, train: list[np.ndarray], heldout: np.ndarray, args) -> dict:
    config = preset(name)
    torch.manual_seed(args.seed)
    model = VideoTokenizer(config)
    params = sum(p.numel() for p in model.parameters())
    tc = TrainConfig(preset=name, steps=10 ** 9, seconds=args.budget_min * 60, batch_size=args.batch,
                     clip_frames=1 + 2 * config.temporal_compression, size=args.size, crop=args.crop, lr=args.lr,
                     warmup_steps=10,
                     seed=args.seed, threads=args.threads, log_every=10)
    probe = heldout[:: max(1, len(heldout) // 8)][:8]
    curve, next_eval = [], 0.0
    every = args.budget_min * 60 / args.curve_points

    def on_log(record: dict) -> None:
        nonlocal next_eval
        print(f"[{name}] step {record['step']} t={record['seconds']:.0f}s loss {record['loss']:.4f} "
              f"train psnr {record['psnr']:.2f} lr {record['lr']:.2e}", flush=True)
        if record["seconds"] >= next_eval:
            value = psnr_u8(probe, roundtrip(model, probe))
            curve.append((record["seconds"], record["step"], value))
            print(f"[{name}] held-out psnr {value:.2f} dB at {record['seconds'] / 60:.1f} min", flush=True)
            next_eval += every

    print(f"[{name}] {params / 1e6:.2f}M parameters, budget {args.budget_min} min", flush=True)
    history = train_tokenizer(model, train, tc, on_log, args.runtime)
    out = args.out / name
    out.mkdir(parents=True, exist_ok=True)
    from safetensors.torch import save_file
    save_file({k: v.detach().cpu() for k, v in model.state_dict().items()}, str(out / "model.safetensors"))
    (out / "config.json").write_text(config.model_dump_json(indent=2))
    recon = roundtrip(model, heldout)
    final = psnr_u8(heldout, recon)
    curve.append((history[-1]["seconds"], history[-1]["step"], final))
    enc_fps, dec_fps = speed(model, heldout)
    t, h, w = heldout.shape[1:4]
    return {"variant": name, "params": params, "steps": history[-1]["step"], "train_s": history[-1]["seconds"],
            "bpp": config.bits_per_pixel(t, h, w), "psnr": final, "ssim": ssim(heldout, recon),
            "encode_fps": enc_fps, "decode_fps": dec_fps, "curve": curve}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--budget-min", type=float, default=30.0, help="training minutes per variant (at most 30)")
    ap.add_argument("--variants", default="small-dv4x8x8,small-cv4x8x8")
    ap.add_argument("--manifest", type=Path, default=MANIFEST, help="scenario whose episodes (every camera) are the clips")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--clip-frames", type=int, default=17)
    ap.add_argument("--train-episodes", type=int, default=32)
    ap.add_argument("--heldout-episodes", type=int, default=4)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--crop", type=int, default=0, help="train on random crops of this side (0: whole frames, the "
                    "default: crops train the lowest level's attention on smaller grids than held-out frames give it)")
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--curve-points", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("bench/out/tokenizer"))
    ap.add_argument("--device", default="cpu", help="where the tokenizers train and run: auto, cpu, cuda (tasks.device)")
    ap.add_argument("--compile", action="store_true", help="torch.compile(mode='reduce-overhead') for training")
    ap.add_argument("--precision", default="fp32", choices=["fp32", "bf16"])
    ap.add_argument("--tf32", action="store_true", help="allow TF32 matmuls and convolutions on a GPU")
    ap.add_argument("--no-h264", action="store_true", help="leave out the H.264 curves (minutes of x264 on one "
                    "core; they do not depend on the device)")
    args = ap.parse_args()
    args.runtime = Runtime(device=args.device, precision=args.precision, compile=args.compile, tf32=args.tf32)
    device = args.runtime.torch_device()
    where = torch.cuda.get_device_name(device) if device.type == "cuda" else f"CPU, {args.threads} threads"
    args.crop = args.crop or None
    if args.budget_min > 30:
        ap.error("--budget-min: the issue caps the bench's training at 30 minutes")
    torch.set_num_threads(args.threads)
    started = time.perf_counter()
    train, held = render(args.out, args.train_episodes, args.heldout_episodes, args.size, args.manifest)
    heldout = windows(held, args.clip_frames)
    print(f"{args.manifest.name}: train {len(train)} camera streams x {train[0].shape[0]} frames; held-out: {len(heldout)} clips of "
          f"{args.clip_frames} frames at {args.size}x{args.size}", flush=True)
    curves = {} if args.no_h264 else {fmt: h264_curve(heldout, fmt) for fmt in ("yuv420p", "yuv444p")}
    results = [run_variant(v, train, heldout, args) for v in args.variants.split(",")]

    fmt = lambda v, p=2: "n/a" if v is None else f"{v:.{p}f}"  # noqa: E731
    for pix_fmt, h264 in curves.items():
        print(f"\nH.264 (libx264 preset medium, {pix_fmt}, {len(heldout)} clips of {args.clip_frames} frames, {args.size}x{args.size})")
        print(f"{'crf':>4} {'bpp whole':>10} {'bpp slices':>11} {'PSNR dB':>8} {'SSIM':>6}")
        for r in h264:
            print(f"{r['crf']:>4} {r['bpp']:>10.4f} {r['bpp_slices']:>11.4f} {r['psnr']:>8.2f} {r['ssim']:>6.3f}")
    print("\nTokenizers on the same clips; H.264 interpolated to the same bpp: whole stream / slices only "
          "(n/a: outside x264's range)")
    print(f"{'variant':<15} {'params':>7} {'steps':>6} {'min':>5} {'bpp':>7} {'PSNR':>6} {'SSIM':>6} "
          f"{'enc fps':>8} {'dec fps':>8}")
    for r in results:
        print(f"{r['variant']:<15} {r['params'] / 1e6:>6.2f}M {r['steps']:>6} {r['train_s'] / 60:>5.1f} {r['bpp']:>7.4f} "
              f"{r['psnr']:>6.2f} {r['ssim']:>6.3f} {r['encode_fps']:>8.1f} {r['decode_fps']:>8.1f}")
        r["x264_at_bpp"] = {}
        for pix_fmt, h264 in curves.items():
            got = {f"{key}_{which}": interpolate(h264, r["bpp"], key, bpp_key)
                   for key in ("psnr", "ssim") for which, bpp_key in (("whole", "bpp"), ("slices", "bpp_slices"))}
            r["x264_at_bpp"][pix_fmt] = got
            print(f"{'':<15} x264 {pix_fmt} at {r['bpp']:.4f} bpp: PSNR {fmt(got['psnr_whole'])} / {fmt(got['psnr_slices'])}"
                  f"  SSIM {fmt(got['ssim_whole'], 3)} / {fmt(got['ssim_slices'], 3)}")
    print("\nHeld-out PSNR against training time (probe of 8 clips; last point: all clips)")
    for r in results:
        print(f"{r['variant']:<15} " + "  ".join(f"{s / 60:.1f}min/{n}st {p:.2f}dB" for s, n, p in r["curve"]))
    print(f"\ntotal {time.perf_counter() - started:.0f}s; trained on {where} ({args.runtime.precision}, "
          f"compile {args.runtime.compile}, tf32 {args.runtime.tf32}); torch {torch.__version__}")
    (args.out / "results.json").write_text(json.dumps({"h264": curves, "tokenizers": results, "args": {
        k: str(v) for k, v in vars(args).items()}}, indent=2))


if __name__ == "__main__":
    main()

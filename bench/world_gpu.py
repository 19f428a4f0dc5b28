"""World-model recipes on a machine that has PyTorch but not the project's stack (a lent GPU).

`worldline train --device cuda` is the way to train on a GPU where the whole project is
installed. This bench is for a GPU machine that lacks Prefect and DuckDB (the one lent to
development sessions here): it splits the train flow at the one place the GPU matters.

``pack`` (here, on the data root): everything `worldline train` would read, gathered with the
flow's own functions and checked against lineage (``tasks.world.inputs``): the tokenizer's token
sequences with their captions (pre-training) and every episode's codes with aligned actions and
its manifest's text (post-training, ``phases.encode_episode``, cached under the root), into one
file.

``train`` (anywhere): pre- and post-trains each variant from that file with the flow's phase
functions (``tasks.world.phases``), in parallel processes on one device, and writes checkpoint
folders whose config names the tokenizer by its data-root path, as the flow's do. Copy a folder
back beside the data root and `worldline evaluate policies ... --world-model FOLDER` reads it as an
external checkpoint (no lineage id: it was not trained by a flow run).

``pack-raw`` is for when the tokenizer is to be trained there too: it carries the curated
shards and clip files the tokenize flow would read, each episode camera's video, and its actions
aligned as post-training aligns them (``data.episode_parts``, for the temporal compression of
``--tokenizer-preset``); ``train --raw`` then trains the tokenizer as `worldline tokenize` would
(the same TrainConfig, on the device), saves it, encodes the clips and the episodes with it on
the device, and trains the variants on those codes.

    .venv/bin/python bench/world_gpu.py pack manifests/push_closeup.yaml --also manifests/push_closeup_noisy.yaml \\
        --tokenizer ID --action-totals 3 --out BUNDLE.pt           # WORLDLINE_DATA_ROOT names the root
    python3 bench/world_gpu.py train BUNDLE.pt --out DIR --device cuda --compile \\
        --variant 'name=base post_steps=5000' --variant 'name=wide width=256 layers=6 batch=32 seconds=240'
    .venv/bin/python bench/world_gpu.py pack-raw manifests/push_closeup.yaml --also manifests/push_closeup_noisy.yaml \
        --shards SHARD_FOLDER --tokenizer-preset small-dv4x4x4 --action-totals 3 --out RAW_DIR
    python3 bench/world_gpu.py train RAW_DIR --raw --tokenizer-steps 3000 --out DIR --device cuda --compile ...
    .venv/bin/python bench/world_gpu.py train BUNDLE.pt --out DIR --device cpu \
        --variant 'name=more init=DIR/w8sc/posttrain batch=8 self_condition=0.5 seconds=2400 lr=2e-4'  # go on training
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from models.world_model import preset  # noqa: E402
from tasks.device import Runtime  # noqa: E402
from tasks.world import data, phases  # noqa: E402
from tasks.world.train import WorldTrainConfig  # noqa: E402

# Variant keys and their defaults (``episodes``: the first N episodes of each packed source, e.g.
# "1240,400"; empty: all): the CPU recipe of docs/evaluation.md (`--preset small-wm --steps 100
# --post-steps 5000 --window 4 --action-totals 3`). Model keys go to the preset as overrides.
# ``init``: a post-trained checkpoint folder to go on training (no pre-training; its architecture,
# window and action scale are kept, and the bundle must be packed with its tokenizer).
DEFAULTS = {"name": "base", "preset": "small-wm", "pre_steps": 100, "post_steps": 5000, "batch": 8, "window": 4,
            "seconds": 0.0, "self_condition": 0.0, "change_weight": 0.0, "episodes": "", "seed": 0, "init": "",
            "lr": 0.0}
MODEL_KEYS = ("width", "layers", "heads")


def _plain(seq: data.CodeSequence) -> dict:
    """A sequence as tensors and plain values: a bundle loads with ``torch.load(weights_only=True)``."""
    return {"key": seq.key, "codes": torch.from_numpy(seq.codes.astype(np.int16)), "text": seq.text,
            "actions": None if seq.actions is None else torch.from_numpy(np.asarray(seq.actions, np.float32)),
            "info": _jsonable(seq.info)}


def _jsonable(info: dict) -> dict:
    return json.loads(json.dumps(info, default=lambda v: v.item() if hasattr(v, "item") else str(v)))


def _sequence(row: dict) -> data.CodeSequence:
    return data.CodeSequence(key=row["key"], codes=row["codes"].numpy().astype(np.int64), text=row["text"],
                             actions=None if row["actions"] is None else row["actions"].numpy(), info=row["info"])


def pack(args) -> None:
    from schemas.settings import Settings
    from tasks.world import inputs
    from warehouse.store import Warehouse

    settings = Settings()
    root = settings.data_root.resolve()
    warehouse = Warehouse(settings.warehouse_path, read_only=True)
    tok_folder, tok_id, tok_config = inputs.tokenizer_checkpoint(warehouse, root, args.tokenizer)
    shards = inputs.token_shards(warehouse, root, tok_id, None)
    pretrain = data.load_token_sequences([p for p, _, _ in shards], root)
    (grid_h, grid_w), size = inputs.shape(pretrain)
    action_dim = preset(DEFAULTS["preset"]).action_dim
    episodes, folders = [], []
    for n, source in enumerate([args.manifest, *args.also]):
        found, scenario = inputs.episode_folders(source, root)
        inputs.episodes(warehouse, found, root)
        inputs.check_episode_videos(warehouse, found, args.camera, root)
        texts = inputs.episode_texts(warehouse, found, scenario)
        started = time.perf_counter()
        for i, folder in enumerate(found):
            for seq in phases.encode_episode(folder, tok_folder, tok_id, size, [args.camera] if args.camera else None,
                                             action_dim, texts[folder], root, args.action_totals):
                episodes.append(seq)
                seq.info.update(source=n, index=i, folder=inputs.uri(folder, root))
            if (i + 1) % 200 == 0:
                print(f"{source}: encoded {i + 1} of {len(found)} episodes ({time.perf_counter() - started:.0f} s)")
        folders += found
    body = {"tokenizer_id": tok_id, "tokenizer": inputs.uri(tok_folder, root), "size": size,
            "grid": [grid_h, grid_w], "codebook_size": tok_config.codebook_size,
            "temporal_compression": tok_config.temporal_compression, "camera": args.camera,
            "action_totals": args.action_totals, "episode_folders": [inputs.uri(f, root) for f in folders],
            "pretrain": [_plain(s) for s in pretrain], "posttrain": [_plain(s) for s in episodes]}
    torch.save(body, args.out)
    print(f"packed {len(pretrain)} token sequences and {len(episodes)} episode videos of {len(folders)} episodes "
          f"(tokenizer {tok_id}) into {args.out} ({Path(args.out).stat().st_size / 1e6:.1f} MB)")


def pack_raw(args) -> None:
    import shutil

    from models.tokenizer import preset as tokenizer_preset
    from schemas.settings import Settings
    from tasks.tokenize.data import usable_frames
    from tasks.video import frame_rate, read_frames
    from tasks.world import inputs
    from warehouse.store import Warehouse

    settings = Settings()
    root = settings.data_root.resolve()
    warehouse = Warehouse(settings.warehouse_path, read_only=True)
    out = Path(args.out)
    t = tokenizer_preset(args.tokenizer_preset).temporal_compression
    action_dim = preset(DEFAULTS["preset"]).action_dim
    shards = sorted(Path(args.shards).resolve().rglob("*.parquet"))
    for shard in shards:  # the shard and the clip files it names, at their data-root paths
        inputs.known(warehouse, "shard", shard, root, "curated shard", "pack-raw reads curate's shards")
        for row in data.read_shard(shard).select(["clip_uri"]).to_pylist():
            if row["clip_uri"]:
                (out / row["clip_uri"]).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(root / row["clip_uri"], out / row["clip_uri"])
        (out / inputs.uri(shard, root)).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(shard, out / inputs.uri(shard, root))

    def latent_frames(video: Path):
        n = usable_frames(read_frames(video).shape[0], t)
        return np.zeros(1 + (n - 1) // t), frame_rate(video)

    episodes, folders = [], []
    for n, source in enumerate([args.manifest, *args.also]):
        found, scenario = inputs.episode_folders(source, root)
        found = found[:args.limit or None]
        inputs.episodes(warehouse, found, root)
        texts = inputs.episode_texts(warehouse, found, scenario)
        for i, folder in enumerate(found):
            for camera in [args.camera] if args.camera else data.read_meta(folder).get("cameras", []):
                key, latent, text, actions, info = data.episode_parts(folder, camera, t, latent_frames, action_dim,
                                                                      texts[folder], args.action_totals)
                video = f"episodes/{len(episodes):05d}.mp4"
                (out / video).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(folder / f"{camera}.mp4", out / video)
                episodes.append({"key": key, "video": video, "text": text, "actions": torch.from_numpy(actions),
                                 "info": _jsonable({**info, "source": n, "index": i,
                                                    "folder": inputs.uri(folder, root)})})
        folders += found
    torch.save({"tokenizer_preset": args.tokenizer_preset, "shards": [inputs.uri(s, root) for s in shards],
                "action_totals": args.action_totals, "camera": args.camera, "episodes": episodes,
                "episode_folders": [inputs.uri(f, root) for f in folders]}, out / "raw.pt")
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    print(f"packed {len(shards)} shards and {len(episodes)} episode videos of {len(folders)} episodes into {out} "
          f"({size / 1e6:.1f} MB)")


@torch.no_grad()
def _encode(tokenizer, frames: np.ndarray, size: int, max_frames: int | None = None) -> np.ndarray:
    """``data.encode_frames`` with the frames moved to the tokenizer's device."""
    from tasks.tokenize.data import square, usable_frames
    from tasks.tokenize.train import to_tensor

    n = usable_frames(frames.shape[0], tokenizer.config.temporal_compression, max_frames)
    device = next(tokenizer.parameters()).device
    return tokenizer.eval().encode(to_tensor(square(frames[:n], size))[None].to(device))[0].cpu().numpy()


def tokenize_raw(raw: Path, out: Path, steps: int, size: int, device: str, compile_model: bool,
                 tokenizer_uri: str | None = None, seconds: float | None = None) -> Path:
    """Train the tokenizer as `worldline tokenize SHARDS --preset P --steps N --size 64 --batch 8
    --motion-weight 4` would, encode the clips and episodes with it, and write a packed bundle."""
    from models.tokenizer import preset as tokenizer_preset
    from tasks.curate.shards import read_shard
    from tasks.tokenize import phases as tokenize_phases
    from tasks.tokenize.data import shard_clips
    from tasks.tokenize.train import TrainConfig
    from tasks.video import read_frames

    body = torch.load(raw / "raw.pt", weights_only=True)
    name = body["tokenizer_preset"]
    config = TrainConfig(preset=name, steps=steps, seconds=seconds, size=size, batch_size=8, seed=0, motion_weight=4.0,
                         clip_frames=1 + 2 * tokenizer_preset(name).temporal_compression, threads=2)
    clips = [c for uri in body["shards"] for c in shard_clips(raw / uri, raw, uri, size, 129)]
    started = time.perf_counter()
    folder = out / "tokenizer"
    history, _ = tokenize_phases.train(clips, config, folder, {"checkpoint_id": "tokenizer", "shards": body["shards"]},
                                       None, Runtime(device=device, compile=compile_model))
    print(f"tokenizer {name}: {history[-1]['step']} steps in {time.perf_counter() - started:.0f} s, train PSNR "
          f"{history[-1]['psnr']:.2f} dB", flush=True)
    from tasks.tokenize import tokens

    tokenizer = tokens.load_checkpoint(folder).to(Runtime(device=device).torch_device())
    captions = {r["clip_id"]: r["caption"] for uri in body["shards"]
                for r in read_shard(raw / uri).select(["clip_id", "caption"]).to_pylist()}
    pretrain = [data.CodeSequence(key=c.clip_id, codes=_encode(tokenizer, c.frames, size, 129).astype(np.int64),
                                  text=captions.get(c.clip_id, ""), info={"clip_id": c.clip_id, "size": size})
                for c in clips]
    episodes = []
    for e in body["episodes"]:
        codes = _encode(tokenizer, read_frames(raw / e["video"]), size).astype(np.int64)
        if codes.shape[0] != e["actions"].shape[0] + 1:
            raise SystemExit(f"{e['key']}: {codes.shape[0]} latent frames against {e['actions'].shape[0]} action rows")
        episodes.append(data.CodeSequence(key=e["key"], codes=codes, text=e["text"], actions=e["actions"].numpy(),
                                          info=e["info"]))
    print(f"encoded {len(pretrain)} clips and {len(episodes)} episode videos in {time.perf_counter() - started:.0f} s",
          flush=True)
    grid = pretrain[0].codes.shape[1:]
    bundle = {"tokenizer_id": "tokenizer", "tokenizer": tokenizer_uri or str(folder.resolve()), "size": size, "grid": list(grid),
              "codebook_size": tokenizer.config.codebook_size,
              "temporal_compression": tokenizer.config.temporal_compression, "camera": body["camera"],
              "action_totals": body["action_totals"], "episode_folders": body["episode_folders"],
              "pretrain": [_plain(s) for s in pretrain], "posttrain": [_plain(s) for s in episodes],
              "tokenizer_history": history[-1]}
    torch.save(bundle, out / "bundle.pt")
    return out / "bundle.pt"


def variant(text: str) -> dict:
    spec = dict(DEFAULTS)
    for item in text.split():
        key, _, value = item.partition("=")
        if key not in DEFAULTS and key not in MODEL_KEYS:
            raise SystemExit(f"--variant {text!r}: unknown key {key!r} (known: {', '.join([*DEFAULTS, *MODEL_KEYS])})")
        spec[key] = value if key in ("name", "preset", "episodes", "init") else \
            float(value) if "." in value or "e-" in value else int(value)
    return spec


def train_one(bundle_path: str, spec: dict, out: str, device: str, compile_model: bool, threads: int) -> dict:
    torch.set_num_threads(threads)
    bundle = torch.load(bundle_path, weights_only=True)
    pretrain = [_sequence(r) for r in bundle["pretrain"]]
    episodes = [_sequence(r) for r in bundle["posttrain"]]
    if spec["episodes"]:
        limits = [int(x) for x in str(spec["episodes"]).split(",")]
        episodes = [e for e in episodes if e.info["index"] < limits[min(e.info["source"], len(limits) - 1)]]
    grid_h, grid_w = bundle["grid"]
    model_config = preset(spec["preset"], codebook_size=bundle["codebook_size"], max_height=grid_h, max_width=grid_w,
                          temporal_compression=bundle["temporal_compression"], max_frames=spec["window"],
                          patch=phases.token_patch(grid_h, grid_w), **{k: spec[k] for k in MODEL_KEYS if k in spec})
    runtime = Runtime(device=device, compile=compile_model)
    pre_config = WorldTrainConfig(preset=spec["preset"], steps=spec["pre_steps"], batch_size=spec["batch"],
                                  seed=spec["seed"], threads=threads, change_weight=spec["change_weight"])
    post_config = WorldTrainConfig(preset=spec["preset"], steps=spec["post_steps"], batch_size=spec["batch"],
                                   seed=spec["seed"], threads=threads, lr=pre_config.lr / 2, warmup_steps=10,
                                   change_weight=spec["change_weight"], self_condition=spec["self_condition"],
                                   action_totals=bundle["action_totals"], seconds=spec["seconds"] or None)
    if spec["lr"]:
        post_config = post_config.model_copy(update={"lr": spec["lr"]})
    folder = Path(out) / spec["name"]
    common = {"tokenizer_id": bundle["tokenizer_id"], "size": bundle["size"], "tokenizer": bundle["tokenizer"]}
    started = time.perf_counter()
    if spec["init"]:
        return go_on(spec, bundle, episodes, post_config, folder, common, runtime, started)
    pre_history, _ = phases.pretrain(pretrain, model_config, pre_config, folder / "pretrain",
                                     {"checkpoint_id": f"{spec['name']}-pretrain", **common}, runtime)
    post_history, params = phases.posttrain(
        folder / "pretrain", episodes, post_config, folder / "posttrain",
        {"checkpoint_id": spec["name"], "pretrained_id": f"{spec['name']}-pretrain", **common,
         "episodes": sorted({e.info["folder"] for e in episodes}), "camera": bundle["camera"],
         "trained_by": f"bench/world_gpu.py on {runtime.torch_device()}"}, runtime)
    return _report(spec, runtime, params, episodes, started, post_history, folder, pretrain_final=pre_history[-1])


def _report(spec: dict, runtime: Runtime, params: int, episodes: list, started: float, history: list[dict],
            folder: Path, **more) -> dict:
    """The variant's result: written to its folder's result.json, its summary printed."""
    result = {"spec": spec, "device": str(runtime.torch_device()),
              "card": torch.cuda.get_device_name() if torch.cuda.is_available() else "cpu",
              "params": params, "episode_videos": len(episodes), "seconds": round(time.perf_counter() - started, 1),
              "post_steps_done": history[-1]["step"], "post_train_seconds": history[-1]["seconds"],
              "final": history[-1], **more}
    (folder / "result.json").write_text(json.dumps(result, indent=1))
    print(json.dumps({k: result[k] for k in ("spec", "params", "seconds", "post_steps_done", "final")}), flush=True)
    return result


def go_on(spec: dict, bundle: dict, episodes: list, post_config: WorldTrainConfig, folder: Path, common: dict,
          runtime: Runtime, started: float) -> dict:
    """Go on post-training the checkpoint ``spec["init"]`` on the bundle's episodes."""
    from tasks.world import checkpoints
    from tasks.world.train import train_world_model

    init = Path(spec["init"])
    before = checkpoints.read_config(init)
    if before.get("tokenizer_id") != bundle["tokenizer_id"]:
        raise SystemExit(f"init {init}: tokenizer {before.get('tokenizer_id')}, "
                         f"the bundle's is {bundle['tokenizer_id']}")
    model = checkpoints.load_checkpoint(init).train()
    post_config = post_config.model_copy(update={"action_totals": model.config.action_totals, "warmup_steps": 10})
    history = train_world_model(model, episodes, post_config, None, runtime)
    checkpoints.save_checkpoint(model.cpu().eval(), folder / "posttrain", {
        **{k: v for k, v in before.items() if k != "world_model"}, "phase": "posttrain",
        "train": post_config.model_dump(mode="json"), "checkpoint_id": spec["name"], "continued_from": str(init),
        "episodes": sorted({e.info["folder"] for e in episodes}), **common,
        "trained_by": f"bench/world_gpu.py on {runtime.torch_device()}"})
    return _report(spec, runtime, sum(p.numel() for p in model.parameters()), episodes, started, history, folder)


def train(args) -> None:
    specs = [variant(v) for v in args.variant] or [dict(DEFAULTS)]
    if len({s["name"] for s in specs}) != len(specs):
        raise SystemExit("--variant: two variants share a name")
    Path(args.out).mkdir(parents=True, exist_ok=True)
    if args.raw:
        args.bundle = str(tokenize_raw(Path(args.bundle), Path(args.out), args.tokenizer_steps, 64, args.device,
                                       args.compile, args.tokenizer_uri, args.tokenizer_seconds))
    if len(specs) == 1:
        train_one(args.bundle, specs[0], args.out, args.device, args.compile, args.threads)
        return
    ctx = torch.multiprocessing.get_context("spawn")
    with ctx.Pool(len(specs)) as pool:
        done = [pool.apply_async(train_one, (args.bundle, s, args.out, args.device, args.compile, args.threads))
                for s in specs]
        for job in done:
            job.get()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("pack", help="gather what `worldline train` reads into one file")
    p.add_argument("manifest")
    p.add_argument("--also", action="append", default=[])
    p.add_argument("--tokenizer", default=None)
    p.add_argument("--camera", default=None)
    p.add_argument("--action-totals", type=int, default=0)
    p.add_argument("--out", required=True)
    t = sub.add_parser("train", help="pre- and post-train variants from a packed file")
    t.add_argument("bundle", help="a packed file, or with --raw a pack-raw folder")
    t.add_argument("--raw", action="store_true", help="train the tokenizer first, from a pack-raw folder")
    t.add_argument("--tokenizer-steps", type=int, default=3000)
    t.add_argument("--tokenizer-seconds", type=float, default=None, help="with --raw: stop the tokenizer's training "
                   "at this many seconds if its steps are not done")
    t.add_argument("--tokenizer-uri", default=None, help="with --raw: where the world models' configs will say "
                   "the tokenizer is (where it will be copied to; default: where it is written)")
    t.add_argument("--out", required=True)
    t.add_argument("--variant", action="append", default=[], help="'name=N key=value ...' (keys: see DEFAULTS)")
    t.add_argument("--device", default="auto")
    t.add_argument("--compile", action="store_true")
    t.add_argument("--threads", type=int, default=2)
    r = sub.add_parser("pack-raw", help="gather what `worldline tokenize` and `train` read, before any tokenizer")
    r.add_argument("manifest")
    r.add_argument("--also", action="append", default=[])
    r.add_argument("--shards", required=True, help="the curated shard folder the tokenizer trains on")
    r.add_argument("--tokenizer-preset", default="small-dv4x4x4")
    r.add_argument("--camera", default=None)
    r.add_argument("--action-totals", type=int, default=0)
    r.add_argument("--limit", type=int, default=0, help="the first N episodes of each source (0: all)")
    r.add_argument("--out", required=True)
    args = parser.parse_args()
    {"pack": pack, "pack-raw": pack_raw, "train": train}[args.command](args)


if __name__ == "__main__":
    main()

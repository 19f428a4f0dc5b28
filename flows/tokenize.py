"""tokenize: curated shards -> decode clips -> train a tokenizer (TensorBoard, safetensors
checkpoint) -> encode every shard into a token shard. Checkpoint, token shards, their edges
and the training metrics land in lineage; a finished step is skipped on a re-run."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import torch
from prefect import flow, task
from pydantic import Field

from flows.params import Batch, Seed, Side, Steps, Weight
from flows.recording import RunContext, recorded_run
from flows.report import markdown_table
from flows.report import publish as publish_report
from models.tokenizer import VideoTokenizer, preset
from schemas import paths
from schemas.hashing import content_hash, stable_id
from schemas.records import EdgeRecord
from schemas.settings import Settings
from tasks import integrity
from tasks.lookup import verified_file
from tasks.tokenize import data, tokens
from tasks.tokenize.train import TrainConfig, psnr, to_tensor, train_tokenizer
from tasks.world.inputs import tokenizer_folder

STAGE_TRAIN, STAGE_ENCODE = "train_tokenizer", "encode_tokens"


def shard_files(shards: str, root: Path) -> list[Path]:
    """A folder or file of shards, or a manifest hash (its first 12+ hex digits) naming its shard folder."""
    place = Path(shards)
    if not place.exists() and len(shards) >= 12 and all(ch in "0123456789abcdef" for ch in shards):
        place = paths.resolve(root, paths.SHARDS_OF_MANIFEST, manifest_hash=shards)
    found = data.find_shards([place])
    if not found:
        raise FileNotFoundError(f"{shards}: no shard files there (give a shard folder or a manifest hash)")
    return found


def shard_artifacts(run: RunContext, files: list[Path]) -> list[tuple[Path, str, str, str | None]]:
    """(path, uri, artifact id, manifest hash) per shard, each hashed once and checked against
    lineage: a changed shard raises TamperedArtifact, one curate never wrote InvalidInput
    (registering it would start a lineage with no clips or raw videos behind it)."""
    root = run.settings.data_root.resolve()
    out = []
    for path in files:
        shard_id, mh, _ = verified_file(run.warehouse, root, path, "shard", "curated shard",
                                        "tokenize reads shards `worldline curate` wrote")
        out.append((path, integrity.uri_of(path, root), shard_id, mh))
    return out


@task(name="decode-shard", retries=1)
def decode_shard(path: Path, root: Path, uri: str, size: int, max_frames: int) -> list[data.Clip]:
    return data.shard_clips(path, root, uri, size, max_frames)


def init_checkpoint(run: RunContext, init: str, preset_name: str) -> tuple[Path, str]:
    """(folder, artifact id) of the tokenizer checkpoint to continue from (a folder or an id in
    lineage, as `worldline train --tokenizer` takes them); it must hold the same preset."""
    folder, checkpoint_id = tokenizer_folder(run.warehouse, run.settings.data_root, init, variant=None)
    found = tokens.load_checkpoint(folder).config
    if found != preset(preset_name):
        raise ValueError(f"--init {folder}: holds tokenizer {found.name!r}, not preset {preset_name!r} "
                         "(continue training with the same preset)")
    return folder, checkpoint_id


@task(name="train-tokenizer", log_prints=True)
def train(clips: list[data.Clip], config: TrainConfig, folder: Path, extra: dict,
          init: Path | None = None) -> tuple[list[dict], int]:
    """Train from the preset's seeded initial weights (or from checkpoint folder ``init``), log to
    TensorBoard beside the checkpoint, save it; returns the history and the parameter count."""
    from torch.utils.tensorboard import SummaryWriter

    torch.manual_seed(config.seed)
    model = tokens.load_checkpoint(init).train() if init else VideoTokenizer(preset(config.preset))
    with SummaryWriter(str(folder / "tensorboard")) as writer:
        every = max(config.log_every, config.steps // 20 // config.log_every * config.log_every)

        def log(record: dict) -> None:
            for name in ("loss", "psnr", "lr"):
                writer.add_scalar(f"train/{name}", record[name], record["step"])
            if record["step"] % every == 0:  # about 20 progress lines per run, into the flow run's log
                print(f"step {record['step']}/{config.steps} ({record['seconds']:.0f} s): loss {record['loss']:.4f}, "
                      f"train PSNR {record['psnr']:.2f} dB")
        history = train_tokenizer(model, data.frame_arrays(clips), config, log)
    tokens.save_checkpoint(model, folder, {"train": config.model_dump(mode="json"), **extra})
    return history, sum(p.numel() for p in model.parameters())


@task(name="encode-shard", retries=1)
def encode_shard(folder: Path, clips: list[data.Clip], target: Path, max_frames: int) -> tuple[str, int, int, float | None]:
    """Encode a shard's clips to a token shard; returns sha256, bytes, rows and the mean round-trip PSNR."""
    model = tokens.load_checkpoint(folder)
    rows, scores = [], []
    for clip in clips:
        row = tokens.encode_clip(model, clip, max_frames)
        if row is not None:
            rows.append(row)
            scores.append(psnr(to_tensor(clip.frames[:row["frames"]])[None], tokens.decode_row(model, row)).item())
    digest, size = tokens.write_token_shard(rows, target)
    return digest, size, len(rows), (sum(scores) / len(scores) if scores else None)


@flow(name="tokenize", log_prints=True)
def tokenize(shards: str, preset_name: str = "tiny-dv4x8x8", steps: Steps = 200, size: Side = 64,
             batch_size: Batch = 4, seed: Seed = 0, max_encode_frames: Annotated[int, Field(ge=1)] = 129,
             crop: Side | None = None,
             motion_weight: Weight = 0.0, focus_crops: Annotated[int, Field(ge=1, le=64)] = 1,
             init: str | None = None) -> dict:
    """Train tokenizer ``preset_name`` for ``steps`` on the clips of ``shards`` (on random
    ``crop`` x ``crop`` windows when given; weighting moving pixels and favouring crops that
    move when asked; continuing from checkpoint ``init`` when given), then tokenize every shard."""
    settings = Settings()
    root = settings.data_root.resolve()
    model_config = preset(preset_name)
    config = TrainConfig(preset=preset_name, steps=steps, size=size, batch_size=batch_size, seed=seed, crop=crop,
                         motion_weight=motion_weight, focus_crops=focus_crops,
                         clip_frames=1 + 2 * model_config.temporal_compression, threads=min(2, torch.get_num_threads()))
    files = shard_files(shards, root)
    with recorded_run("tokenize", settings, params={"shards": shards, "preset": preset_name, "steps": steps,
                                                    "size": size, "batch_size": batch_size, "seed": seed,
                                                    "crop": crop, "motion_weight": motion_weight,
                                                    "focus_crops": focus_crops, "init": init}) as run:
        init_folder, init_id = init_checkpoint(run, init, preset_name) if init else (None, None)
        known = shard_artifacts(run, files)
        hashes = {mh for *_, mh in known if mh}
        mh = hashes.pop() if len(hashes) == 1 else None
        decoded = {uri: decode_shard.submit(path, root, uri, size, max_encode_frames) for path, uri, _, _ in known}
        clips = {uri: future.result() for uri, future in decoded.items()}
        # A clip two curate runs put in two shards of a bucket (shards are named by content)
        # is trained on and encoded to tokens once, from the first shard that holds it.
        seen: set[str] = set()
        for uri in sorted(clips):
            clips[uri] = [c for c in clips[uri] if not (c.clip_id in seen or seen.add(c.clip_id))]

        key = stable_id(STAGE_TRAIN, content_hash(model_config), content_hash(config), *sorted(s for _, _, s, _ in known),
                        *([f"init:{init_id}"] if init_id else []))
        checkpoint_id = stable_id("checkpoint", key)
        folder = paths.resolve(root, paths.CHECKPOINT_DIR, model=model_config.name, checkpoint_id=checkpoint_id)
        all_clips = [c for uri in sorted(clips) for c in clips[uri]]
        history: list[dict] = []
        stage = run.stage(STAGE_TRAIN, key, [folder / tokens.WEIGHTS_FILE], manifest_hash=mh)
        if not stage.done:
            history, params = train(all_clips, config, folder, {"checkpoint_id": checkpoint_id, "init": init_id,
                                                                "shards": [u for _, u, _, _ in known]}, init_folder)
            batch = tokens.checkpoint_lineage(
                checkpoint_id, folder, root, [s for _, _, s, _ in known], history, stage.id, mh,
                {"preset": preset_name, "variant": model_config.variant, "steps": steps, "size": size,
                 "params": params, "init": init_id})
            if init_id:
                batch.edges.append(EdgeRecord(parent_id=init_id, child_id=checkpoint_id, relation="continued_from"))
            stage.finish(len(all_clips), 1, batch, attrs={"checkpoint_id": checkpoint_id, "steps": steps})
            print(f"trained {preset_name} for {steps} steps in {time.perf_counter() - stage.started:.1f}s: "
                  f"loss {history[-1]['loss']:.4f}, train PSNR {history[-1]['psnr']:.2f} dB")

        written = []
        for index, (path, uri, shard_id, shard_mh) in enumerate(known):
            target, rel = tokens.token_shard_path(root, checkpoint_id, index)
            ekey = stable_id(STAGE_ENCODE, checkpoint_id, shard_id, str(max_encode_frames), str(index))
            if not clips[uri]:
                continue
            stage = run.stage(STAGE_ENCODE, ekey, [target], manifest_hash=shard_mh or mh)
            if stage.done:
                continue
            digest, nbytes, n, score = encode_shard(folder, clips[uri], target, max_encode_frames)
            stage.finish(len(clips[uri]), n, tokens.token_shard_lineage(
                rel, digest, nbytes, n, checkpoint_id, shard_id, stage.id, shard_mh or mh, score), attrs={"source": uri})
            written.append((rel, n, score))

        rows = [(h["step"], f"{h['seconds']:.1f}", f"{h['loss']:.4f}", f"{h['psnr']:.2f}") for h in history]
        body = (f"checkpoint `{checkpoint_id}` ({preset_name}, {model_config.variant}) under "
                f"`{folder.relative_to(root).as_posix()}`\n\n"
                + (markdown_table(("step", "seconds", "L1 loss", "train PSNR dB"), rows) if rows else "training skipped: done before")
                + "\n\n" + markdown_table(("token shard", "clips", "round-trip PSNR dB"),
                                          [(r, n, "" if s is None else f"{s:.2f}") for r, n, s in written]))
        publish_report("tokenize", f"{len(all_clips)} clips from {len(known)} shards, {len(written)} token shards",
                       body, "tokenizer training and token shards")
        summary = {"run_id": run.run_id, "checkpoint_id": checkpoint_id, "checkpoint": str(folder),
                   "clips": len(all_clips), "trained": bool(history), "token_shards": [r for r, _, _ in written],
                   "final_loss": history[-1]["loss"] if history else None,
                   "final_psnr": history[-1]["psnr"] if history else None}
    print(summary)
    return summary

"""tokenize: curated shards -> decode clips -> train a tokenizer (TensorBoard, safetensors
checkpoint) -> encode every shard into a token shard. Checkpoint, token shards, their edges
and the training metrics land in lineage; a finished step is skipped on a re-run."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Literal

import torch
from prefect import flow, task

from flows.params import Batch, EncodeFrames, FocusCrops, Seed, Side, Steps, Weight
from flows.params_world import TokenizeParams
from flows.recording import recorded_run
from flows.report import markdown_table, progress
from flows.report import publish as publish_report
from models.tokenizer import preset
from schemas import paths
from schemas.hashing import content_hash, stable_id
from schemas.records import EdgeRecord
from schemas.settings import Settings
from tasks import progress as ticks
from tasks.lookup import verified_file
from tasks.tokenize import data, phases, tokens
from tasks.tokenize.inputs import init_checkpoint, shard_artifacts, shard_files
from tasks.tokenize.train import TrainConfig

STAGE_TRAIN, STAGE_ENCODE = "train_tokenizer", "encode_tokens"

train = task(phases.train, name="train-tokenizer", log_prints=True)
encode_shard = task(phases.encode_shard, name="encode-shard", retries=1)


@task(name="decode-shard", retries=1)
def decode_shard(path: Path, root: Path, uri: str, size: int, max_frames: int) -> list[data.Clip]:
    return data.shard_clips(path, root, uri, size, max_frames)


@flow(name="tokenize", log_prints=True)
def tokenize(shards: str, preset_name: str = "tiny-dv4x8x8", steps: Steps = 200, size: Side = 64,
             batch_size: Batch = 4, seed: Seed = 0, max_encode_frames: EncodeFrames = 129,
             crop: Side | None = None,
             motion_weight: Weight = 0.0, focus_crops: FocusCrops = 1,
             init: str | None = None, device: str | None = None, precision: Literal["fp32", "bf16"] = "fp32",
             compile_model: bool = False) -> dict:
    """Train tokenizer ``preset_name`` for ``steps`` on the clips of ``shards`` (on random
    ``crop`` x ``crop`` windows when given; weighting moving pixels and favouring crops that
    move when asked; continuing from checkpoint ``init`` when given), then tokenize every shard,
    on ``device`` (``tasks.device``: none of it enters the checkpoint's id)."""
    runtime = TokenizeParams.of(locals()).runtime()  # every parameter check, for a deployment as for the CLI
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
        init_folder, init_id = init_checkpoint(run.warehouse, root, init, preset_name) if init else (None, None)
        known = shard_artifacts(run.warehouse, root, files)
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
            with progress(steps, f"train {preset_name} (steps)", topic=ticks.TOKENIZER_STEPS):
                history, params = train(all_clips, config, folder, {"checkpoint_id": checkpoint_id, "init": init_id,
                                                                    "shards": [u for _, u, _, _ in known]},
                                        init_folder, runtime)
            batch = tokens.checkpoint_lineage(
                checkpoint_id, folder, root, [s for _, _, s, _ in known], history, stage.id, mh,
                {"preset": preset_name, "variant": model_config.variant, "steps": steps, "size": size,
                 "params": params, "init": init_id})
            if init_id:
                batch.edges.append(EdgeRecord(parent_id=init_id, child_id=checkpoint_id, relation="continued_from"))
            stage.finish(len(all_clips), 1, batch, attrs={"checkpoint_id": checkpoint_id, "steps": steps})
            print(f"trained {preset_name} for {steps} steps in {time.perf_counter() - stage.started:.1f}s: "
                  f"loss {history[-1]['loss']:.4f}, train PSNR {history[-1]['psnr']:.2f} dB")

        written, trained = [], bool(history)  # weights this run wrote need no check
        with progress(len(known), "encode token shards") as bar:
            for index, (path, uri, shard_id, shard_mh) in enumerate(known):
                target, rel = tokens.token_shard_path(root, checkpoint_id, index)
                ekey = stable_id(STAGE_ENCODE, checkpoint_id, shard_id, str(max_encode_frames), str(index))
                stage = run.stage(STAGE_ENCODE, ekey, [target], manifest_hash=shard_mh or mh) if clips[uri] else None
                if stage is None or stage.done:  # no clips, or encoded by an earlier run
                    bar.advance()
                    continue
                if not trained:  # trained by an earlier run: its weights as lineage recorded them (else exit 5)
                    trained = bool(verified_file(run.warehouse, root, folder / tokens.WEIGHTS_FILE, "checkpoint",
                                                 "tokenizer checkpoint"))
                digest, nbytes, n, score = encode_shard(folder, clips[uri], target, max_encode_frames)
                stage.finish(len(clips[uri]), n, tokens.token_shard_lineage(
                    rel, digest, nbytes, n, checkpoint_id, shard_id, stage.id, shard_mh or mh, score), attrs={"source": uri})
                written.append((rel, n, score))
                bar.advance()

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

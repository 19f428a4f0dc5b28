"""train: a tokenizer's token shards -> pre-train the world model with text -> encode a
manifest's simulated episodes with that tokenizer -> post-train with their actions. Both
checkpoints, their training curves and their edges (``trained_on`` the token shards or episodes
and the tokenizer, ``posttrained_from`` the pre-trained checkpoint) land in lineage; a finished
phase is skipped on a re-run. ``family``: the autoregressive model on a discrete tokenizer's
codes, or the diffusion one on a continuous tokenizer's latents (``tasks.world.phases.family_setup``)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import torch
from prefect import flow, task

from flows.params import ActionTotals, Batch, Patch, Seed, Share, Steps, Weight, Window
from flows.params_world import TrainParams
from flows.recording import RunContext, recorded_run
from flows.report import progress, publish
from schemas import paths
from schemas.hashing import content_hash, stable_id
from schemas.settings import Settings
from tasks import progress as ticks
from tasks.device import Runtime
from tasks.lookup import verified_checkpoint
from tasks.world import checkpoints, inputs, phases
from tasks.world.family import TOKENIZER_VARIANT
from tasks.world.inputs import episode_folders, uri

STAGE_PRETRAIN, STAGE_POSTTRAIN = "pretrain_world_model", "posttrain_world_model"
# Bumped when post-training learns something different from the same inputs, so an earlier
# checkpoint is not taken for a finished one. 2: actions divided by their RMS (action_scale).
POSTTRAIN_RECIPE = 2

load_tokens = task(phases.load_sequences, name="load-token-shards", retries=1)
encode_episode = task(phases.encode_episode, name="encode-episode", retries=1)
pretrain = task(phases.pretrain, name="pretrain-world-model")
posttrain = task(phases.posttrain, name="posttrain-world-model")


def pretrain_phase(run: RunContext, tok_folder: Path, tok_id: str, shards: list, sequences: list, size: int,
                   setup: dict, preset_name: str, runtime: Runtime | None = None) -> tuple[str, Path, list]:
    """(checkpoint id, folder, history: empty when done before) of pre-training on token sequences
    with their captions."""
    root, model_config, config = run.settings.data_root.resolve(), setup["model"], setup["pre"]
    hashes = {mh for *_, mh in shards if mh}
    mh = hashes.pop() if len(hashes) == 1 else None
    shard_ids = sorted(s for _, s, _ in shards)
    key = stable_id(STAGE_PRETRAIN, *setup["key"], content_hash(model_config), phases.meaning(config), tok_id,
                    *shard_ids)
    pre_id = stable_id("checkpoint", key)
    folder = paths.resolve(root, paths.CHECKPOINT_DIR, model=model_config.name, checkpoint_id=pre_id)
    stage = run.stage(STAGE_PRETRAIN, key, [folder / checkpoints.WEIGHTS_FILE], manifest_hash=mh)
    if stage.done:  # trained by an earlier run: post-training reads it, so it must still be those bytes
        verified_checkpoint(run.warehouse, root, folder)
        return pre_id, folder, []
    with progress(config.steps, f"pre-train {preset_name} (steps)", topic=ticks.WORLD_MODEL_STEPS):
        history, params = pretrain(sequences, model_config, config, folder,
                                   {"checkpoint_id": pre_id, "tokenizer_id": tok_id, "size": size, "tokenizer":
                                    uri(tok_folder, root), "token_shards": [uri(p, root) for p, _, _ in shards]},
                                   runtime)
    stage.finish(len(sequences), 1, checkpoints.checkpoint_lineage(
        pre_id, folder, root, [(s, "trained_on") for s in shard_ids] + [(tok_id, "trained_on")],
        history, stage.id, mh, {"model": "world_model", "phase": "pretrain", "preset": preset_name,
                                "steps": config.steps, "params": params, "tokenizer_id": tok_id, **setup["attrs"]},
        metrics=setup["metrics"]), attrs={"checkpoint_id": pre_id, "steps": config.steps})
    print(f"pre-trained {preset_name} on {len(sequences)} token sequences for {config.steps} steps: "
          f"{phases.scores(history)}")
    return pre_id, folder, history


def posttrain_phase(run: RunContext, sources: list, pre_id: str, pre_folder: Path, tok_folder: Path, tok_id: str,
                    size: int, camera: str | None, setup: dict, preset_name: str,
                    runtime: Runtime | None = None) -> tuple[str, Path, list, int]:
    """(checkpoint id, folder, history, episode videos) of post-training with actions on the
    episodes of ``sources``, from the pre-trained weights."""
    root, model_config, config = run.settings.data_root.resolve(), setup["model"], setup["post"]
    folders = [f for found, _ in sources for f in found]
    episodes = inputs.episodes(run.warehouse, folders, root)
    episode_hashes = {mh for *_, mh in episodes if mh}
    mh = run.manifest_hash or (episode_hashes.pop() if len(episode_hashes) == 1 else None)
    episode_ids = sorted(e for _, e, _ in episodes)
    key = stable_id(STAGE_POSTTRAIN, *setup["key"], f"recipe {POSTTRAIN_RECIPE}", pre_id, phases.meaning(config),
                    camera or "*", *episode_ids)
    post_id = stable_id("checkpoint", key)
    folder = paths.resolve(root, paths.CHECKPOINT_DIR, model=model_config.name, checkpoint_id=post_id)
    stage = run.stage(STAGE_POSTTRAIN, key, [folder / checkpoints.WEIGHTS_FILE], manifest_hash=mh)
    if stage.done:
        return post_id, folder, [], 0
    inputs.check_episode_videos(run.warehouse, folders, camera, root)
    texts = {f: t for found, source in sources for f, t in inputs.episode_texts(run.warehouse, found, source).items()}
    futures = [encode_episode.submit(folder, tok_folder, tok_id, size, [camera] if camera else None,
                                     model_config.action_dim, texts[folder], root, config.action_totals)
               for folder in folders]
    sequences = [s for f in futures for s in f.result()]
    with progress(config.steps, f"post-train {preset_name} with actions (steps)", topic=ticks.WORLD_MODEL_STEPS):
        history, params = posttrain(pre_folder, sequences, config, folder,
                                    {"checkpoint_id": post_id, "pretrained_id": pre_id, "tokenizer_id": tok_id,
                                     "size": size, "episodes": [uri(f, root) for f in folders],
                                     "camera": camera, "tokenizer": uri(tok_folder, root)}, runtime)
    stage.finish(len(sequences), 1, checkpoints.checkpoint_lineage(
        post_id, folder, root,
        [(e, "trained_on") for e in episode_ids] + [(tok_id, "trained_on"), (pre_id, "posttrained_from")],
        history, stage.id, mh,
        {"model": "world_model", "phase": "posttrain", "preset": preset_name, "steps": config.steps,
         "params": params, "tokenizer_id": tok_id, "pretrained_id": pre_id, "camera": camera, **setup["attrs"]},
        metrics=setup["metrics"]), attrs={"checkpoint_id": post_id, "steps": config.steps})
    print(f"post-trained on {len(sequences)} episode videos for {config.steps} steps: {phases.scores(history)}")
    return post_id, folder, history, len(sequences)


@flow(name="train", log_prints=True)
def train(manifest: str, tokenizer: str | None = None, token_shards: str | None = None, preset_name: str = "tiny-wm",
          pretrain_steps: Steps = 200, posttrain_steps: Steps = 100, batch_size: Batch = 8,
          window: Window | None = None,
          camera: str | None = None, seed: Seed = 0, patch: Patch | None = None,
          change_weight: Weight = 0.0, self_condition: Share = 0.0,
          action_totals: ActionTotals = 0, also: list[str] | None = None, device: str | None = None,
          precision: Literal["fp32", "bf16"] = "fp32", compile_model: bool = False,
          family: Literal["autoregressive", "diffusion"] = "autoregressive") -> dict:
    """Pre-train world model ``preset_name`` on ``tokenizer``'s token shards (or ``token_shards``),
    then post-train it with actions on the simulated episodes of ``manifest`` (a YAML, an
    episode folder or a manifest hash), every camera or only ``camera``. ``patch``: codes per
    token side (default `token_patch`: at most 64 tokens per latent frame). ``change_weight``:
    extra loss weight on codes that change from one latent frame to the next. ``self_condition``:
    share of post-training windows that read the model's own rollout instead of the true frames
    (``tasks.world.train.own_inputs``). ``action_totals``: the first n action values also enter
    as running totals since the episode's start (3 for ``ee_delta``: where the hand was sent).
    ``also``: more manifests (or episode folders, or hashes) whose episodes join post-training,
    each with its own manifest's text (e.g. the same scene at a noisier controller, so the model
    sees pushes that fail). ``device``, ``precision``, ``compile_model``: where it trains
    (``tasks.device``; none of it enters a checkpoint's id). ``family`` ``diffusion``: the diffusion
    world model on a continuous tokenizer's latents, with a ``*-dwm`` preset."""
    checks = TrainParams.of(locals())  # every parameter check, for a deployment as for the CLI
    checks.check_tokenizer(tokenizer)
    runtime = checks.runtime()
    settings = Settings()
    root = settings.data_root.resolve()
    sources = [episode_folders(m, root) for m in [manifest, *(also or [])]]
    folders, scenario = [f for found, _ in sources for f in found], sources[0][1]
    checks.check_episodes(folders[0])
    threads = min(2, torch.get_num_threads())
    with recorded_run("train", settings, scenario, source_uri=manifest if scenario is not None else None,
                      params={"manifest": manifest, "tokenizer": tokenizer, "token_shards": token_shards,
                              "preset": preset_name, "pretrain_steps": pretrain_steps,
                              "posttrain_steps": posttrain_steps, "batch_size": batch_size, "window": window,
                              "camera": camera, "seed": seed, "patch": patch,
                              "change_weight": change_weight, "self_condition": self_condition,
                              "action_totals": action_totals, "also": also or [],
                              **({"family": family} if family != "autoregressive" else {})}) as run:
        variant = TOKENIZER_VARIANT[family]
        tok_folder, tok_id, tok_config = inputs.tokenizer_checkpoint(run.warehouse, root, tokenizer, variant)
        shards = inputs.token_shards(run.warehouse, root, tok_id, token_shards)
        sequences = load_tokens([p for p, _, _ in shards], root, variant)
        grid, size = inputs.shape(sequences)
        setup = phases.family_setup(family, preset_name, tok_config, grid, patch, window,
                                    (pretrain_steps, posttrain_steps), batch_size, seed, threads, change_weight,
                                    self_condition, action_totals)
        pre_id, pre_folder, pre_history = pretrain_phase(run, tok_folder, tok_id, shards, sequences, size, setup,
                                                         preset_name, runtime)
        post_id, post_folder, post_history, videos = posttrain_phase(
            run, sources, pre_id, pre_folder, tok_folder, tok_id, size, camera, setup, preset_name, runtime)

        body = (f"tokenizer `{tok_id}`, {len(shards)} token shards ({len(sequences)} sequences), "
                f"{len(folders)} episodes\n\n"
                f"### pre-training: `{pre_id}` under `{uri(pre_folder, root)}`\n\n{phases.curve(pre_history)}\n\n"
                f"### post-training with actions: `{post_id}` under `{uri(post_folder, root)}`\n\n"
                f"{phases.curve(post_history)}")
        publish("train", f"{preset_name}: pre-trained on {len(sequences)} sequences, post-trained on "
                f"{len(folders)} episodes", body, "world model pre- and post-training")
        summary = {"run_id": run.run_id, "tokenizer_id": tok_id, "pretrain_checkpoint_id": pre_id,
                   "pretrain_checkpoint": str(pre_folder), "posttrain_checkpoint_id": post_id,
                   "posttrain_checkpoint": str(post_folder), "pretrained": bool(pre_history),
                   "posttrained": bool(post_history), "sequences": len(sequences), "episodes": len(folders),
                   "episode_videos": videos,
                   "pretrain_loss": pre_history[-1]["loss"] if pre_history else None,
                   "posttrain_loss": post_history[-1]["loss"] if post_history else None}
    print(summary)
    return summary

"""train: a discrete tokenizer's token shards -> pre-train the world model with text -> encode a
manifest's simulated episodes with that tokenizer -> post-train with their actions. Both
checkpoints, their training curves and their edges (``trained_on`` the token shards or episodes
and the tokenizer, ``posttrained_from`` the pre-trained checkpoint) land in lineage; a finished
phase is skipped on a re-run."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import torch
from prefect import flow, task
from pydantic import Field

from flows.lookup import checkpoint_by_id, is_hex_id, tokenizer_condition, verified_checkpoint, verified_file
from flows.params import Batch, Seed, Share, Steps, Weight
from flows.recording import RunContext, recorded_run
from flows.report import markdown_table
from flows.report import publish as publish_report
from models.tokenizer import TokenizerConfig
from models.world_model import WorldModel, WorldModelConfig, preset
from schemas import paths
from schemas.errors import StepMissing
from schemas.hashing import content_hash, stable_id
from schemas.manifest import manifest_hash
from schemas.records import LineageBatch, StageRunRecord
from schemas.settings import Settings
from tasks import integrity, manifests
from tasks.checkpoint_files import CheckpointError
from tasks.tokenize import tokens
from tasks.world import checkpoints, data
from tasks.world.train import WorldTrainConfig, train_world_model
from tasks.world.train import posttrain as posttrain_model
from warehouse import integrity as claims

STAGE_PRETRAIN, STAGE_POSTTRAIN = "pretrain_world_model", "posttrain_world_model"
# Bumped when post-training learns something different from the same inputs, so an earlier
# checkpoint is not taken for a finished one. 2: actions divided by their RMS (action_scale).
POSTTRAIN_RECIPE = 2


def _uri(path: Path, root: Path) -> str:
    return path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)


def _known(run: RunContext, kind: str, path: Path, root: Path, what: str, hint: str) -> tuple[str, str | None]:
    """(artifact id, manifest hash) of an input file, hashed once and checked against lineage:
    TamperedArtifact when its bytes changed, InvalidInput (``hint``) when lineage never saw it."""
    artifact_id, mh, _ = verified_file(run.warehouse, root, path, kind, what, hint)
    return artifact_id, mh


def tokenizer_checkpoint(run: RunContext, tokenizer: str | None) -> tuple[Path, str, TokenizerConfig]:
    """(folder, artifact id, config) of a discrete tokenizer checkpoint: a checkpoint folder, a
    checkpoint id (its first 12+ hex digits), or None for the newest one in lineage with token shards."""
    folder, checkpoint_id = tokenizer_folder(run, tokenizer)
    config = tokens.load_checkpoint(folder).config
    if config.variant != "discrete":
        raise ValueError(f"tokenizer {checkpoint_id} is {config.variant}: the world model reads a discrete one's codes")
    return folder, checkpoint_id, config


def tokenizer_folder(run: RunContext, tokenizer: str | None, variant: str | None = "discrete") -> tuple[Path, str]:
    """(folder, artifact id) of a tokenizer checkpoint, its weights checked against lineage: a folder,
    an id prefix of one of ``variant`` (any variant when None) in lineage, or None for the newest
    one with token shards."""
    root = run.settings.data_root.resolve()
    if tokenizer and Path(tokenizer).is_dir():
        folder = Path(tokenizer).resolve()
        if not (folder / tokens.CONFIG_FILE).is_file():
            raise FileNotFoundError(f"{tokenizer}: not a tokenizer checkpoint folder (no {tokens.CONFIG_FILE})")
        if not (folder / tokens.WEIGHTS_FILE).is_file():
            raise CheckpointError(f"{folder}: no {tokens.WEIGHTS_FILE}")
        checkpoint_id, _ = _known(run, "checkpoint", folder / tokens.WEIGHTS_FILE, root, "tokenizer checkpoint",
                                  "train on a tokenizer `worldline tokenize` trained")
        return folder, checkpoint_id
    if tokenizer and not is_hex_id(tokenizer):
        raise FileNotFoundError(f"{tokenizer}: no such checkpoint folder, and not a checkpoint id")
    which = tokenizer_condition(variant)
    if tokenizer:
        checkpoint_id, uri = checkpoint_by_id(run.warehouse, tokenizer, which,
                                              f"{variant} tokenizer" if variant else "tokenizer", root)
        return integrity.path_of(uri, root).parent, checkpoint_id
    _, rows = run.warehouse.query(f"SELECT artifact_id FROM artifacts WHERE kind = 'checkpoint' AND {which} AND "
                                  "artifact_id IN (SELECT parent_id FROM edges WHERE relation = 'encoded_by') "
                                  "ORDER BY recorded_at DESC, artifact_id LIMIT 1")
    if not rows:
        raise StepMissing("no discrete tokenizer with token shards in lineage: run `worldline tokenize` first")
    checkpoint_id, uri = checkpoint_by_id(run.warehouse, rows[0][0], which, "tokenizer", root)
    return integrity.path_of(uri, root).parent, checkpoint_id


def token_inputs(run: RunContext, tokenizer_id: str, token_shards: str | None):
    """(token shards as (path, artifact id, manifest hash), their sequences, latent grid, frame size)
    of a token shard folder, or by default the tokenizer's own token shards."""
    root = run.settings.data_root.resolve()
    place = Path(token_shards) if token_shards else \
        paths.resolve(root, paths.TOKEN_SHARD_FILE, tokenizer_id=tokenizer_id, index=0).parent
    files = data.find_shards([place])
    if not files:
        raise StepMissing(f"{place}: no token shards (run `worldline tokenize` first)")
    shards = [(path, *_known(run, "token_shard", path, root, "token shard",
                             "train reads token shards `worldline tokenize` wrote")) for path in files]
    check_sources(run, [s for _, s, _ in shards], root)
    sequences = load_tokens(files, root)
    grids = {s.codes.shape[1:] for s in sequences}
    sizes = {s.info["size"] for s in sequences}
    if len(grids) != 1 or len(sizes) != 1:
        raise ValueError(f"token shards mix latent grids {sorted(grids)} or frame sizes {sorted(sizes)}")
    return shards, sequences, grids.pop(), sizes.pop()


def check_sources(run: RunContext, token_ids: list[str], root: Path) -> None:
    """The curated shards the token shards' captions come from, checked against lineage where
    they are still there (a shard gone since is read as no captions, as before)."""
    for row in claims.parents(run.warehouse, token_ids, "tokens_of"):
        source = integrity.Recorded(*row)
        if (path := integrity.path_of(source.uri, root)).is_file():
            integrity.check(path, source)


def check_episode_videos(run: RunContext, folders: list[Path], camera: str | None, root: Path) -> None:
    """Each camera video post-training will encode, checked against lineage before it is read."""
    for folder in folders:
        for name in [camera] if camera else data.read_meta(folder).get("cameras", []):
            if (video := folder / f"{name}.mp4").is_file():
                _known(run, "episode_video", video, root, "episode video", "post-train on `worldline simulate`'s episodes")


def episode_folders(manifest: str, root: Path):
    """(episode folders, scenario or None) of a manifest YAML, an episode folder or a manifest hash."""
    scenario = None
    place = Path(manifest)
    if place.is_file():
        scenario = manifests.load(place)
        place = paths.resolve(root, paths.EPISODES_OF_MANIFEST, manifest_hash=manifest_hash(scenario))
    elif not place.exists() and is_hex_id(manifest):
        place = paths.resolve(root, paths.EPISODES_OF_MANIFEST, manifest_hash=manifest)
    found = data.episode_dirs(place)
    if not found:
        raise StepMissing(f"{manifest}: no simulated episodes under {place} (run `worldline simulate` first)")
    return found, scenario


def _episode_texts(run: RunContext, folders: list[Path], scenario) -> dict[Path, str | None]:
    """The manifest's instruction and stressor kinds per episode, where the manifest is known."""
    texts: dict[Path, str | None] = {}
    for folder in folders:
        body = scenario.model_dump(mode="json") if scenario is not None else None
        if body is None:
            _, rows = run.warehouse.query("SELECT body FROM manifests WHERE manifest_hash = $mh",
                                          {"mh": data.read_meta(folder).get("manifest_hash", "")})
            body = json.loads(rows[0][0]) if rows else None
        texts[folder] = None if body is None else data.episode_text(body["task"]["instruction"],
                                                                    [s["kind"] for s in body.get("stressors", [])])
    return texts


@task(name="load-token-shards", retries=1)
def load_tokens(files: list[Path], root: Path) -> list[data.CodeSequence]:
    return data.load_token_sequences(files, root)


@task(name="encode-episode", retries=1)
def encode_episode(directory: Path, tokenizer_folder: Path, tokenizer_id: str, size: int, cameras: list[str] | None,
                   action_dim: int, text: str | None, root: Path, totals: int = 0) -> list[data.CodeSequence]:
    """Every camera (or the ones named) of one episode as codes with aligned actions (cached under root)."""
    tokenizer = tokens.load_checkpoint(tokenizer_folder)
    return data.load_episodes([directory], tokenizer, size, cameras, action_dim, text, tokenizer_id, root, totals)


def _tensorboard(folder: Path):
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(folder / "tensorboard"))

    def log(record: dict) -> None:
        for name in ("loss", "accuracy", "copy_accuracy", "lr"):
            writer.add_scalar(f"train/{name}", record[name], record["step"])
    return writer, log


@task(name="pretrain-world-model")
def pretrain(sequences: list[data.CodeSequence], model_config: WorldModelConfig, config: WorldTrainConfig,
             folder: Path, extra: dict) -> tuple[list[dict], int]:
    """Train from seeded initial weights on codes and text, log to TensorBoard beside the
    checkpoint, save it; returns the history and the parameter count."""
    torch.manual_seed(config.seed)
    model = WorldModel(model_config)
    writer, log = _tensorboard(folder)
    with writer:
        history = train_world_model(model, sequences, config, log)
    checkpoints.save_checkpoint(model, folder, {"phase": "pretrain", "train": config.model_dump(mode="json"), **extra})
    return history, sum(p.numel() for p in model.parameters())


@task(name="posttrain-world-model")
def posttrain(pretrained: Path, episodes: list[data.CodeSequence], config: WorldTrainConfig, folder: Path,
         extra: dict) -> tuple[list[dict], int]:
    """Load the pre-trained checkpoint, add the zero-initialised action encoder, train on episodes, save."""
    writer, log = _tensorboard(folder)
    with writer:
        model, history = posttrain_model(checkpoints.load_checkpoint(pretrained), episodes, config, log)
    checkpoints.save_checkpoint(model, folder, {"phase": "posttrain", "train": config.model_dump(mode="json"), **extra})
    return history, sum(p.numel() for p in model.parameters())


def _meaning(config: WorldTrainConfig) -> str:
    # Threads change float summation order, not what is trained: the same run elsewhere is skipped.
    # A field added later is left out at its default, so checkpoints trained before it keep their ids.
    unset = {name for name in ("self_condition", "action_totals") if not getattr(config, name)}
    return content_hash(config.model_dump(mode="json", exclude={"threads", *unset}))


def _stage(run: RunContext, stage: str, key: str, n_in: int, n_out: int, t0: float, mh: str | None, **attrs):
    return StageRunRecord(stage_run_id=run.stage_run_id(stage, key), run_id=run.run_id, stage=stage, input_key=key,
                          manifest_hash=mh, n_in=n_in, n_out=n_out, seconds=round(time.perf_counter() - t0, 3),
                          attrs=attrs)


def _curve(history: list[dict]) -> str:
    rows = [(h["step"], f"{h['seconds']:.1f}", f"{h['loss']:.4f}", f"{h['accuracy']:.3f}", f"{h['copy_accuracy']:.3f}")
            for h in history]
    return markdown_table(("step", "seconds", "loss (nats)", "next-frame accuracy", "copy-frame accuracy"), rows) \
        if rows else "skipped: done before"


def token_patch(grid_h: int, grid_w: int, max_tokens: int = 64) -> int:
    """The smallest patch side dividing the latent grid that keeps a frame at ``max_tokens``
    transformer tokens or fewer (1 for the 8 x 8 grid of 64 x 64 frames, 2 for 16 x 16)."""
    for q in range(1, min(grid_h, grid_w) + 1):
        if grid_h % q == 0 and grid_w % q == 0 and (grid_h // q) * (grid_w // q) <= max_tokens:
            return q
    return 1


@flow(name="train", log_prints=True)
def train(manifest: str, tokenizer: str | None = None, token_shards: str | None = None, preset_name: str = "tiny-wm",
          pretrain_steps: Steps = 200, posttrain_steps: Steps = 100, batch_size: Batch = 8,
          window: Annotated[int, Field(ge=2, le=64)] | None = None,
          camera: str | None = None, seed: Seed = 0, patch: Annotated[int, Field(ge=1, le=16)] | None = None,
          change_weight: Weight = 0.0, self_condition: Share = 0.0,
          action_totals: Annotated[int, Field(ge=0, le=8)] = 0, also: list[str] | None = None) -> dict:
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
    sees pushes that fail)."""
    settings = Settings()
    root = settings.data_root.resolve()
    sources = [episode_folders(m, root) for m in [manifest, *(also or [])]]
    folders, scenario = [f for found, _ in sources for f in found], sources[0][1]
    threads = min(2, torch.get_num_threads())
    with recorded_run("train", settings, scenario, source_uri=manifest if scenario is not None else None,
                      params={"manifest": manifest, "tokenizer": tokenizer, "token_shards": token_shards,
                              "preset": preset_name, "pretrain_steps": pretrain_steps,
                              "posttrain_steps": posttrain_steps, "batch_size": batch_size, "window": window,
                              "camera": camera, "seed": seed, "patch": patch,
                              "change_weight": change_weight, "self_condition": self_condition,
                              "action_totals": action_totals, "also": also or []}) as run:
        tok_folder, tok_id, tok_config = tokenizer_checkpoint(run, tokenizer)
        shards, sequences, (grid_h, grid_w), size = token_inputs(run, tok_id, token_shards)
        hashes = {mh for *_, mh in shards if mh}
        pre_mh = hashes.pop() if len(hashes) == 1 else None
        model_config = preset(preset_name, codebook_size=tok_config.codebook_size, max_height=grid_h, max_width=grid_w,
                              temporal_compression=tok_config.temporal_compression,
                              patch=patch or token_patch(grid_h, grid_w),
                              **({"max_frames": window} if window else {}))
        pre_config = WorldTrainConfig(preset=preset_name, steps=pretrain_steps, batch_size=batch_size, seed=seed,
                                      threads=threads, change_weight=change_weight)
        post_config = WorldTrainConfig(preset=preset_name, steps=posttrain_steps, batch_size=batch_size, seed=seed,
                                       threads=threads, lr=pre_config.lr / 2, warmup_steps=10,
                                       change_weight=change_weight, self_condition=self_condition,
                                       action_totals=action_totals)

        # -- pre-training: token sequences with their captions
        t0 = time.perf_counter()
        shard_ids = sorted(s for _, s, _ in shards)
        key = stable_id(STAGE_PRETRAIN, content_hash(model_config), _meaning(pre_config), tok_id, *shard_ids)
        pre_id = stable_id("checkpoint", key)
        pre_folder = paths.resolve(root, paths.CHECKPOINT_DIR, model=model_config.name, checkpoint_id=pre_id)
        pre_history: list[dict] = []
        if run.pending(STAGE_PRETRAIN, [key]) or not (pre_folder / checkpoints.WEIGHTS_FILE).exists():
            pre_history, params = pretrain(sequences, model_config, pre_config, pre_folder,
                                           {"checkpoint_id": pre_id, "tokenizer_id": tok_id, "size": size,
                                            "tokenizer": _uri(tok_folder, root),
                                            "token_shards": [_uri(p, root) for p, _, _ in shards]})
            stage = _stage(run, STAGE_PRETRAIN, key, len(sequences), 1, t0, pre_mh, checkpoint_id=pre_id,
                           steps=pretrain_steps)
            run.write(LineageBatch(stage_runs=[stage]).extend(checkpoints.checkpoint_lineage(
                pre_id, pre_folder, root, [(s, "trained_on") for s in shard_ids] + [(tok_id, "trained_on")],
                pre_history, stage.stage_run_id, pre_mh,
                {"model": "world_model", "phase": "pretrain", "preset": preset_name, "steps": pretrain_steps,
                 "params": params, "tokenizer_id": tok_id})))
            print(f"pre-trained {preset_name} on {len(sequences)} token sequences for {pretrain_steps} steps: "
                  f"loss {pre_history[-1]['loss']:.3f}, accuracy {pre_history[-1]['accuracy']:.3f}")
        else:  # trained by an earlier run: post-training reads it, so it must still be those bytes
            verified_checkpoint(run.warehouse, root, pre_folder)

        # -- post-training: episodes with their actions, from the pre-trained weights
        t0 = time.perf_counter()
        episodes = [(folder, *_known(run, "episode", folder / "steps.parquet", root, "episode",
                                     "post-train on `worldline simulate`'s episodes")) for folder in folders]
        episode_hashes = {mh for *_, mh in episodes if mh}
        post_mh = run.manifest_hash or (episode_hashes.pop() if len(episode_hashes) == 1 else None)
        episode_ids = sorted(e for _, e, _ in episodes)
        pkey = stable_id(STAGE_POSTTRAIN, f"recipe {POSTTRAIN_RECIPE}", pre_id, _meaning(post_config), camera or "*",
                         *episode_ids)
        post_id = stable_id("checkpoint", pkey)
        post_folder = paths.resolve(root, paths.CHECKPOINT_DIR, model=model_config.name, checkpoint_id=post_id)
        post_history: list[dict] = []
        episode_sequences: list[data.CodeSequence] = []
        if run.pending(STAGE_POSTTRAIN, [pkey]) or not (post_folder / checkpoints.WEIGHTS_FILE).exists():
            check_episode_videos(run, folders, camera, root)
            texts = {f: t for found, source in sources for f, t in _episode_texts(run, found, source).items()}
            futures = [encode_episode.submit(folder, tok_folder, tok_id, size, [camera] if camera else None,
                                             model_config.action_dim, texts[folder], root, post_config.action_totals)
                       for folder in folders]
            episode_sequences = [s for f in futures for s in f.result()]
            post_history, params = posttrain(pre_folder, episode_sequences, post_config, post_folder,
                                             {"checkpoint_id": post_id, "pretrained_id": pre_id, "tokenizer_id": tok_id,
                                              "size": size, "episodes": [_uri(f, root) for f in folders],
                                              "camera": camera, "tokenizer": _uri(tok_folder, root)})
            stage = _stage(run, STAGE_POSTTRAIN, pkey, len(episode_sequences), 1, t0, post_mh, checkpoint_id=post_id,
                           steps=posttrain_steps)
            run.write(LineageBatch(stage_runs=[stage]).extend(checkpoints.checkpoint_lineage(
                post_id, post_folder, root,
                [(e, "trained_on") for e in episode_ids] + [(tok_id, "trained_on"), (pre_id, "posttrained_from")],
                post_history, stage.stage_run_id, post_mh,
                {"model": "world_model", "phase": "posttrain", "preset": preset_name, "steps": posttrain_steps,
                 "params": params, "tokenizer_id": tok_id, "pretrained_id": pre_id, "camera": camera})))
            print(f"post-trained on {len(episode_sequences)} episode videos for {posttrain_steps} steps: "
                  f"loss {post_history[-1]['loss']:.3f}, accuracy {post_history[-1]['accuracy']:.3f}")

        body = (f"tokenizer `{tok_id}`, {len(shards)} token shards ({len(sequences)} sequences), "
                f"{len(folders)} episodes\n\n"
                f"### pre-training: `{pre_id}` under `{_uri(pre_folder, root)}`\n\n{_curve(pre_history)}\n\n"
                f"### post-training with actions: `{post_id}` under `{_uri(post_folder, root)}`\n\n{_curve(post_history)}")
        publish_report("train", f"{preset_name}: pre-trained on {len(sequences)} sequences, post-trained on "
                       f"{len(folders)} episodes", body, "world model pre- and post-training")
        summary = {"run_id": run.run_id, "tokenizer_id": tok_id, "pretrain_checkpoint_id": pre_id,
                   "pretrain_checkpoint": str(pre_folder), "posttrain_checkpoint_id": post_id,
                   "posttrain_checkpoint": str(post_folder), "pretrained": bool(pre_history),
                   "posttrained": bool(post_history), "sequences": len(sequences), "episodes": len(folders),
                   "episode_videos": len(episode_sequences),
                   "pretrain_loss": pre_history[-1]["loss"] if pre_history else None,
                   "posttrain_loss": post_history[-1]["loss"] if post_history else None}
    print(summary)
    return summary

"""train-transfer: a manifest's simulator pairs -> a transfer model (checkpoint, curves, a
`transfer_model` in lineage). transfer: simulated episodes x looks -> the same episodes in those
looks under transfer/, labels copied unchanged, each clip through both guards and in lineage
(docs/transfer.md). A finished stage is skipped on a re-run."""

from __future__ import annotations

from pathlib import Path

import torch
from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.params import Side, Steps
from flows.params_transfer import TrainTransferParams, TransferParams, seed_list
from flows.recording import recorded_run
from flows.report import markdown_table, publish
from models.transfer import preset
from schemas import paths
from schemas.hashing import content_hash, sha256_file, stable_id
from schemas.settings import Settings
from tasks import manifests
from tasks.checkpoint_files import WEIGHTS_FILE
from tasks.guard.config import GuardConfig
from tasks.transfer import apply, lineage, pairs, train
from tasks.video.write import write_mp4

STAGE_TRAIN, STAGE_TRANSFER = "train_transfer", "transfer"
# Generated footage at the model's size: search every 5th frame for faces of 20 px and more,
# as panels do.
TRANSFER_GUARD = GuardConfig(detect_every=5)

load_manifest = task(manifests.load, name="load-manifest")
# Inputs are manifests, clips and models: hashing them for a cache key would cost more than it saves.
simulate_pairs = task(pairs.make_pairs, name="transfer-pairs", cache_policy=NO_CACHE)
fit = task(train.train_and_save, name="train-transfer-model", cache_policy=NO_CACHE)
make_controls = task(apply.source_clip, name="transfer-controls", retries=1, cache_policy=NO_CACHE)
generate = task(apply.guarded_clip, name="transfer-generate", cache_policy=NO_CACHE)
write_video = task(write_mp4, name="write-transfer-video", retries=1, cache_policy=NO_CACHE)


@flow(name="train-transfer", log_prints=True)
def train_transfer(manifest: str, seeds: str = "9", preset_name: str = "small-palette", steps: Steps = 2000,
                   seconds: float | None = None, temporal: float = 1.0, size: Side = 64, camera: str | None = None,
                   device: str | None = None) -> dict:
    """Train transfer model ``preset_name`` on ``manifest``'s pairs (each seed of ``seeds`` in
    every look, ``camera`` at ``size`` x ``size``) for ``steps`` or ``seconds``, with the temporal
    loss at ``temporal``, on ``device`` (``tasks.device``: it enters no id)."""
    checks = TrainTransferParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    root = settings.data_root.resolve()
    scenario = load_manifest(Path(manifest))
    cam = checks.check_scenario(scenario)
    seed_ids, model_config = seed_list(seeds), preset(preset_name)
    config = train.TrainConfig(preset=preset_name, steps=steps, seconds=seconds, temporal=temporal,
                               threads=min(2, torch.get_num_threads()))
    params = {"manifest": manifest, "seeds": list(seed_ids), "preset": preset_name, "steps": steps,
              "seconds": seconds, "temporal": temporal, "size": size, "camera": cam}
    with recorded_run("train-transfer", settings, scenario, source_uri=manifest, params=params) as run:
        key = stable_id(STAGE_TRAIN, content_hash(model_config), content_hash(config), scenario.sha256, cam, str(size),
                        *map(str, seed_ids))
        checkpoint_id = stable_id("checkpoint", key)
        folder = paths.resolve(root, paths.CHECKPOINT_DIR, model=f"transfer-{model_config.name}",
                               checkpoint_id=checkpoint_id)
        stage = run.stage(STAGE_TRAIN, key, [folder / WEIGHTS_FILE])
        history: list[dict] = []
        if not stage.done:
            made = simulate_pairs(scenario, seed_ids, size=size, camera=cam)
            extra = {"checkpoint_id": checkpoint_id, "size": size, "camera": cam, "manifest_hash": scenario.sha256,
                     "seeds": list(seed_ids)}
            history, n_params = fit(made, config, folder, extra, device)
            stage.finish(len(made), 1, lineage.model_lineage(
                checkpoint_id, folder, root, scenario.sha256, history, stage.id,
                {"preset": preset_name, "steps": steps, "size": size, "camera": cam, "seeds": list(seed_ids),
                 "params": n_params}), attrs={"checkpoint_id": checkpoint_id, "pairs": len(made)})
        rows = [(h["step"], f"{h['seconds']:.1f}", f"{h['loss']:.4f}", f"{h['psnr']:.2f}") for h in history]
        publish("train-transfer", f"{preset_name} on {scenario.name}, {len(seed_ids)} seeds",
                f"checkpoint `{checkpoint_id}` under `{folder.relative_to(root).as_posix()}`\n\n"
                + (markdown_table(("step", "seconds", "L1 loss", "train PSNR dB"), rows) if rows
                   else "training skipped: done before"), "transfer model training")
        print(f"transfer model {checkpoint_id[:12]} ({preset_name}): "
              + (f"loss {history[-1]['loss']:.4f}, train PSNR {history[-1]['psnr']:.2f} dB" if history
                 else "trained before"))
        return {"run_id": run.run_id, "checkpoint_id": checkpoint_id, "checkpoint": str(folder),
                "trained": bool(history), "final_loss": history[-1]["loss"] if history else None,
                "final_psnr": history[-1]["psnr"] if history else None}


@flow(name="transfer", log_prints=True)
def transfer(source: str, look: str, model: str | None = None, camera: str | None = None,
             weights: str | None = None, reference: str | None = None, device: str | None = None) -> dict:
    """Each camera clip of ``source`` (an episode folder, or a manifest YAML or hash: every episode
    simulated of it) in each look of ``look`` by transfer checkpoint ``model`` (a folder, an id,
    or the newest trained), controls weighted by ``weights``, taking ``reference``'s look if given;
    the labels copied unchanged beside each clip."""
    checks = TransferParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    root = settings.data_root.resolve()
    folder, info, sources = checks.check_inputs(root, flow=True)  # before anything is written
    looks, control_weights, size = apply.parse_looks(look), apply.parse_weights(weights), info["size"]
    where = checks.torch_device()
    written, done = [], 0
    params = {"source": source, "model": str(folder), "look": list(looks), "camera": camera,
              "weights": control_weights, "reference": reference}
    look_of, reference_sha = None, None
    if reference:
        look_of = apply.reference_look(reference, size, apply.model_info(folder)[0])
        reference_sha = sha256_file(reference)
    with recorded_run("transfer", settings, params=params) as run:
        model_in = lineage.model_inputs(run.warehouse, root, folder)  # its bytes checked before it is loaded
        net = train.load_transfer(folder).to(where)
        setting = apply.setting_id(model_in.model_sha, control_weights, reference_sha)
        for src in sources:
            inputs = lineage.episode_inputs(run.warehouse, root, model_in, src.video, src.controls)
            clip = None
            for name in looks:
                out = apply.output_paths(root, src, name, setting)
                key = apply.stage_key(inputs.video_sha, src.camera, name, setting, size)
                stage = run.stage(STAGE_TRANSFER, key, out.values(), manifest_hash=src.meta.get("manifest_hash"))
                if stage.done:
                    done += 1
                    continue
                clip = clip if clip is not None else make_controls(src, size)
                frames, faces = generate(net, clip, name, control_weights, TRANSFER_GUARD, where, look_of)
                video = write_video(out["video"], frames, apply.fps_of(src.video))
                apply.write_labels(src, out, root, {"look": name, "model_id": inputs.model_id, "size": size,
                                                    "weights": control_weights, "reference_sha256": reference_sha})
                _, batch = lineage.transferred_lineage(
                    video, key, inputs, root, stage.id, stage.manifest_hash, name, faces, TRANSFER_GUARD,
                    {"camera": src.camera, "index": src.meta.get("index"), "frames": len(frames), "size": size,
                     "weights": control_weights, "source_episode": paths.escaped(str(src.folder)),
                     "reference_sha256": reference_sha})
                stage.finish(1, 1, batch, attrs={"look": name, "camera": src.camera, "video": out["video"].name})
                written.append(video)
        summary = (f"{len(sources)} episodes x {len(looks)} looks: {len(written)} clips written, "
                   f"{done} done before")
        publish("transfer", summary, "\n".join(f"- `{paths.escaped(str(p))}`" for p in written),
                "episodes transferred to other looks")
        print(summary)
        return {"episodes": len(sources), "looks": list(looks), "model_id": model_in.model_id,
                "written": [str(p) for p in written], "done_before": done}

"""train-policy: scripted demonstrations of a manifest -> a behaviour-cloning policy (safetensors
checkpoint) -> its success on held-out seeds. Checkpoint, training loss and held-out success
land in lineage; a finished training is skipped on a re-run.

A state policy reads the simulator (tasks/policy/features.py); with ``observe`` a vision policy
sees the named cameras and the robot's proprioception only, and DAgger rounds follow its
behaviour cloning (tasks/policy/vision.py); with ``encoder`` ``tokenizer:CHECKPOINT`` it sees
through that tokenizer's encoder, frozen, instead of its own convolutions (lineage edge
``encoder_from``).

Seeds: demonstrations use seed+1000 .. seed+1000+episodes-1, DAgger rounds seed+1500 onwards
and the held-out check seed+2000 onwards, so none overlaps the seeds panels use by default
(seed, seed+1, ...)."""

from __future__ import annotations

from pathlib import Path

from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.params import Episodes, Holdout, Seed, Side, Steps
from flows.params_policy import TrainPolicyParams
from flows.recording import recorded_run
from flows.report import markdown_table, publish
from schemas import paths
from schemas.hashing import content_hash, stable_id
from schemas.records import MetricRecord
from schemas.settings import Settings
from tasks import manifests
from tasks.checkpoint_files import CONFIG_FILE
from tasks.lookup import verified_file
from tasks.policy import bc, vision, vision_train
from tasks.policy.features import FEATURES_VERSION
from tasks.policy.lineage import checkpoint_lineage
from tasks.policy.vision import VisionPolicy
from tasks.tokenize import tokens
from tasks.world import inputs

STAGE = "train_policy"
TRAIN_OFFSET, DAGGER_OFFSET, HOLDOUT_OFFSET = 1000, 1500, 2000

load_manifest = task(manifests.load, name="load-manifest")
collect = task(bc.collect, name="collect-demonstrations", retries=1, cache_policy=NO_CACHE)
held_out = task(bc.success_rate, name="held-out-success", cache_policy=NO_CACHE)


@task(name="train-bc", cache_policy=NO_CACHE)
def train(demos: bc.Demonstrations, config: bc.TrainConfig, folder: Path, scenario, extra: dict, device="cpu"):
    model, history = bc.train_bc(demos, config, device=device)
    bc.save_checkpoint(model, folder, scenario, config, extra)
    return model, history


@task(name="train-vision-dagger", cache_policy=NO_CACHE)
def train_seeing(scenario, spec, seeds: list[int], rounds: list[list[int]], config: bc.TrainConfig, folder: Path,
                 extra: dict, device="cpu", tokenizer=None, layer: str = "latent",
                 gate: float | None = vision_train.DAGGER_GATE):
    """Behaviour cloning on the expert's camera demonstrations, then DAgger rounds (``gate``
    None: plain DAgger)."""
    demos = vision.collect(scenario, seeds, spec)
    model, history = vision_train.train_vision(demos, spec, config, device=device, tokenizer=tokenizer, layer=layer)
    model, demos, more = vision_train.dagger(scenario, spec, demos, model, rounds, config, offset=config.steps,
                                             device=device, gate=gate, loss=history[-1]["loss"])
    learner = sorted({(row["round"], row["learner_success"]) for row in more})
    taken = {row["round"]: row["interventions"] for row in more}
    vision_train.save_checkpoint(model, spec, folder, scenario, config, {
        **extra, "demonstrations": int(len(demos.act)), "successes": sum(demos.successes[:len(seeds)]),
        "dagger_gate": gate, "dagger_rounds": [{"round": k, "seeds": rounds[k - 1], "learner_success": r,
                                                "interventions": taken[k]} for k, r in learner]})
    return history + more, learner


@flow(name="train-policy", log_prints=True)
def train_policy(manifest: str, episodes: Episodes = 30, steps: Steps = 3000, preset_name: str = "tiny", seed: Seed = 0,
                 holdout: Holdout = 10, observe: str | None = None, image_size: Side = 64, dagger: int = 0,
                 dagger_gate: float = vision_train.DAGGER_GATE, encoder: str = "cnn", encoder_layer: str = "latent",
                 shift: int = 0, device: str | None = None) -> dict:
    """Behaviour-clone the scripted controller of ``manifest`` from ``episodes`` demonstrations;
    with ``observe``, a vision policy on those cameras, then ``dagger`` DAgger rounds, gated at
    ``dagger_gate`` (0: plain DAgger).
    ``device``: where the network trains (``tasks.device``; not part of the checkpoint's id)."""
    checks = TrainPolicyParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    root = settings.data_root.resolve()
    scenario = load_manifest(Path(manifest))
    checks.check_scenario(scenario)
    spec, on = checks.spec(), checks.torch_device()
    config = bc.TrainConfig(preset=preset_name, steps=steps, seed=seed, batch_size=64 if spec else 256, shift=shift)
    train_seeds = list(range(scenario.seed + TRAIN_OFFSET, scenario.seed + TRAIN_OFFSET + episodes))
    test_seeds = list(range(scenario.seed + HOLDOUT_OFFSET, scenario.seed + HOLDOUT_OFFSET + holdout))
    per_round = max(4, episodes // 2)
    rounds = [list(range(scenario.seed + DAGGER_OFFSET + k * per_round, scenario.seed + DAGGER_OFFSET + (k + 1) * per_round))
              for k in range(dagger)] if spec else []
    with recorded_run("train-policy", settings, scenario, source_uri=manifest,
                      params={"manifest": manifest, "episodes": episodes, "steps": steps, "preset": preset_name,
                              "seed": seed, "holdout": holdout, "observe": observe, "image_size": image_size,
                              "dagger": dagger, "dagger_gate": dagger_gate, "encoder": encoder,
                              "encoder_layer": encoder_layer, **({"shift": shift} if shift else {})}) as run:
        tok_id, tokenizer = None, None
        if checks.tokenizer():
            tok_folder, tok_id = inputs.tokenizer_folder(run.warehouse, root, checks.tokenizer(), None)
            checks.check_tokenizer(str(tok_folder))  # a deployment's run, as the CLI before it starts
            tokenizer = tokens.load_checkpoint(tok_folder)
        seen = [content_hash(spec.model_dump(mode="json")), *map(str, sum(rounds, []))] if spec else []
        seen += ["tokenizer", tok_id, encoder_layer] if tok_id else []
        gate = dagger_gate or None  # 0: plain DAgger
        seen += ["dagger_gate", str(gate)] if rounds else []
        key = stable_id(STAGE, run.manifest_hash, content_hash(config), str(FEATURES_VERSION), *map(str, train_seeds), *seen)
        checkpoint_id = stable_id("checkpoint", key)
        model_name = "vision-policy" if spec else "bc-policy"
        folder = paths.resolve(root, paths.CHECKPOINT_DIR, model=model_name, checkpoint_id=checkpoint_id)
        history, rate, outcomes = [], None, []
        stage = run.stage(STAGE, key, [folder / bc.WEIGHTS_FILE])
        if not stage.done:
            extra = {"checkpoint_id": checkpoint_id, "train_seeds": train_seeds}
            if spec:
                history, learner = train_seeing(scenario, spec, train_seeds, rounds, config, folder, extra, on,
                                                tokenizer, encoder_layer, gate)
                policy = VisionPolicy.from_checkpoint(folder)
            else:
                demos = collect(scenario, train_seeds)
                model, history = train(demos, config, folder, scenario,
                                       {**extra, "demonstrations": int(len(demos.obs)), "successes": sum(demos.successes)},
                                       on)
                policy, learner = bc.BCPolicy.from_checkpoint(folder), []
            rate, outcomes = held_out(scenario, policy, test_seeds) if test_seeds else (None, [])
            attrs = {"preset": preset_name, "steps": steps, "train_seeds": train_seeds, "held_out_seeds": test_seeds,
                     "held_out_success_rate": rate, "config": (folder / CONFIG_FILE).relative_to(root).as_posix()}
            if spec:
                attrs |= {"observe": list(spec.cameras), "image_size": spec.image_size, "dagger_seeds": rounds,
                          "dagger_learner_success": [r for _, r in learner], "encoder": "tokenizer" if tok_id else "cnn"}
                attrs |= {"dagger_gate": gate} if rounds else {}
                attrs |= {"shift": shift} if shift else {}
                attrs |= {"tokenizer_id": tok_id, "encoder_layer": encoder_layer} if tok_id else {}
            batch = checkpoint_lineage(checkpoint_id, folder / bc.WEIGHTS_FILE, root, stage.id, run.manifest_hash,
                                       {"model": model_name, **attrs},
                                       [(run.manifest_hash, "trained_on")] + ([(tok_id, "encoder_from")] if tok_id else []),
                                       "train_loss", history)
            if rate is not None:
                batch.metrics.append(MetricRecord(subject_id=checkpoint_id, name="held_out_success_rate", value=rate,
                                                  stage_run_id=stage.id, manifest_hash=run.manifest_hash,
                                                  attrs={"seeds": test_seeds}))
            stage.finish(episodes, 1, batch, attrs={"checkpoint_id": checkpoint_id, "steps": steps})
        else:  # trained before: handed back only while its weights are the ones lineage recorded (else exit 5)
            verified_file(run.warehouse, root, folder / bc.WEIGHTS_FILE, "checkpoint", "policy checkpoint")
        rows = [(s, "success" if ok else "failure", why) for s, ok, why in outcomes]
        publish("train-policy", f"checkpoint {checkpoint_id}" + ("" if rate is None else f", held-out success {rate:.2f}"),
                markdown_table(("held-out seed", "outcome", "reason"), rows), "behaviour-cloning policy and its held-out success")
        print(f"checkpoint {checkpoint_id} under {folder}" + ("" if not history else
              f": loss {history[0]['loss']:.4f} -> {history[-1]['loss']:.4f}, held-out success {rate}"))
        return {"checkpoint_id": checkpoint_id, "folder": str(folder), "held_out_success_rate": rate,
                "history": history, "held_out": outcomes, "manifest_hash": run.manifest_hash}

"""`worldline tokenize`, `train` and `evaluate physics`: the world model."""

from __future__ import annotations

from pathlib import Path

from flows import cli_checks as need
from flows.cli_command import command
from flows.cli_shell import app, evaluate_app, fail, out, refuse, writing
from flows.params_world import CameraParams, PhysicsParams, RigParams, TokenizeParams, TrainParams
from schemas.settings import Settings


def _is_yaml(name: str) -> bool:
    return Path(name).suffix in (".yaml", ".yml")


@command(app, TokenizeParams)
def tokenize(params: TokenizeParams) -> None:
    """Train a video tokenizer on curated shards and write token shards (Prefect flow `tokenize`)."""
    if params.init:
        need.tokenizer(params.init, variant=None)
    from flows.tokenize import shard_files
    from flows.tokenize import tokenize as tokenize_flow

    try:
        shard_files(params.shards, Settings().data_root.resolve())
    except FileNotFoundError as exc:
        fail(str(exc))
    writing()
    try:
        result = tokenize_flow(**params.model_dump())
    except (FileNotFoundError, ValueError) as exc:
        refuse(exc)
    psnr = f", train PSNR {result['final_psnr']:.2f} dB" if result["final_psnr"] is not None else " (already trained)"
    out.print(f"checkpoint {result['checkpoint_id']}{psnr}; {len(result['token_shards'])} new token shards "
              f"from {result['clips']} clips", highlight=False)


@command(app, TrainParams)
def train(params: TrainParams) -> None:
    """Pre-train a world model on token shards, post-train it with actions on episodes (Prefect flow `train`)."""
    if _is_yaml(params.manifest):
        need.manifest(params.manifest)
    if params.tokenizer and params.family == "diffusion":  # any variant found, the family's refusal says why not
        params.check_tokenizer(need.tokenizer(params.tokenizer, variant=None))
    elif params.tokenizer:
        need.tokenizer(params.tokenizer)
    from flows.train import episode_folders
    from flows.train import train as train_flow

    for extra in params.also or []:
        if _is_yaml(extra):
            need.manifest(extra)
    try:
        folders, _ = episode_folders(params.manifest, Settings().data_root.resolve())
        for extra in params.also or []:
            episode_folders(extra, Settings().data_root.resolve())
    except FileNotFoundError as exc:
        refuse(exc)
    params.check_episodes(folders[0])
    writing()
    try:
        result = train_flow(**params.model_dump())
    except (FileNotFoundError, ValueError) as exc:
        refuse(exc)
    done = {True: "trained", False: "already trained"}
    out.print(f"pre-trained {result['pretrain_checkpoint_id']} ({done[result['pretrained']]}), post-trained "
              f"{result['posttrain_checkpoint_id']} ({done[result['posttrained']]}) on {result['episodes']} episodes",
              highlight=False)


def _heldout(params, evaluate) -> dict:
    """Run a held-out evaluation flow (physics, camera, rig) with the world model and tokenizer
    resolved and checked first; a refusal is one line, exit 2."""
    need.simulable(params.manifest)
    folder = need.world_model(params.world_model)
    from tasks.world.family import TOKENIZER_VARIANT, family_of, read_world_config

    variant = TOKENIZER_VARIANT[family_of(read_world_config(folder))]  # a diffusion one reads a continuous tokenizer
    tokenizer = need.tokenizer(params.tokenizer, variant) if params.tokenizer else None
    writing()
    try:
        return evaluate(**params.model_copy(update={"world_model": folder, "tokenizer": tokenizer}).model_dump())
    except (FileNotFoundError, ValueError) as exc:
        refuse(exc)


@command(evaluate_app, PhysicsParams, "physics")
def evaluate_physics_cmd(params: PhysicsParams) -> None:
    """A world model against MuJoCo on held-out seeds: per-horizon PSNR, SSIM, package position
    error and IoU beside copy-last-frame and the tokenizer's reconstruction, true against
    shuffled actions (Prefect flow `evaluate-physics`)."""
    from flows.physics import evaluate_physics

    result = _heldout(params, evaluate_physics)
    checks = ", ".join(f"{k} {'passed' if v else 'failed'}" for k, v in result["checks"].items())
    out.print(f"evaluation {result['evaluation_id']} ({result['windows']} windows, {result['moving']} with the "
              f"package moving): {checks}; table and plots under {result['folder']}", highlight=False)


@command(evaluate_app, CameraParams, "camera")
def evaluate_camera_cmd(params: CameraParams) -> None:
    """Camera control: a world model of a rig whose action is its cameras' motion, on held-out
    seeds; the camera motion re-estimated from its frames against the commanded motion, beside
    copy-last-frame and the tokenizer's reconstruction (Prefect flow `evaluate-camera`)."""
    from flows.camera_control import evaluate_camera

    result = _heldout(params, evaluate_camera)
    verdict = "passed" if result["checks"]["beats_copy_last"] else "failed"
    out.print(f"evaluation {result['evaluation_id']} ({result['windows']} windows, camera {result['camera']}): "
              f"rotation error below copy-last's {verdict}; table under {result['folder']}", highlight=False)


@command(evaluate_app, RigParams, "rig")
def evaluate_rig_cmd(params: RigParams) -> None:
    """Multi-view rig: a world model trained on a rig's tiled video (every view generated
    together), on held-out seeds; the rig's ego-motion re-estimated from all its views in cm
    against the commanded motion, and how well neighbouring views agree (Prefect flow `evaluate-rig`)."""
    from flows.rig import evaluate_rig

    result = _heldout(params, evaluate_rig)
    verdict = "passed" if result["checks"]["beats_copy_last"] else "failed"
    out.print(f"evaluation {result['evaluation_id']} ({result['windows']} windows, rig {result['rig']}): "
              f"ego-motion error below copy-last's {verdict}; tables under {result['folder']}", highlight=False)

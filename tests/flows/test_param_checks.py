"""Each flow's parameter model (flows/params_*.py) holds every check of its parameters, and the
CLI and the deployments share it: the same bad value is refused by the `worldline` command and
by the flow as a deployment run calls it (Prefect's validation of the parameters, then the
flow's first line), without a Prefect server."""

import inspect
import re

import pytest
from prefect.exceptions import ParameterTypeError
from typer.testing import CliRunner

from flows import cli_world
from flows.cli import app
from flows.corpus import corpus
from flows.curate import curate
from flows.evaluate import evaluate
from flows.loop import loop
from flows.panels import panels
from flows.params import ParamsError, Refused
from flows.params_data import CorpusParams, CurateParams, RegisterParams, SimulateParams
from flows.params_policy import EvaluateParams, LoopParams, PanelsParams, TrainPolicyParams
from flows.params_transfer import TrainTransferParams, TransferParams
from flows.camera_control import evaluate_camera
from flows.params_world import CameraParams, PhysicsParams, RigParams, TokenizeParams, TrainParams
from flows.physics import evaluate_physics
from flows.policy import train_policy
from flows.register import register
from flows.rig import evaluate_rig
from flows.simulate import simulate
from flows.tokenize import tokenize
from flows.train import train
from flows.transfer import train_transfer, transfer
from tasks.manifests import load

from tests.support import MANIFESTS

runner = CliRunner()
PUSH = str(MANIFESTS / "conveyor_push.yaml")
BASE = str(MANIFESTS / "mobile_rig_aisle.yaml")  # a mobile base: no arm

MODELS = [(register, RegisterParams), (simulate, SimulateParams), (corpus, CorpusParams), (curate, CurateParams),
          (tokenize, TokenizeParams), (train, TrainParams), (evaluate_physics, PhysicsParams), (panels, PanelsParams),
          (evaluate, EvaluateParams), (train_policy, TrainPolicyParams), (loop, LoopParams),
          (train_transfer, TrainTransferParams), (transfer, TransferParams), (evaluate_camera, CameraParams),
          (evaluate_rig, RigParams)]

# (flow, the parameters a deployment passes, the same value on the command line, what both say;
# a pair where the CLI names the option and the flow the parameter)
CHECKS = [
    (tokenize, {"shards": "x", "preset_name": "huge"}, ["tokenize", "x", "--preset", "huge"],
     "unknown tokenizer preset 'huge'"),
    (tokenize, {"shards": "x", "size": 36}, ["tokenize", "x", "--size", "36"],
     "36 is not a multiple of tiny-dv4x8x8's spatial compression 8"),
    (tokenize, {"shards": "x", "crop": 20}, ["tokenize", "x", "--crop", "20"],
     "20 is not a multiple of tiny-dv4x8x8's spatial compression 8"),
    (tokenize, {"shards": "x", "crop": 128}, ["tokenize", "x", "--crop", "128"], "128 is larger than"),
    (tokenize, {"shards": "x", "device": "tpu"}, ["tokenize", "x", "--device", "tpu"],
     "expected auto, cpu, cuda or cuda:N"),
    (panels, {"manifest": PUSH, "device": "tpu"}, ["panels", PUSH, "--device", "tpu"],
     "expected auto, cpu, cuda or cuda:N"),
    (train, {"manifest": PUSH, "device": "cpu", "precision": "bf16"}, ["train", PUSH, "--device", "cpu", "--precision", "bf16"],
     "bf16 runs only on a CUDA device"),
    (train, {"manifest": PUSH, "preset_name": "huge"}, ["train", PUSH, "--preset", "huge"],
     "unknown world model preset 'huge'"),
    (train, {"manifest": PUSH, "family": "diffusion"}, ["train", PUSH, "--family", "diffusion"],
     ("--preset 'tiny-wm' is an autoregressive (*-wm) world model preset; --family diffusion takes small-dwm, tiny-dwm",
      "preset_name 'tiny-wm' is an autoregressive (*-wm) world model preset; family diffusion takes small-dwm, "
      "tiny-dwm")),
    (train, {"manifest": PUSH, "preset_name": "small-dwm"}, ["train", PUSH, "--preset", "small-dwm"],
     "'small-dwm' is a diffusion (*-dwm) world model preset"),
    (train, {"manifest": PUSH, "family": "diffusion", "preset_name": "tiny-dwm", "self_condition": 0.5},
     ["train", PUSH, "--family", "diffusion", "--preset", "tiny-dwm", "--self-condition", "0.5"],
     "the autoregressive world model's option"),
    (train_policy, {"manifest": PUSH, "preset_name": "huge"}, ["train-policy", PUSH, "--preset", "huge"],
     "unknown state policy preset 'huge'"),
    (train_transfer, {"manifest": PUSH, "preset_name": "huge"}, ["train-transfer", PUSH, "--preset", "huge"],
     "unknown transfer preset 'huge'"),
    (train_transfer, {"manifest": PUSH, "seeds": "5-2"}, ["train-transfer", PUSH, "--seeds", "5-2"],
     "'5-2': a range A-B runs upwards (A at most B)"),
    (train_transfer, {"manifest": PUSH, "seeds": "0-10000"}, ["train-transfer", PUSH, "--seeds", "0-10000"],
     "from 1 to 10000 seeds"),
    (transfer, {"source": "x", "model": "m", "look": "sepia"}, ["transfer", "x", "--model", "m", "--look", "sepia"],
     "unknown look 'sepia'"),
    (train_policy, {"manifest": PUSH, "observe": "overhead,overhead"}, ["train-policy", PUSH, "--observe", "overhead,overhead"],
     "observe 'overhead,overhead': name one or more distinct cameras"),
    (train_policy, {"manifest": PUSH, "encoder": "tokenizer:abc123abc123"},
     ["train-policy", PUSH, "--encoder", "tokenizer:abc123abc123"],
     "a state policy reads the simulator, it has no image encoder; add"),
    (train_policy, {"manifest": PUSH, "observe": "side", "encoder": "resnet"},
     ["train-policy", PUSH, "--observe", "side", "--encoder", "resnet"],
     "encoder 'resnet': cnn, or tokenizer: and a tokenizer checkpoint folder or id"),
    (train_policy, {"manifest": PUSH, "observe": "side", "encoder_layer": "hidden"},
     ["train-policy", PUSH, "--observe", "side", "--encoder-layer", "hidden"],
     "only a tokenizer encoder has layers to choose"),
    (train_policy, {"manifest": PUSH, "observe": "side", "dagger_gate": 0.5},
     ["train-policy", PUSH, "--observe", "side", "--dagger-gate", "0.5"],
     "gates the DAgger rounds of a vision policy; add"),
    (train_policy, {"manifest": PUSH, "dagger": 2}, ["train-policy", PUSH, "--dagger", "2"],
     "DAgger rounds train a vision policy; add"),
    (train_policy, {"manifest": PUSH, "shift": 4}, ["train-policy", PUSH, "--shift", "4"],
     "moves a vision policy's frames for its own convolutions; add"),
    (train_policy, {"manifest": PUSH, "observe": "side", "encoder": "tokenizer:abc", "shift": 4},
     ["train-policy", PUSH, "--observe", "side", "--encoder", "tokenizer:abc", "--shift", "4"],
     "moves a vision policy's frames for its own convolutions; add"),
    (loop, {"manifest": PUSH, "policy": "scripted"}, ["loop", PUSH, "--policy", "scripted"],
     "policy 'scripted': the loop post-trains learned policies"),
    (simulate, {"manifest": PUSH, "episodes": 0}, ["simulate", PUSH, "--episodes", "0"],
     ("'--episodes': Input should be greater than or equal to 1",
      "episodes: Input should be greater than or equal to 1")),
    (corpus, {"minutes": 0.01}, ["corpus", "--minutes", "0.01"],
     ("'--minutes': Input should be greater than or equal to 0.05",
      "minutes: Input should be greater than or equal to 0.05")),
    (train, {"manifest": PUSH, "action_totals": 9}, ["train", PUSH, "--action-totals", "9"],
     ("'--action-totals': Input should be less than or equal to 8",
      "action_totals: Input should be less than or equal to 8")),
    (panels, {"manifest": PUSH, "episodes": 1001}, ["panels", PUSH, "--episodes", "1001"],
     ("'--episodes': Input should be less than or equal to 1000",
      "episodes: Input should be less than or equal to 1000")),
    (evaluate_physics, {"manifest": PUSH, "horizon": 0}, ["evaluate", "physics", PUSH, "--horizon", "0"],
     ("'--horizon': Input should be greater than or equal to 1",
      "horizon: Input should be greater than or equal to 1")),
    (loop, {"manifest": PUSH, "worst": 9}, ["loop", PUSH, "--worst", "9"],
     ("'--worst': Input should be less than or equal to 8",
      "worst: Input should be less than or equal to 8")),
    (evaluate, {"manifest": PUSH, "in_world_model": True}, ["evaluate", "policies", PUSH, "--in-world-model"],
     ("--in-world-model needs --world-model", "in_world_model needs world_model")),
    (evaluate, {"manifest": PUSH, "world_model": "wm", "in_world_model": True},
     ["evaluate", "policies", PUSH, "--world-model", "wm", "--in-world-model"],
     "policy 'scripted' reads the simulator's state, not frames; only vision policies"),
    (evaluate, {"manifest": PUSH, "world_model": "wm", "in_world_model": True, "policies": ["vision:v", "bc:b"]},
     ["evaluate", "policies", PUSH, "--world-model", "wm", "--in-world-model", "--policy", "vision:v", "--policy", "bc:b"],
     "policy 'bc:b' reads the simulator's state, not frames"),
]


@pytest.mark.parametrize("flow, params, args, said", CHECKS, ids=lambda v: v.name if hasattr(v, "fn") else None)
def test_each_check_refuses_a_value_from_the_cli_and_from_a_deployment(flow, params, args, said, data_root):
    cli_said, flow_said = said if isinstance(said, tuple) else (said, said)
    result = runner.invoke(app, args, terminal_width=400)
    assert result.exit_code == 2 and cli_said in " ".join(result.output.split()), result.output
    assert not (data_root / "lineage.duckdb").exists()

    try:  # a deployment run: Prefect validates the parameters against the signature, then the flow runs
        validated = flow.validate_parameters(params)
    except ParameterTypeError as exc:
        assert flow_said in str(exc)
        validated = params
    with pytest.raises(ParamsError) as refused:  # the flow's first line, before it reads or writes anything
        flow.fn(**validated)
    assert flow_said in str(refused.value) and "\n" not in str(refused.value)
    assert not (data_root / "lineage.duckdb").exists()


def test_the_cli_names_options_and_a_flow_names_its_parameters():
    with pytest.raises(ParamsError, match=r"^crop: 128 is larger than size 64$"):
        tokenize.fn(shards="x", crop=128)
    result = runner.invoke(app, ["tokenize", "x", "--crop", "128"])
    assert "--crop: 128 is larger than --size 64" in result.output
    with pytest.raises(ParamsError, match=r"^preset_name: unknown"):
        train.fn(manifest=PUSH, preset_name="huge")
    assert "--preset: unknown" in runner.invoke(app, ["train", PUSH, "--preset", "huge"]).output


@pytest.mark.parametrize("flow, model", [(train_policy, TrainPolicyParams), (loop, LoopParams)])
def test_behaviour_cloning_needs_an_arm_from_the_cli_and_in_the_flow(flow, model, data_root):
    args = ["train-policy" if flow is train_policy else "loop", BASE]
    result = runner.invoke(app, args, terminal_width=400)
    assert result.exit_code == 2 and "drives arms" in result.output, result.output
    with pytest.raises(Refused, match="drives arms"):  # the check the flow makes on the manifest it loads
        model.of(flow.validate_parameters({"manifest": BASE})).check_scenario(load(MANIFESTS / "mobile_rig_aisle.yaml"))
    assert "check_scenario(" in inspect.getsource(flow.fn)


def test_a_tokenizer_of_the_other_variant_is_refused_for_each_family(data_root, tmp_path):
    """The diffusion world model denoises a continuous tokenizer's latents: a discrete tokenizer is
    refused in one line, by the CLI (exit 2) and by the flow before it writes anything; the
    autoregressive family keeps its own refusal of a continuous one."""
    from models.tokenizer import VideoTokenizer
    from models.tokenizer import preset as tokenizer_preset
    from tasks.tokenize.tokens import save_checkpoint

    for name in ("tiny-dv4x8x8", "tiny-cv4x8x8"):
        save_checkpoint(VideoTokenizer(tokenizer_preset(name)), tmp_path / name)
    discrete, continuous = str(tmp_path / "tiny-dv4x8x8"), str(tmp_path / "tiny-cv4x8x8")
    cases = [(["--family", "diffusion", "--preset", "tiny-dwm", "--tokenizer", discrete],
              f"--tokenizer {discrete}: a discrete tokenizer; --family diffusion needs a continuous one"),
             (["--tokenizer", continuous], f"{continuous}: a continuous tokenizer; a discrete one is needed here")]
    for args, said in cases:
        result = runner.invoke(app, ["train", PUSH, *args], terminal_width=400)
        assert result.exit_code == 2 and said in " ".join(result.output.split()), result.output
        assert len(result.output.strip().splitlines()) == 1
    with pytest.raises(Refused, match=re.escape(f"tokenizer {discrete}: a discrete tokenizer; family diffusion "
                                                "needs a continuous one")) as refused:
        train.fn(manifest=PUSH, family="diffusion", preset_name="tiny-dwm", tokenizer=discrete)
    assert "\n" not in str(refused.value)
    assert not (data_root / "lineage.duckdb").exists()


def test_train_takes_a_rig_as_its_camera_and_names_the_rigs_when_refusing(tmp_path):
    import json

    (tmp_path / "meta.json").write_text(json.dumps({"cameras": ["front", "left"], "rigs": ["surround"]}))
    TrainParams.of({"manifest": PUSH, "camera": "surround"}).check_episodes(tmp_path)  # the rig's tiled video
    with pytest.raises(Refused) as refused:
        TrainParams.of({"manifest": PUSH, "camera": "roof"}).check_episodes(tmp_path)
    said = refused.value.named(TrainParams.labels(True))
    assert "--camera 'roof': the episodes of" in said and said.endswith("have cameras front, left and rigs surround")


def test_train_checks_its_episodes_in_the_flow_as_in_the_cli():
    assert "check_episodes(" in inspect.getsource(train.fn)
    assert "check_episodes(" in inspect.getsource(cli_world.train)


@pytest.mark.parametrize("flow, model", MODELS, ids=lambda v: v.name if hasattr(v, "fn") else v.__name__)
def test_each_flow_validates_with_a_model_of_its_very_parameters(flow, model):
    signature = inspect.signature(flow.fn).parameters
    assert list(signature) and set(signature) == set(model.model_fields)
    for name, parameter in signature.items():
        field = model.model_fields[name]
        assert parameter.default == (inspect.Parameter.empty if field.is_required() else field.default), name
    assert f"{model.__name__}.of(locals())" in inspect.getsource(flow.fn)


@pytest.mark.skipif(__import__("torch").cuda.is_available(), reason="this machine has a GPU")
@pytest.mark.parametrize("flow,params,argv", [
    (tokenize, {"shards": "x", "device": "cuda"}, ["tokenize", "x", "--device", "cuda"]),
    (train, {"manifest": PUSH, "device": "cuda:0"}, ["train", PUSH, "--device", "cuda:0"]),
    (train_policy, {"manifest": PUSH, "device": "cuda"}, ["train-policy", PUSH, "--device", "cuda"]),
    (evaluate, {"manifest": PUSH, "device": "cuda"}, ["evaluate", "policies", PUSH, "--device", "cuda"]),
    (panels, {"manifest": PUSH, "device": "cuda"}, ["panels", PUSH, "--device", "cuda"]),
    (train_transfer, {"manifest": PUSH, "device": "cuda"}, ["train-transfer", PUSH, "--device", "cuda"])])
def test_cuda_without_a_gpu_is_refused_in_one_line(flow, params, argv):
    done = runner.invoke(app, argv)
    assert done.exit_code == 2 and "no CUDA GPU is visible to PyTorch" in done.output, done.output
    with pytest.raises(ParamsError, match="device: no CUDA GPU is visible"):
        flow.fn(**params)


def test_a_vision_policy_on_a_camera_the_manifest_lacks_is_refused_before_anything_runs(data_root):
    result = runner.invoke(app, ["train-policy", PUSH, "--observe", "wrist"], terminal_width=400)
    assert result.exit_code == 2, result.output
    assert ("--observe: the policy observes camera(s) wrist, which conveyor-push does not have (it has overhead)"
            in " ".join(result.output.split()))
    assert not (data_root / "lineage.duckdb").exists()


def test_a_world_model_or_a_policy_that_does_not_fit_the_panel_is_refused_in_one_line(data_root, tmp_path):
    """The issue's bad input: a world model post-trained on another camera (or whose tokenizer or
    action layout differs) is named, and so is a vision policy whose camera it does not generate."""
    from tasks.world.checkpoints import load_checkpoint, read_config, save_checkpoint

    from tests.flows.test_evaluate import vision_checkpoint
    from tests.flows.test_panels import random_world_model

    wm = random_world_model(tmp_path)
    side = tmp_path / "side"
    save_checkpoint(load_checkpoint(wm), side, {**read_config(wm), "camera": "side"})
    pair = str(MANIFESTS / "push_closeup_pair.yaml")
    sees_b = f"vision:{vision_checkpoint(tmp_path, MANIFESTS / 'push_closeup_pair.yaml', 'side_b')}"
    cases = [(PUSH, side, ["scripted"], False, "post-trained on camera side; the panel's camera is overhead"),
             (pair, wm, [sees_b], True, "sees camera(s) side_b; the world model generates side only")]
    for manifest, folder, policies, closed, said in cases:
        argv = ["evaluate", "policies", manifest, "--world-model", str(folder)]
        argv += [arg for p in policies for arg in ("--policy", p)]
        result = runner.invoke(app, argv + (["--in-world-model"] if closed else []), terminal_width=400)
        assert result.exit_code == 2 and said in " ".join(result.output.split()), result.output
        assert len(result.output.strip().splitlines()) == 1
        with pytest.raises(ParamsError, match=re.escape(said)) as refused:
            evaluate.fn(manifest=manifest, world_model=str(folder), policies=policies, in_world_model=closed)
        assert "\n" not in str(refused.value)
    # panels --world-model runs the same check
    said = cases[0][-1]
    result = runner.invoke(app, ["panels", PUSH, "--world-model", str(side)], terminal_width=400)
    assert result.exit_code == 2 and said in " ".join(result.output.split()), result.output
    with pytest.raises(ParamsError, match=re.escape(said)):
        panels.fn(manifest=PUSH, world_model=str(side))
    assert not (data_root / "lineage.duckdb").exists()


def test_the_dagger_gate_default_is_the_libraries():
    from flows.params_policy import DAGGER_GATE
    from tasks.policy.vision_train import DAGGER_GATE as LIBRARY

    assert DAGGER_GATE == LIBRARY

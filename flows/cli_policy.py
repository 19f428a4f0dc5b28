"""`worldline panels`, `evaluate policies`, `train-policy` and `loop`: panels and policies."""

from __future__ import annotations

from flows import cli_checks as need
from flows.cli_command import command
from flows.cli_shell import app, err, evaluate_app, fail, out, print_rows, writing
from flows.params_policy import EvaluateParams, LoopParams, PanelsParams, TrainPolicyParams
from schemas.settings import Settings


@command(app, PanelsParams)
def panels(params: PanelsParams) -> None:
    """A matched panel: variants differing only in stressors, simulated, contact sheet + MP4 (Prefect flow `panels`)."""
    parent = need.simulable(params.manifest)
    need.grid(parent, params.grid, params.episodes)
    folder = need.world_model(params.world_model) if params.world_model else None
    from flows.panels import panels as panels_flow
    from flows.panels import primary_camera

    try:
        primary_camera(parent, params.camera)
    except ValueError as exc:
        fail(f"--camera: {exc}")
    params.check_world(parent, folder, Settings().data_root)

    writing()
    try:
        result = panels_flow(**params.model_copy(update={"world_model": folder}).model_dump())
    except ValueError as exc:
        fail(str(exc))
    cells = ", ".join(f"{v['cell']} {sum(e['success'] for e in v['episodes'])}/{len(v['episodes'])}"
                      for v in result["variants"])
    out.print(f"panel {result['panel_id']}: {cells}; sheet {result['contact_sheet']}, video {result['video']}",
              highlight=False)


@command(app, TrainPolicyParams, "train-policy")
def train_policy_cmd(params: TrainPolicyParams) -> None:
    """Behaviour-clone the scripted controller into a small MLP policy (Prefect flow `train-policy`)."""
    params.check_scenario(need.simulable(params.manifest))
    if params.tokenizer():
        folder = need.tokenizer(params.tokenizer(), variant=None)
        params.check_tokenizer(folder)
        params = params.model_copy(update={"encoder": "tokenizer:" + folder})
    from flows.policy import train_policy as train_flow

    writing()
    result = train_flow(**params.model_dump())
    rate = result["held_out_success_rate"]
    out.print(f"checkpoint {result['folder']}" + ("" if rate is None else f"; held-out success {rate:.2f}"),
              highlight=False)


@command(evaluate_app, EvaluateParams, "policies", listing=True)
def evaluate_policies_cmd(params: EvaluateParams, fmt: str = "table") -> None:
    """Policies on a panel: simulator and frame-detector success per stressor cell, their rank
    correlation (Prefect flow `evaluate`); with --in-world-model, vision policies also driven
    closed loop in the world model; exit 2 when panel contracts differ. With csv or json, the
    rows alone on stdout and the correlations on stderr."""
    parent = need.simulable(params.manifest)
    for other in params.compare or []:
        need.simulable(other)
    need.grid(parent, params.grid, params.episodes)
    from tasks.panels.contract import PanelContractError

    from flows.evaluate import DEFAULT_POLICIES, JUDGES, agreement_line, plan
    from flows.evaluate import evaluate as evaluate_flow

    specs, loaded = need.policies(params.policies or [])
    folder = need.world_model(params.world_model) if params.world_model else None
    loaded = loaded or need.policies(list(DEFAULT_POLICIES))[1]
    try:  # the flow plans again; refusing here spares starting Prefect for nothing
        plan([params.manifest, *(params.compare or [])], params.grid, params.episodes, loaded)
    except PanelContractError as exc:
        fail(str(exc))
    params.check_world(parent, loaded, folder, Settings().data_root)

    writing()
    try:
        result = evaluate_flow(**params.model_copy(update={
            "policies": specs or None, "compare": params.compare or [], "world_model": folder}).model_dump())
    except PanelContractError as exc:
        fail(str(exc))
    judges = ("sim", "detector", "world", *(["closed"] if params.in_world_model else []))
    rows = [(e["panel"], e["policy"], r["cell"], r["episodes"], *("-" if r.get(k) is None else f"{r[k]:.2f}"
                                                                  for k in judges))
            for e in result["evaluations"] for r in e["table"]]
    print_rows(["panel", "policy", "cell", "episodes", "simulator", "detector on sim", "world model",
                *([JUDGES["closed"]] if params.in_world_model else [])], rows, fmt,
               title="success rate per stressor cell")
    prose = out if fmt == "table" else err  # csv and json stay parseable
    prose.print("Spearman (simulator vs): " + ", ".join(f"{k} {'-' if v is None else f'{v:.2f}'}"
                                                         for k, v in result["spearman"].items()), highlight=False)
    for column, a in result["agreement"].items():
        prose.print(agreement_line(f"{JUDGES.get(column, column)} vs simulator, per episode", a), highlight=False)


@command(app, LoopParams, "loop", listing=True)
def loop_cmd(params: LoopParams, fmt: str = "table") -> None:
    """Failures back into data: the worst stressor cells become derived manifests, simulated,
    curated and post-trained on; success per cell before and after (Prefect flow `loop`). With
    csv or json, the rows alone on stdout and the checkpoint on stderr."""
    parent = need.simulable(params.manifest)
    params.check_scenario(parent)
    need.grid(parent, params.grid, params.episodes)
    policy = need.policies([params.policy])[0][0] if params.policy is not None else None
    from flows.loop import loop as loop_flow

    writing()
    result = loop_flow(**params.model_copy(update={"policy": policy}).model_dump())
    rate = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
    control = bool(result["table"]) and "untargeted" in result["table"][0]
    print_rows(["cell", "episodes", "before", "after", *(["untargeted control"] if control else []), "targeted"],
               [(r["cell"], r["episodes"], rate(r["before"]), rate(r["after"]),
                 *([rate(r["untargeted"])] if control else []), "yes" if r["targeted"] else "")
                for r in result["table"]], fmt, title="success rate per stressor cell, before and after")
    (out if fmt == "table" else err).print(f"checkpoint {result['checkpoint']}", highlight=False)

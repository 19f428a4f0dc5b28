"""prefect.yaml, and a real Prefect server + process worker on 127.0.0.1 driven from the command line.

The integration tests share one stack (a start costs ~20-35 s here): the deployment run first,
the schedule second, and stopping everything by PID last; `serve` then gets a stack of its own.
"""

import ast
import os
import re
import signal
import subprocess
import sys
import time
from datetime import timedelta, timezone
from pathlib import Path

import pytest
import yaml

from flows.server import AUTH_FILE, POOL, LocalStack, auth_string, group_members
from schemas.manifest import manifest_hash
from schemas.settings import Settings
from tasks.manifests import load
from warehouse.store import Warehouse

from tests.support import MANIFESTS, REPO

PREFECT_YAML = yaml.safe_load((REPO / "prefect.yaml").read_text())
LIVE = PREFECT_YAML["deployments"]
RUN_TIMEOUT_S = 180


def flow_functions() -> dict[str, tuple[str, set[str], set[str]]]:
    """Every @flow in flows/*.py: 'file.py:function' -> (flow name, parameters, required parameters)."""
    found = {}
    for path in sorted((REPO / "flows").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.FunctionDef):
                continue
            for deco in node.decorator_list:
                target = deco.func if isinstance(deco, ast.Call) else deco
                if getattr(target, "id", None) != "flow":
                    continue
                names = [k.value.value for k in getattr(deco, "keywords", []) if k.arg == "name"]
                positional = node.args.posonlyargs + node.args.args
                params = {a.arg for a in positional + node.args.kwonlyargs}
                required = {a.arg for a in positional[:len(positional) - len(node.args.defaults)]}
                required |= {a.arg for a, d in zip(node.args.kwonlyargs, node.args.kw_defaults) if d is None}
                found[f"flows/{path.name}:{node.name}"] = (names[0] if names else node.name, params, required)
    return found


FLOWS = flow_functions()


def flow_name(deployment: dict) -> str:
    """The Prefect flow name, which `prefect deployment run 'FLOW/NAME'` uses."""
    built = FLOWS.get(deployment["entrypoint"])
    return built[0] if built else deployment["entrypoint"].split(":")[1]


# -- prefect.yaml, without a server ----------------------------------------------------------
@pytest.mark.parametrize("deployment", LIVE, ids=lambda d: d["entrypoint"])
def test_live_deployment_matches_its_flow(deployment):
    assert deployment["entrypoint"] in FLOWS, f"prefect.yaml: no @flow at {deployment['entrypoint']}"
    _, names, required = FLOWS[deployment["entrypoint"]]
    params = set(deployment.get("parameters", {}))
    assert params <= names, f"{deployment['entrypoint']} takes no {sorted(params - names)}"
    assert required <= params, f"{deployment['entrypoint']} needs {sorted(required - params)} for a scheduled run"


@pytest.mark.parametrize("deployment", LIVE, ids=lambda d: d["entrypoint"])
def test_every_deployment_names_a_valid_manifest_and_the_pool(deployment):
    assert deployment["work_pool"]["name"] == POOL
    manifests = [v for k, v in deployment["parameters"].items() if k in ("manifest", "manifest_path")]
    takes_one = deployment["entrypoint"] not in FLOWS or FLOWS[deployment["entrypoint"]][1] & {"manifest", "manifest_path"}
    if not takes_one:  # corpus and demo make their own data
        assert manifests == []
        return
    assert len(manifests) == 1, f"{deployment['entrypoint']} names no manifest"
    assert (REPO / manifests[0]).resolve().parent == MANIFESTS
    load(REPO / manifests[0])


def test_every_flow_has_a_deployment_and_curate_runs_nightly():
    deployed = {d["entrypoint"] for d in LIVE}
    assert set(FLOWS) <= deployed, f"flows without a deployment in prefect.yaml: {sorted(set(FLOWS) - deployed)}"
    flows = {flow_name(d) for d in LIVE}
    assert flows >= {"register", "simulate", "curate", "tokenize", "train", "panels", "evaluate", "loop"}
    curate = next(d for d in LIVE if flow_name(d) == "curate")
    (schedule,) = curate["schedules"]
    minute, hour, *rest = schedule["cron"].split()
    assert rest == ["*", "*", "*"] and int(hour) < 6 and schedule["timezone"] == "UTC"
    assert curate["parameters"]["inputs"] == [".worldline/inbox"]
    pull = PREFECT_YAML["pull"][0]["prefect.deployments.steps.set_working_directory"]
    assert pull["directory"] == "{{ project-root.stdout }}"



def test_deployment_names_are_unique_and_say_what_they_run():
    """Issue 30: four deployments were called `conveyor-push` and three `default`. Each name is
    now the flow, then its manifest's name (the file's own `name:`, not the file's), and the
    preset, seed or schedule a deployment runs with."""
    names = [d["name"] for d in LIVE]
    assert len(names) == len(set(names)), sorted(n for n in names if names.count(n) > 1)
    for deployment in LIVE:
        name, params = deployment["name"], deployment.get("parameters", {})
        assert name.startswith(f"{flow_name(deployment)}-"), f"{name}: not named after its flow {flow_name(deployment)}"
        said = [load(REPO / v).name for k, v in params.items() if k in ("manifest", "manifest_path")]
        said += [params[k] for k in ("preset_name",) if k in params] + [f"seed-{params[k]}" for k in ("seed",) if k in params]
        said += [s["slug"] for s in deployment.get("schedules", [])]
        assert all(part in name for part in said), f"{name}: does not say {[p for p in said if p not in name]}"

# -- the auth string, without a server -------------------------------------------------------------
def test_auth_string_is_generated_once_kept_0600_and_shown_only_then(tmp_path):
    settings = Settings(data_root=tmp_path)
    first = auth_string(settings, {})
    path = settings.prefect_home_path / AUTH_FILE
    assert first.created and first.source == str(path.resolve())
    assert path.stat().st_mode & 0o777 == 0o600 and path.read_text().strip() == first.value
    assert first.value.startswith("worldline:") and len(first.value) > 40
    assert first.value in first.notice() and str(path.resolve()) in first.notice()
    again = auth_string(settings, {})
    assert (again.value, again.created) == (first.value, False)
    assert first.value not in again.notice() and str(path.resolve()) in again.notice()
    assert auth_string(Settings(data_root=tmp_path / "other"), {}).value != first.value  # one per data root
    path.chmod(0o644)
    auth_string(settings, {})
    assert path.stat().st_mode & 0o777 == 0o600


def test_a_user_supplied_auth_string_wins(tmp_path):
    settings = Settings(data_root=tmp_path)
    mine = auth_string(settings, {"PREFECT_SERVER_API_AUTH_STRING": "me:secret"})
    assert (mine.value, mine.source, mine.created) == ("me:secret", "PREFECT_SERVER_API_AUTH_STRING", False)
    assert "me:secret" not in mine.notice()
    assert not (settings.prefect_home_path / AUTH_FILE).exists()


# -- a real server and worker -------------------------------------------------------------------
@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    settings = Settings(data_root=tmp_path_factory.mktemp("stack"))
    # The worker polls every 10 s by default; 1 s keeps the run test short.
    stack = LocalStack(settings, env={"PREFECT_WORKER_QUERY_SECONDS": "1"})
    stack.start()
    yield stack
    stack.stop()


def prefect_cli(stack: LocalStack, *args: str) -> subprocess.CompletedProcess:
    done = subprocess.run([sys.executable, "-m", "prefect", *args], cwd=REPO, env=stack.env(),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    return done


def client(stack: LocalStack):
    from prefect.client.orchestration import SyncPrefectClient

    return SyncPrefectClient(stack.api_url, auth_string=stack.auth_string)


def wait_final(stack: LocalStack, flow_run_id: str):
    with client(stack) as api:
        deadline = time.monotonic() + RUN_TIMEOUT_S
        while time.monotonic() < deadline:
            run = api.read_flow_run(flow_run_id)
            if run.state and run.state.is_final():
                return run
            assert stack.dead() is None, stack.dead().tail()
            time.sleep(1)
    pytest.fail(f"flow run {flow_run_id} not finished after {RUN_TIMEOUT_S} s:\n{stack.worker.tail()}")


def _worldline(env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "flows.cli", *args], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=300)


def _registered_run(root: Path) -> str:
    with Warehouse(root / "lineage.duckdb", read_only=True) as wh:
        (run,) = wh.query("SELECT prefect_flow_run_id FROM runs WHERE flow = 'register'")[1]
    return run[0]


@pytest.mark.slow
def test_a_command_uses_the_running_server_instead_of_a_temporary_one(stack, tmp_path):
    """Issue 30: every command paid 17-22 s for a temporary server while one was running. With
    PREFECT_API_URL (and the auth string) exported, and with neither while `worldline server`
    runs for the data root (its server.json), the flow run lands in that server."""
    from flows.server_found import announce

    good = str(MANIFESTS / "conveyor_push.yaml")
    for case in ("exported", "found"):
        settings = Settings(data_root=tmp_path / case)
        env = {**stack.env(), "WORLDLINE_DATA_ROOT": str(settings.data_root)}
        env["PREFECT_HOME"] = env["WORLDLINE_PREFECT_HOME"] = str(settings.prefect_home_path)
        if case == "found":  # the server as `worldline server` announces it; this test's pid stands for its own
            for name in ("PREFECT_API_URL", "PREFECT_API_AUTH_STRING"):
                env.pop(name)
            settings.prefect_home_path.mkdir(parents=True)
            (settings.prefect_home_path / AUTH_FILE).write_text(stack.auth_string + "\n")
            announce(settings, stack.api_url)
        done = _worldline(env, "-v", "register", good)
        assert done.returncode == 0, done.stderr[-3000:]
        assert "temporary server" not in done.stderr and f"Prefect API: {stack.api_url}" in done.stderr, done.stderr
        with client(stack) as api:
            assert api.read_flow_run(_registered_run(settings.data_root)).state.is_completed()


@pytest.mark.slow
def test_a_start_deletes_the_deployments_prefect_yaml_names_no_more(stack):
    """The renamed deployments (`simulate/bin-pick-dim-forklift`, four `conveyor-push`, three
    `default`) would stay in a data root's server database beside their new names."""
    from flows.server_start import prune_deployments

    with client(stack) as api:
        register = api.create_flow_from_name("register")
        stale = api.create_deployment(register, "conveyor-push", tags=["worldline", "register"], work_pool_name=POOL)
        theirs = api.create_deployment(register, "someone-elses", tags=["mine"], work_pool_name=POOL)
    assert prune_deployments(stack.api_url, stack.auth) == ["register/conveyor-push"]
    with client(stack) as api:
        left = {d.id: d.name for d in api.read_deployments()}
        api.delete_deployment(theirs)
    assert stale not in left and theirs in left and {d["name"] for d in LIVE} <= set(left.values())


def test_a_prefect_api_url_nobody_answers_is_one_line_exit_5(tmp_path):
    env = {**os.environ, "WORLDLINE_DATA_ROOT": str(tmp_path), "PREFECT_HOME": str(tmp_path / "prefect"),
           "PREFECT_API_URL": "http://127.0.0.1:9/api"}  # the discard port: nothing listens
    done = _worldline(env, "register", str(MANIFESTS / "conveyor_push.yaml"))
    assert done.returncode == 5 and done.stderr.strip().splitlines() == [
        "PREFECT_API_URL=http://127.0.0.1:9/api: no Prefect server answers there (start one with `worldline server`, "
        "or unset it for a temporary one)"], done.stderr


@pytest.mark.slow
def test_deployment_run_from_the_command_line_lands_in_lineage(stack):
    register = next(d for d in LIVE if flow_name(d) == "register")
    manifest = "manifests/bin_pick_dim_forklift.yaml"  # not the deployment's default: --param must win
    assert register["parameters"]["manifest_path"] != manifest
    done = prefect_cli(stack, "deployment", "run", f"register/{register['name']}", "--param", f"manifest_path={manifest}")
    flow_run_id = re.search(r"UUID: ([0-9a-f-]{36})", done.stdout).group(1)

    run = wait_final(stack, flow_run_id)
    assert run.state.type.value == "COMPLETED", f"{run.state}\n{stack.worker.tail()}"
    with client(stack) as api:
        deployment = api.read_deployment(run.deployment_id)
    # the pull step moved the run to this checkout, wherever the worker started it
    assert deployment.pull_steps == [{"prefect.deployments.steps.set_working_directory": {"directory": str(REPO)}}]

    digest = manifest_hash(load(REPO / manifest))
    with Warehouse(stack.settings.warehouse_path, read_only=True) as wh:
        _, runs = wh.query("SELECT run_id, prefect_flow_run_id, status, manifest_hash, params->>'manifest' "
                           "FROM runs WHERE flow = 'register'")
        _, manifests = wh.query("SELECT manifest_hash, name, source_uri FROM manifests")
    assert runs == [(flow_run_id, flow_run_id, "completed", digest, manifest)]
    assert manifests == [(digest, "bin-pick-dim-forklift", manifest)]


@pytest.mark.slow
def test_curate_deployment_run_twice_reuses_finished_work(stack, tmp_path):
    from tasks.mp4 import write_mp4
    from tasks.sim.episode import rollout

    inbox = tmp_path / "inbox"
    scenario = load(MANIFESTS / "conveyor_push.yaml").model_copy(update={"horizon_s": 3.0})
    write_mp4(inbox / "episode.mp4", rollout(scenario, 3).frames["overhead"], 30)
    curate = next(d for d in LIVE if flow_name(d) == "curate")
    name = f"curate/{curate['name']}"
    counts = "SELECT (SELECT count(*) FROM artifacts), (SELECT count(*) FROM stage_runs WHERE stage = 'analyse'), " \
             "(SELECT count(*) FROM edges), (SELECT count(*) FROM rejections)"
    seen = []
    for _ in range(2):
        done = prefect_cli(stack, "deployment", "run", name, "--param", f'inputs=["{inbox}"]')
        run = wait_final(stack, re.search(r"UUID: ([0-9a-f-]{36})", done.stdout).group(1))
        assert run.state.type.value == "COMPLETED", f"{run.state}\n{stack.worker.tail()}"
        with Warehouse(stack.settings.warehouse_path, read_only=True) as wh:
            _, rows = wh.query(counts)
            _, runs = wh.query("SELECT status, params->>'inputs' FROM runs WHERE flow = 'curate' ORDER BY started_at")
        seen.append(rows[0])
    assert seen[0][1] == 1 and seen[0][0] > 2  # one video analysed: raw video, clips, shard, manifest
    assert seen[1] == seen[0]  # the second run analysed nothing and added no artifact, edge or rejection
    assert [r[0] for r in runs] == ["completed", "completed"] and str(inbox) in runs[0][1]


@pytest.mark.slow
def test_nightly_schedule_creates_scheduled_runs(stack):
    from prefect.client.schemas.filters import (DeploymentFilter, DeploymentFilterId, FlowRunFilter,
                                                FlowRunFilterState, FlowRunFilterStateType)
    from prefect.client.schemas.objects import StateType

    curate = next(d for d in LIVE if flow_name(d) == "curate")
    minute, hour = (int(f) for f in curate["schedules"][0]["cron"].split()[:2])
    with client(stack) as api:
        deployment = api.read_deployment_by_name(f"curate/{curate['name']}")
        assert [s.schedule.cron for s in deployment.schedules] == [curate["schedules"][0]["cron"]]
        only_scheduled = FlowRunFilter(state=FlowRunFilterState(type=FlowRunFilterStateType(any_=[StateType.SCHEDULED])))
        deadline = time.monotonic() + 90  # the scheduler visits new deployments every 5 s
        while time.monotonic() < deadline:
            runs = api.read_flow_runs(deployment_filter=DeploymentFilter(id=DeploymentFilterId(any_=[deployment.id])),
                                      flow_run_filter=only_scheduled)
            if len(runs) >= 3:
                break
            time.sleep(2)
    assert len(runs) >= 3, f"{len(runs)} scheduled runs after 90 s:\n{stack.server.tail()}"
    starts = sorted(r.expected_start_time.astimezone(timezone.utc) for r in runs)
    assert all((t.hour, t.minute, t.second) == (hour, minute, 0) for t in starts)
    assert all(b - a == timedelta(days=1) for a, b in zip(starts, starts[1:]))
    assert all(r.parameters == curate["parameters"] for r in runs)


EVIL_ORIGIN = "http://evil.example"


@pytest.mark.slow
def test_a_page_of_another_origin_cannot_make_the_worker_run_a_command(stack, tmp_path):
    """Issue 26: three requests from a page on another origin made the worker run a shell command."""
    import httpx
    from prefect.client.schemas.filters import FlowFilter, FlowFilterName

    marker = tmp_path / "pwned"
    command = f"touch {marker}"
    register = next(d for d in LIVE if flow_name(d) == "register")
    with client(stack) as api:
        deployment = api.read_deployment_by_name(f"register/{register['name']}")
    # What a browser sends for a page on evil.example: its Origin, no credentials it could know.
    with httpx.Client(base_url=stack.api_url, headers={"Origin": EVIL_ORIGIN}, timeout=30) as page:
        preflight = page.options("/flows/", headers={"Access-Control-Request-Method": "POST",
                                                     "Access-Control-Request-Headers": "content-type"})
        answers = {
            "create flow": page.post("/flows/", json={"name": "evil"}),
            "create deployment": page.post("/deployments/", json={
                "name": "evil", "flow_id": str(deployment.flow_id), "work_pool_name": stack.pool,
                "entrypoint": register["entrypoint"], "job_variables": {"command": command}}),
            "create flow run": page.post(f"/deployments/{deployment.id}/create_flow_run",
                                         json={"job_variables": {"command": command}}),
        }
    codes = {what: answer.status_code for what, answer in answers.items()}
    assert all(code in (401, 403) for code in codes.values()), codes
    assert preflight.status_code >= 400 and "access-control-allow-origin" not in preflight.headers, preflight.headers
    # The auth string alone is not enough for a state change: CSRF protection wants a token too.
    auth = httpx.BasicAuth(*stack.auth_string.split(":", 1))
    assert httpx.post(f"{stack.api_url}/flows/", json={"name": "evil"}, auth=auth, timeout=30).status_code == 403
    with client(stack) as api:  # the legitimate client (auth string and CSRF token) still works
        assert api.read_flows(flow_filter=FlowFilter(name=FlowFilterName(any_=["evil"]))) == []
        assert api.create_flow_from_name("legitimate")
    assert not marker.exists()


@pytest.mark.slow
def test_a_rebound_host_name_is_refused(stack):
    """DNS rebinding: evil.example resolving to 127.0.0.1 makes the browser send Host: evil.example."""
    import httpx

    port = int(stack.api_url.split(":")[2].split("/")[0])
    codes = {host: httpx.get(f"{stack.api_url}/health", headers={"Host": host}, timeout=30).status_code
             for host in (f"evil.example:{port}", f"127.0.0.1:{port}", f"localhost:{port}")}
    assert codes == {f"evil.example:{port}": 400, f"127.0.0.1:{port}": 200, f"localhost:{port}": 200}


@pytest.mark.slow
def test_stop_ends_server_and_worker_by_pid(stack):
    pids = {"server": stack.server_pid, "worker": stack.worker_pid}
    stopped = stack.stop()
    # graceful: the worker on SIGINT, the server on SIGTERM; no SIGKILL was needed
    assert stopped == {"worker": signal.SIGINT, "server": signal.SIGTERM}
    for name, pid in pids.items():
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
        assert group_members(pid) == [], f"{name} left processes behind"
    assert Path(stack.settings.prefect_home_path, "server.log").stat().st_size > 0


def test_children_stop_on_sigint_even_when_the_parent_ignores_it(tmp_path):
    # A background job of a script starts with SIGINT ignored, and exec keeps it ignored: the
    # worker would then outlive stop()'s SIGINT by STOP_TIMEOUT_S and the server's SIGTERM.
    script = (
        "import os, signal, sys\n"
        "from pathlib import Path\n"
        "from flows.server import spawn\n"
        "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
        "child = spawn('probe', [sys.executable, '-c', 'import signal; "
        "print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)'], dict(os.environ), Path(sys.argv[1]))\n"
        "child.proc.wait(60)\n"
        "print(signal.getsignal(signal.SIGINT) == signal.SIG_IGN)\n")
    log = tmp_path / "probe.log"
    result = subprocess.run([sys.executable, "-c", script, str(log)], cwd=REPO, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0 and result.stdout.strip() == "True", result.stderr  # the parent's own is kept
    assert log.read_text().strip() == "True"  # the child handles SIGINT (KeyboardInterrupt)


@pytest.mark.slow
@pytest.mark.parametrize("sigint", ["default", "ignored"])
def test_serve_runs_until_ctrl_c_then_leaves_nothing_behind(tmp_path, sigint):
    """'ignored': started as a script's background job is, SIGINT ignored from the start."""
    env = {**os.environ, "WORLDLINE_DATA_ROOT": str(tmp_path)}
    ignore = (lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if sigint == "ignored" else None
    proc = subprocess.Popen([sys.executable, "-c", "from flows.server import serve; serve(deploy=False)"],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=ignore)
    lines = []
    try:
        for line in proc.stdout:  # ends when serve exits, so a failed start cannot hang here
            lines.append(line)
            if line.startswith("Ctrl-C"):
                break
        text = "".join(lines)
        pids = [int(p) for p in re.findall(r"pid (\d+)", text)]
        assert len(pids) == 2 and "PREFECT_API_URL=http://127.0.0.1:" in text, text
        kept = tmp_path / "prefect" / AUTH_FILE
        assert f"kept in {kept}): {kept.read_text().strip()}" in text  # a new string: shown once, with its file
        assert f'PREFECT_API_AUTH_STRING="$(cat {kept})"' in text
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=120) == 0, proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
        assert group_members(pid) == []
    assert (tmp_path / "prefect" / "server.log").is_file() and (tmp_path / "prefect" / "worker.log").is_file()


@pytest.mark.slow
def test_a_killed_serve_leaves_no_server_or_worker_behind(tmp_path):
    """SIGKILL gives serve no chance to stop its children: they stop because their parent died."""
    env = {**os.environ, "WORLDLINE_DATA_ROOT": str(tmp_path)}
    proc = subprocess.Popen([sys.executable, "-c", "from flows.server import serve; serve(deploy=False)"],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    try:
        for line in proc.stdout:
            lines.append(line)
            if line.startswith("Ctrl-C"):
                break
        pids = [int(p) for p in re.findall(r"pid (\d+)", "".join(lines))]
        assert len(pids) == 2, "".join(lines)
        proc.kill()
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and any(group_members(pid) for pid in pids):
        time.sleep(0.5)
    left = {pid: group_members(pid) for pid in pids if group_members(pid)}
    for pid in left:
        os.killpg(pid, signal.SIGKILL)
    assert left == {}, "the server or the worker outlived a SIGKILLed serve"

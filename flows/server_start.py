"""Starting the local stack's parts (flows/server.py): the Prefect server (Prefect's own app
behind a Host check), the process work pool, the deployments of prefect.yaml, and a worker."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import uuid
from pathlib import Path

from flows.server_auth import ALLOWED_HOSTS, HOST, AuthString, child_env, server_env
from flows.server_children import PROJECT_ROOT, Child, StackError, prefect_command, spawn, stop, wait_until
from schemas.settings import Settings

PREFECT_FILE = PROJECT_ROOT / "prefect.yaml"
POOL = "worldline-local"
SERVER_LOG = "server.log"
WORKER_LOG = "worker.log"
DEPLOY_LOG = "deploy.log"


def free_port(host: str = HOST) -> int:
    with socket.socket() as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]


def healthy(api_url: str) -> bool:
    import httpx

    try:
        return httpx.get(f"{api_url}/health", timeout=5).status_code == 200
    except httpx.HTTPError:
        return False


def run_server(port: int) -> None:
    """What the server child runs: Prefect's app as `prefect server start` runs it (same factory,
    uvicorn options from the same settings), behind Starlette's Host check.

    Prefect has no setting for allowed hosts, and the auth string alone would still let a rebound
    name reach the UI and the unauthenticated health routes. The port is not compared: a browser
    can only reach this socket through a name that resolves here, and that name is what is checked.
    """
    import prefect
    import uvicorn
    from prefect.server.api.server import create_app
    from prefect.settings import get_current_settings
    from starlette.middleware.trustedhost import TrustedHostMiddleware

    server = get_current_settings().server
    print(f"Prefect {prefect.__version__} server on http://{HOST}:{port}: auth string required, CSRF protection on, "
          f"hosts {', '.join(ALLOWED_HOSTS)} only", flush=True)
    app = TrustedHostMiddleware(create_app(final=True), allowed_hosts=list(ALLOWED_HOSTS), www_redirect=False)
    uvicorn.run(app, host=HOST, port=port, timeout_keep_alive=server.api.keepalive_timeout,
                ws_ping_interval=server.api.websocket_ping_interval, ws_ping_timeout=server.api.websocket_ping_timeout,
                log_level=server.logging_level.lower())


def start_server(settings: Settings, auth: AuthString, port: int | None = None, ui: bool = False,
                 env: dict[str, str] | None = None) -> tuple[Child, str]:
    """Start the Prefect server (`run_server`) on 127.0.0.1 (a free port unless given); returns it and its API URL.

    The scheduler and the other services run inside it, so cron schedules create runs.
    """
    port = port or free_port()
    api_url = f"http://{HOST}:{port}/api"
    home = settings.prefect_home_path.resolve()
    home.mkdir(parents=True, exist_ok=True)
    args = [sys.executable, "-m", "flows.server", str(port)]
    server = spawn("prefect server", args, server_env(settings, port, auth, ui, env), home / SERVER_LOG)
    try:
        wait_until(lambda: healthy(api_url), server, f"prefect server at {api_url}")
    except BaseException:
        stop(server, signal.SIGTERM)
        raise
    return server, api_url


def ensure_pool(api_url: str, auth: AuthString, pool: str = POOL) -> None:
    """Create the process work pool unless it exists; refuse a pool of another type."""
    from prefect.client.orchestration import SyncPrefectClient
    from prefect.client.schemas.actions import WorkPoolCreate
    from prefect.exceptions import ObjectNotFound
    from prefect.workers.process import ProcessWorker

    with SyncPrefectClient(api_url, auth_string=auth.value) as client:
        try:
            existing = client.read_work_pool(pool)
        except ObjectNotFound:
            client.create_work_pool(WorkPoolCreate(
                name=pool, type="process", base_job_template=ProcessWorker.get_default_base_job_template()))
            return
    if existing.type != "process":
        raise StackError(f"work pool {pool!r} at {api_url} is of type {existing.type!r}, not 'process'")


def deploy_flows(api_url: str, settings: Settings, auth: AuthString, prefect_file: Path = PREFECT_FILE,
                 env: dict[str, str] | None = None) -> str:
    """`prefect --no-prompt deploy --all` from the project root; returns its output, raises StackError on failure."""
    if not Path(prefect_file).is_file():
        raise StackError(f"{prefect_file}: no such deployment file")
    args = prefect_command("--no-prompt", "deploy", "--all", "--prefect-file", str(Path(prefect_file).resolve()))
    log = settings.prefect_home_path.resolve() / DEPLOY_LOG
    log.parent.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(args, cwd=PROJECT_ROOT, env=child_env(settings, api_url, env, auth), stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=600)
    output = done.stdout + done.stderr
    with open(log, "a") as out:
        out.write(f"$ {' '.join(args)}\n{output}\n")
    if done.returncode != 0:
        tail = "\n".join(output.splitlines()[-30:])
        raise StackError(f"prefect deploy failed with {done.returncode}; see {log}:\n{tail}")
    return output


def prune_deployments(api_url: str, auth: AuthString, prefect_file: Path = PREFECT_FILE) -> list[str]:
    """Delete the deployments an earlier prefect.yaml made (tagged ``worldline``) that this one no
    longer names: a renamed deployment would otherwise stay in the server's database beside its
    new name, running what its old parameters said. Returns the 'flow/name' of each deleted."""
    import yaml
    from prefect.client.orchestration import SyncPrefectClient
    from prefect.client.schemas.filters import DeploymentFilter, DeploymentFilterTags

    named = {d["name"] for d in yaml.safe_load(Path(prefect_file).read_text())["deployments"]}
    ours = DeploymentFilter(tags=DeploymentFilterTags(all_=["worldline"]))
    gone = []
    with SyncPrefectClient(api_url, auth_string=auth.value) as client:
        for deployment in client.read_deployments(deployment_filter=ours):
            if deployment.name not in named:
                client.delete_deployment(deployment.id)
                gone.append(f"{client.read_flow(deployment.flow_id).name}/{deployment.name}")
    return gone


def start_worker(api_url: str, settings: Settings, auth: AuthString, pool: str = POOL, name: str | None = None,
                 env: dict[str, str] | None = None) -> Child:
    """Start a process worker on `pool` and wait until the server lists it."""
    name = name or f"worldline-{uuid.uuid4().hex[:8]}"
    args = prefect_command("worker", "start", "--pool", pool, "--type", "process", "--name", name)
    log = settings.prefect_home_path.resolve() / WORKER_LOG
    worker = spawn("prefect worker", args, child_env(settings, api_url, env, auth), log)
    try:
        wait_until(lambda: worker_joined(api_url, auth, pool, name), worker, f"worker {name!r} on pool {pool!r}")
    except BaseException:
        stop(worker, signal.SIGINT)
        raise
    return worker


def worker_joined(api_url: str, auth: AuthString, pool: str, name: str) -> bool:
    from prefect.client.orchestration import SyncPrefectClient
    from prefect.exceptions import ObjectNotFound

    with SyncPrefectClient(api_url, auth_string=auth.value) as client:
        try:
            return any(w.name == name for w in client.read_workers_for_work_pool(pool))
        except ObjectNotFound:  # the worker creates the pool when it is missing
            return False

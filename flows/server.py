"""A local Prefect server and process worker on 127.0.0.1, started and stopped by PID.

`serve` backs `worldline server`; `LocalStack` is the same thing as a context manager (the
integration tests use it). The server keeps its SQLite database in `Settings().prefect_home_path`
(`<data_root>/prefect` by default), so one data root holds one lineage file and one Prefect
history. Logs go next to it: server.log, worker.log, deploy.log.

The API is closed to everyone but this user (issue 26: three requests from a page of another
origin made the worker run a shell command). It wants an auth string: the user's own
PREFECT_SERVER_API_AUTH_STRING, else one generated on the first start and kept, mode 0600,
in `api-auth-string` next to the database, so each data root has its own. Every child here
gets it as PREFECT_API_AUTH_STRING, and the worker hands it on to the flow runs it spawns.
State changes also want a CSRF token, CORS admits only the server's own origins, and a request
naming any host but 127.0.0.1 or localhost is refused (DNS rebinding).

Children run in sessions of their own: a Ctrl-C in the terminal reaches only this process,
which then stops the worker first (with SIGINT: a Prefect worker ignores SIGTERM) and the
server after it, each by PID, and kills only as a last resort.
"""

from __future__ import annotations

import os
import secrets
import shlex
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from schemas.settings import Settings

PROJECT_ROOT = Path(__file__).resolve().parents[1]
PREFECT_FILE = PROJECT_ROOT / "prefect.yaml"
POOL = "worldline-local"
HOST = "127.0.0.1"
SERVER_LOG = "server.log"
WORKER_LOG = "worker.log"
DEPLOY_LOG = "deploy.log"
AUTH_FILE = "api-auth-string"
AUTH_USER = "worldline"  # the UI's login asks for user:password
SERVER_AUTH_VAR = "PREFECT_SERVER_API_AUTH_STRING"
CLIENT_AUTH_VAR = "PREFECT_API_AUTH_STRING"
ALLOWED_HOSTS = (HOST, "localhost")
# A server start takes 10-30 s on this two-core machine when it is busy; keep a wide margin.
START_TIMEOUT_S = 180.0
STOP_TIMEOUT_S = 30.0


class StackError(RuntimeError):
    """A server, worker or deploy step failed; the message names its log file."""


@dataclass
class Child:
    """One process this module started, with the file its output goes to."""

    name: str
    proc: subprocess.Popen
    log: Path

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def tail(self, lines: int = 30) -> str:
        try:
            return "\n".join(self.log.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""


def free_port(host: str = HOST) -> int:
    with socket.socket() as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]


@dataclass(frozen=True)
class AuthString:
    """The string the server wants (Basic auth), where it comes from, and whether this start made it."""

    value: str
    source: str  # the file that keeps it, or the variable the user set
    created: bool = False

    def notice(self) -> str:
        """What `serve` prints: the secret only on the start that generated it, its place always."""
        if self.created:
            return f"API auth string (new, shown this once; kept in {self.source}): {self.value}"
        return f"API auth string: in {self.source}"

    def export_hint(self) -> str:
        if self.source == SERVER_AUTH_VAR:
            return f'{CLIENT_AUTH_VAR}="${SERVER_AUTH_VAR}"'
        return f'{CLIENT_AUTH_VAR}="$(cat {shlex.quote(self.source)})"'


def auth_string(settings: Settings, environ: dict[str, str] | None = None) -> AuthString:
    """The user's PREFECT_SERVER_API_AUTH_STRING if set; else the one kept under the data root,
    generated (with `secrets`) and written 0600 when there is none yet."""
    environ = os.environ if environ is None else environ
    if environ.get(SERVER_AUTH_VAR):
        return AuthString(environ[SERVER_AUTH_VAR], SERVER_AUTH_VAR)
    path = settings.prefect_home_path.resolve() / AUTH_FILE
    try:
        kept = path.read_text().strip()
    except FileNotFoundError:
        kept = ""
    if kept:
        if path.stat().st_mode & 0o077:
            path.chmod(0o600)
        return AuthString(kept, str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    value = f"{AUTH_USER}:{secrets.token_urlsafe(32)}"
    # Written whole under another name, then renamed: a reader never sees half a secret, and
    # the file is never readable by others, not even for a moment.
    tmp = path.with_name(f".{AUTH_FILE}.{os.getpid()}")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as out:
        out.write(value + "\n")
    os.replace(tmp, path)
    return AuthString(value, str(path), created=True)


def child_env(settings: Settings, api_url: str | None = None, extra: dict[str, str] | None = None,
              auth: AuthString | None = None) -> dict[str, str]:
    """Environment for every child: absolute data paths (flow runs change directory), no prompts,
    and (given `auth`) the client side of the server's auth string and CSRF protection."""
    env = dict(os.environ)
    env["WORLDLINE_DATA_ROOT"] = str(settings.data_root.resolve())
    if settings.warehouse is not None:
        env["WORLDLINE_WAREHOUSE"] = str(settings.warehouse.resolve())
    # The server's database belongs to the data root it serves, whatever PREFECT_HOME says.
    env["PREFECT_HOME"] = env["WORLDLINE_PREFECT_HOME"] = str(settings.prefect_home_path.resolve())
    env["PREFECT_CLI_PROMPT"] = "false"
    # No network here beyond package registries: telemetry would only log failures.
    env.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    env.setdefault("PREFECT_SERVER_UI_SHOW_PROMOTIONAL_CONTENT", "false")
    if api_url:
        env["PREFECT_API_URL"] = api_url
    env.update(extra or {})
    if auth is not None:
        env[CLIENT_AUTH_VAR] = auth.value
        env["PREFECT_CLIENT_CSRF_SUPPORT_ENABLED"] = "true"
        env.pop(SERVER_AUTH_VAR, None)  # only the server needs its side
    return env


def server_env(settings: Settings, port: int, auth: AuthString, ui: bool,
               extra: dict[str, str] | None = None) -> dict[str, str]:
    """A client's environment plus the server's side: auth string, CSRF protection, its own origins."""
    env = child_env(settings, f"http://{HOST}:{port}/api", extra, auth)
    env[SERVER_AUTH_VAR] = auth.value
    env["PREFECT_SERVER_CSRF_PROTECTION_ENABLED"] = "true"
    # The UI may be opened as localhost while it calls the API at 127.0.0.1: both are its own.
    env["PREFECT_SERVER_CORS_ALLOWED_ORIGINS"] = ",".join(f"http://{h}:{port}" for h in ALLOWED_HOSTS)
    env["PREFECT_SERVER_UI_ENABLED"] = "true" if ui else "false"
    return env


def prefect_command(*args: str) -> list[str]:
    """The Prefect CLI of this interpreter (no reliance on PATH)."""
    return [sys.executable, "-m", "prefect", *args]


def spawn(name: str, args: list[str], env: dict[str, str], log: Path) -> Child:
    """Start ``args`` in a session of its own, logging to ``log``. It stops on SIGINT even when
    this process ignores SIGINT (a background job of a script, whose shell starts it so): an
    ignored signal stays ignored across exec, a handled one is reset to its default."""
    log.parent.mkdir(parents=True, exist_ok=True)
    main = threading.current_thread() is threading.main_thread()
    ignored = main and signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    if ignored:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with open(log, "ab") as out:
            proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                    env=env, cwd=PROJECT_ROOT, start_new_session=True,
                                    preexec_fn=_dies_with(os.getpid()) if main else None)
    finally:
        if ignored:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
    return Child(name, proc, log)


def _dies_with(parent: int):
    """A preexec_fn: the child gets SIGINT (which stops the server and the worker cleanly) when
    this process dies, SIGKILL included, so a killed `worldline server` leaves no worker running
    deployments (issue 26). Linux's PR_SET_PDEATHSIG fires when the *thread* that started the
    child exits, so it is set only for children the main thread starts; a parent already gone
    by the time it is set is caught by the pid check."""
    def arm() -> None:
        if sys.platform.startswith("linux"):
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGINT, 0, 0, 0)  # PR_SET_PDEATHSIG
            if os.getppid() != parent:
                os._exit(1)
    return arm


def _died(child: Child) -> StackError:
    return StackError(f"{child.name} (pid {child.pid}) exited with {child.proc.returncode}; "
                      f"see {child.log}:\n{child.tail()}")


def wait_until(ready, child: Child, what: str, timeout: float = START_TIMEOUT_S) -> None:
    """Poll `ready()` twice a second until it is true; fail early if `child` exits meanwhile."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not child.alive():
            raise _died(child)
        if ready():
            return
        time.sleep(0.5)
    raise StackError(f"{what} not ready after {timeout:.0f} s; see {child.log}")


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


def group_members(pgid: int) -> list[int]:
    """Live (not zombie) processes in a process group, read from /proc (Linux)."""
    members = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z" and int(fields[2]) == pgid:
            members.append(int(stat.parent.name))
    return members


def stop(child: Child, first: signal.Signals, timeout: float = STOP_TIMEOUT_S) -> signal.Signals | None:
    """Stop a child by PID: `first`, then SIGTERM, then SIGKILL, waiting `timeout` s after each.

    Returns the signal it stopped on (None if it had already exited). Anything still in its
    process group then gets SIGTERM and SIGKILL. (Flow runs get sessions of their own; a worker
    that stops gracefully kills the ones still running, which is why it gets SIGINT first.)
    """
    stopped_by = None
    for sig in dict.fromkeys((first, signal.SIGTERM, signal.SIGKILL)):
        if not child.alive():
            break
        child.proc.send_signal(sig)
        try:
            child.proc.wait(timeout)
            stopped_by = sig
            break
        except subprocess.TimeoutExpired:
            continue
    for sig in (signal.SIGTERM, signal.SIGKILL):
        if not group_members(child.pid):
            break
        try:
            os.killpg(child.pid, sig)
        except ProcessLookupError:
            break
        deadline = time.monotonic() + 5
        while group_members(child.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
    return stopped_by


class LocalStack:
    """Server + work pool + deployments + worker, as a context manager. Stops both on exit."""

    def __init__(self, settings: Settings | None = None, port: int | None = None, pool: str = POOL,
                 deploy: bool = True, ui: bool = False, prefect_file: Path = PREFECT_FILE,
                 env: dict[str, str] | None = None):
        self.settings = settings or Settings()
        self.port, self.pool, self.deploy, self.ui = port, pool, deploy, ui
        self.prefect_file, self.extra_env = prefect_file, dict(env or {})
        self.server: Child | None = None
        self.worker: Child | None = None
        self.api_url: str | None = None
        self.auth: AuthString | None = None
        self.deploy_output = ""

    @property
    def server_pid(self) -> int | None:
        return self.server.pid if self.server else None

    @property
    def worker_pid(self) -> int | None:
        return self.worker.pid if self.worker else None

    @property
    def auth_string(self) -> str | None:
        return self.auth.value if self.auth else None

    def env(self) -> dict[str, str]:
        """The environment a `prefect` command needs to talk to this server."""
        return child_env(self.settings, self.api_url, self.extra_env, self.auth)

    def start(self) -> LocalStack:
        try:
            self.auth = auth_string(self.settings, {**os.environ, **self.extra_env})
            self.server, self.api_url = start_server(self.settings, self.auth, self.port, self.ui, self.extra_env)
            ensure_pool(self.api_url, self.auth, self.pool)
            if self.deploy:
                self.deploy_output = deploy_flows(self.api_url, self.settings, self.auth, self.prefect_file,
                                                  self.extra_env)
            self.worker = start_worker(self.api_url, self.settings, self.auth, self.pool, env=self.extra_env)
        except BaseException:
            self.stop()
            raise
        return self

    def dead(self) -> Child | None:
        """The first child that exited on its own, if any."""
        return next((c for c in (self.server, self.worker) if c is not None and not c.alive()), None)

    def stop(self) -> dict[str, signal.Signals | None]:
        """Worker first (it reports to the server), with SIGINT; then the server, with SIGTERM."""
        stopped = {}
        if self.worker is not None:
            stopped["worker"] = stop(self.worker, signal.SIGINT)
        if self.server is not None:
            stopped["server"] = stop(self.server, signal.SIGTERM)
        return stopped

    def __enter__(self) -> LocalStack:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def serve(port: int | None = None, pool: str = POOL, deploy: bool = True) -> None:
    """Run a local server (with UI) and a process worker until Ctrl-C or SIGTERM, then stop both.

    Raises StackError if either exits on its own.
    """
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _interrupt) if main else None
    # A background job of a script starts with SIGINT ignored, and Python keeps it ignored:
    # without this, `kill -INT` (what stops the stack) would never reach it.
    ignored = main and signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    if ignored:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    stack = LocalStack(Settings(), port=port, pool=pool, deploy=deploy, ui=True)
    try:
        stack.start()
        print(f"Prefect server pid {stack.server_pid}: API {stack.api_url}, UI {stack.api_url.removesuffix('/api')}\n"
              f"process worker pid {stack.worker_pid} on pool {pool!r}; logs in {stack.settings.prefect_home_path}\n"
              f"{stack.auth.notice()}\n"
              f"to use it: export PREFECT_API_URL={stack.api_url} {stack.auth.export_hint()}\n"
              f"Ctrl-C stops both.", flush=True)
        while (dead := stack.dead()) is None:
            time.sleep(1)
        raise _died(dead)
    except KeyboardInterrupt:
        print("stopping worker and server...", flush=True)
    finally:
        stack.stop()
        if main:
            signal.signal(signal.SIGTERM, previous)
        if ignored:
            signal.signal(signal.SIGINT, signal.SIG_IGN)


if __name__ == "__main__":  # the server child of start_server: python -m flows.server PORT
    run_server(int(sys.argv[1]))

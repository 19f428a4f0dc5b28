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

The parts sit beside this module: the auth string and the children's environments in
server_auth.py, starting and stopping processes in server_children.py, and starting the server,
pool, deployments and worker in server_start.py.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from pathlib import Path

from flows.server_auth import AUTH_FILE, AuthString, auth_string, child_env  # noqa: F401  (AUTH_FILE: tests)
from flows.server_children import Child, StackError, died, group_members, spawn, stop  # noqa: F401  (tests, cli)
from flows.server_found import announce, withdraw
from flows.server_start import (POOL, PREFECT_FILE, deploy_flows, ensure_pool, prune_deployments, run_server,
                                start_server, start_worker)
from schemas.settings import Settings


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
        self.pruned: list[str] = []  # deployments of an earlier prefect.yaml, deleted on start

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
                self.pruned = prune_deployments(self.api_url, self.auth, self.prefect_file)
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
    announced = None
    try:
        stack.start()
        announced = announce(stack.settings, stack.api_url)  # commands on this data root use this server
        print(f"Prefect server pid {stack.server_pid}: API {stack.api_url}, UI {stack.api_url.removesuffix('/api')}\n"
              f"process worker pid {stack.worker_pid} on pool {pool!r}; logs in {stack.settings.prefect_home_path}\n"
              f"{stack.auth.notice()}\n"
              + "".join(f"deleted deployment {name}: prefect.yaml names it no more\n" for name in stack.pruned) +
              f"to use it: export PREFECT_API_URL={stack.api_url} {stack.auth.export_hint()}\n"
              f"Ctrl-C stops both.", flush=True)
        while (dead := stack.dead()) is None:
            time.sleep(1)
        raise died(dead)
    except KeyboardInterrupt:
        print("stopping worker and server...", flush=True)
    finally:
        if announced is not None:
            withdraw(announced)
        stack.stop()
        if main:
            signal.signal(signal.SIGTERM, previous)
        if ignored:
            signal.signal(signal.SIGINT, signal.SIG_IGN)


if __name__ == "__main__":  # the server child of start_server: python -m flows.server PORT
    run_server(int(sys.argv[1]))

"""A command's Prefect API: a running server rather than a temporary one (issue 30).

A flow started with no PREFECT_API_URL starts Prefect's temporary server, 17-22 s here, even
while `worldline server` runs for the same data root. That server now leaves its API URL and
pid in ``<prefect_home>/server.json`` while it runs; a command (the root callback in
flows/cli_shell.py, before Prefect is imported) that finds no PREFECT_API_URL uses it when its
pid lives and its API answers, with the auth string kept beside it (flows/server_auth.py), so its runs show in that
server's UI. A PREFECT_API_URL the user set is used as it is, but must answer: when nothing
does, the command says so in one line (exit 5) instead of Prefect retrying for minutes.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from flows.server_auth import CLIENT_AUTH_VAR, auth_string
from schemas.errors import EnvironmentFault
from schemas.settings import Settings

SERVER_FILE = "server.json"


def answers(api_url: str, timeout: float = 3.0) -> bool:
    import httpx

    try:
        return httpx.get(f"{api_url.rstrip('/')}/health", timeout=timeout).status_code == 200
    except httpx.HTTPError:
        return False


def announce(settings: Settings, api_url: str) -> Path:
    """Say, for this data root, that this process serves ``api_url`` (``withdraw`` when it stops)."""
    path = settings.prefect_home_path.resolve() / SERVER_FILE
    tmp = path.with_name(f".{SERVER_FILE}.{os.getpid()}")
    tmp.write_text(json.dumps({"api_url": api_url, "pid": os.getpid()}))
    os.replace(tmp, path)
    return path


def withdraw(path: Path) -> None:
    try:
        if json.loads(path.read_text()).get("pid") == os.getpid():
            path.unlink()
    except (OSError, ValueError):
        pass


def _alive(pid) -> bool:
    try:
        os.kill(int(pid), 0)
    except (OSError, TypeError, ValueError):
        return False
    return True


def use_running_server() -> str | None:
    """The API URL this command's flows report to, when not a temporary server's: the
    PREFECT_API_URL in the environment (the user's, or ``find_running_server``'s);
    EnvironmentFault when nothing answers there."""
    given = os.environ.get("PREFECT_API_URL")
    if given and not answers(given):
        raise EnvironmentFault(f"PREFECT_API_URL={given}: no Prefect server answers there (start one with "
                               "`worldline server`, or unset it for a temporary one)")
    return given or None


def find_running_server(settings: Settings | None = None) -> str | None:
    """With no PREFECT_API_URL: the server `worldline server` runs for this data root, when its
    pid lives and its API answers, set in this process's environment with its auth string.
    Called before anything imports Prefect, which reads its settings once, on import."""
    if os.environ.get("PREFECT_API_URL"):
        return None
    settings = settings or Settings()
    try:
        found = json.loads((settings.prefect_home_path.resolve() / SERVER_FILE).read_text())
        api_url = str(found["api_url"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not _alive(found.get("pid")) or not answers(api_url):
        return None
    os.environ["PREFECT_API_URL"] = api_url
    if not os.environ.get(CLIENT_AUTH_VAR):
        os.environ[CLIENT_AUTH_VAR] = auth_string(settings).value
        os.environ["PREFECT_CLIENT_CSRF_SUPPORT_ENABLED"] = "true"
    return api_url

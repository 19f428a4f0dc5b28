"""Who may talk to the local Prefect server (flows/server.py): the API's auth string, and the
environments of the server and of its clients (the worker, deploys, the flow runs they start).

The API is closed to everyone but this user (issue 26). It wants an auth string: the user's own
PREFECT_SERVER_API_AUTH_STRING, else one generated on the first start and kept, mode 0600, in
`api-auth-string` next to the database. State changes also want a CSRF token, and CORS admits
only the server's own origins.
"""

from __future__ import annotations

import os
import secrets
import shlex
from dataclasses import dataclass

from schemas.settings import Settings

HOST = "127.0.0.1"
AUTH_FILE = "api-auth-string"
AUTH_USER = "worldline"  # the UI's login asks for user:password
SERVER_AUTH_VAR = "PREFECT_SERVER_API_AUTH_STRING"
CLIENT_AUTH_VAR = "PREFECT_API_AUTH_STRING"
ALLOWED_HOSTS = (HOST, "localhost")


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

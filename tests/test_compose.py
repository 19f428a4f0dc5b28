"""docker-compose.yml agrees with the Dockerfile, pyproject, the settings class, Prefect's CLI and prefect.yaml.

No Docker engine runs here, so the file is parsed, and each command line is parsed by the
program it calls (Prefect's own CLI parser) or checked against the service it points at.
"""

import re
import shlex
import tomllib
from urllib.parse import urlsplit

import pytest
import yaml

from flows.server import AUTH_FILE, POOL
from schemas.settings import Settings

from tests.support import REPO

COMPOSE = yaml.safe_load((REPO / "docker-compose.yml").read_text())
SERVICES = COMPOSE["services"]
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
PREFECT_YAML = yaml.safe_load((REPO / "prefect.yaml").read_text())
WORLDLINE = sorted(name for name, s in SERVICES.items() if s.get("image") == "worldline:local")
ONE_SHOT = {"deploy"}


def dockerfile() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) pairs, continuation lines joined, comments dropped."""
    text = re.sub(r"\\\n", " ", (REPO / "Dockerfile").read_text())
    lines = [line.strip() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    return [(line.split(None, 1)[0].upper(), line.split(None, 1)[1]) for line in lines]


def instructions(name: str) -> list[str]:
    return [args for instr, args in dockerfile() if instr == name]


def command_lines(service: dict) -> list[list[str]]:
    """The command as argv lists; `sh -c "a && b"` gives one list per part."""
    command = service.get("command") or yaml.safe_load(instructions("CMD")[-1])
    if isinstance(command, str):
        command = shlex.split(command)
    if command[:2] == ["sh", "-c"]:
        return [shlex.split(part) for part in command[2].split("&&")]
    return [command]


def prefect_parse(argv: list[str]) -> tuple[str, dict]:
    """Parse a `prefect ...` command line with Prefect's own CLI: ('module.function', arguments)."""
    from prefect.cli._app import _app

    assert argv[0] == "prefect"
    _, session, _ = _app.meta.parse_args(argv[1:], exit_on_error=False, print_error=False)
    command, bound, _ = _app.parse_args(list(session.arguments.get("tokens", ())), exit_on_error=False,
                                        print_error=False)
    return f"{command.__module__}.{command.__name__}", dict(bound.arguments)


def env(name: str) -> dict[str, str]:
    return {k: str(v) for k, v in (SERVICES[name].get("environment") or {}).items()}


def bare(value: str) -> str:
    """Compose interpolations `${NAME:?message}` / `${NAME:-default}` reduced to NAME."""
    return re.sub(r"\$\{(\w+)[^}]*\}", r"\1", value)


def default(value: str) -> str:
    """What a compose value `${NAME:-default}` gives when NAME is unset (a plain value: itself)."""
    return re.sub(r"\$\{\w+:-([^}]*)\}", r"\1", value)


def flag(argv: list[str], name: str) -> str:
    """Value of `--name=value` or `--name value` in an argv."""
    for i, arg in enumerate(argv):
        if arg.startswith(f"{name}="):
            return arg.split("=", 1)[1]
        if arg == name:
            return argv[i + 1]
    raise AssertionError(f"{name} missing from {argv}")


def pip_installs() -> list[list[str]]:
    return [shlex.split(run)[2:] for run in instructions("RUN") if run.startswith("pip install")]


def extras_installed() -> set[str]:
    return {e for args in pip_installs() for a in args if (m := re.fullmatch(r"(?:\.|/app)\[(.+)\]", a))
            for e in m.group(1).split(",")}


# -- the image -----------------------------------------------------------------------------------
def test_every_worldline_service_builds_the_repo_dockerfile():
    assert set(WORLDLINE) == {"prefect-server", "deploy", "worker", "ray-head", "ray-worker"}
    for name in WORLDLINE:
        build = SERVICES[name]["build"]
        assert (REPO / build["context"] / build["dockerfile"]).resolve() == REPO / "Dockerfile", name


def test_dockerfile_matches_pyproject():
    assert instructions("FROM") == ["python:3.11-slim"]
    assert PYPROJECT["project"]["requires-python"] == ">=3.11,<3.12"
    torch_pin = next(d for d in PYPROJECT["project"]["dependencies"] if d.startswith("torch"))
    torch_runs = [args for args in pip_installs() if any(a.startswith("torch") for a in args)]
    assert torch_runs == [["--index-url", "https://download.pytorch.org/whl/cpu", torch_pin]]
    project = next(args for args in pip_installs() if any(a.startswith(".[") for a in args))
    assert "-e" in project and "asyncpg" in project  # editable: prefect.yaml loads flows by path
    declared = set(PYPROJECT["project"].get("optional-dependencies", {}))
    assert extras_installed() <= declared, f"Dockerfile installs extras pyproject lacks: {extras_installed() - declared}"
    assert instructions("WORKDIR") == ["/app"] and "COPY . /app" in [f"COPY {a}" for a in instructions("COPY")]


def image_env() -> dict[str, str]:
    return dict(pair.split("=", 1) for args in instructions("ENV") for pair in shlex.split(args))


def test_the_image_runs_as_a_user_of_its_own_who_owns_the_data_root_only():
    # Issue 26: the worker runs what a flow run asks, so it must not be root in its container.
    user = instructions("USER")[-1]
    assert user not in ("root", "0") and not user.startswith(("root:", "0:"))
    assert any(re.search(rf"useradd .*\b{user}$", run) for run in instructions("RUN"))
    order = [instr for instr, _ in dockerfile()]
    assert order.index("USER") > max(i for i, instr in enumerate(order) if instr == "RUN")  # nothing after runs as root
    root = env("worker")["WORLDLINE_DATA_ROOT"]
    chowned = [run for run in instructions("RUN") if f"chown -R {user}:{user}" in run]
    assert chowned and root in chowned[0].split() and "/app" not in chowned[0].split()  # the code stays root's
    # before VOLUME: a new volume copies the folder with its owner; later changes would be lost
    steps = dockerfile()
    assert steps.index(("VOLUME", f'["{root}"]')) > steps.index(("RUN", chowned[0]))
    assert instructions("VOLUME") == [f'["{root}"]']
    ui = image_env()["PREFECT_SERVER_UI_STATIC_DIRECTORY"]  # Prefect's own UI folder is root's
    assert ui.startswith(f"/home/{user}/") and ui in chowned[0].split()
    for name in SERVICES:
        assert SERVICES[name].get("user") in (None, user), f"{name} runs as {SERVICES[name]['user']}"


def test_dockerignore_keeps_local_state_out_of_the_context():
    ignored = set((REPO / ".dockerignore").read_text().split())
    assert {".git", ".venv", ".worldline"} <= ignored
    assert {".env", f"**/{AUTH_FILE}"} <= ignored  # secrets would stay in an image layer


def executables() -> dict[str, bool]:
    """Programs the image provides, from pyproject (dependencies, extras installed, scripts)."""
    deps = PYPROJECT["project"]["dependencies"] + [
        d for e in extras_installed() for d in PYPROJECT["project"].get("optional-dependencies", {}).get(e, [])]
    names = {re.split(r"[\[<>=!~; ]", d, maxsplit=1)[0].lower() for d in deps}
    return {"prefect": "prefect" in names, "ray": "ray" in names, "sh": True, "python": True,
            **{script: True for script in PYPROJECT["project"]["scripts"]}}


@pytest.mark.parametrize("name", WORLDLINE + ["<Dockerfile CMD>"])
def test_commands_exist_and_parse(name):
    service = SERVICES.get(name, {})
    provided = executables()
    for argv in command_lines(service):
        assert provided.get(argv[0]), f"{name}: the image has no {argv[0]!r} (add its extra to the Dockerfile)"
        if argv[0] == "prefect":
            prefect_parse(argv)  # raises on an unknown command or option


# -- services talk to each other -------------------------------------------------------------------
def test_pool_is_the_same_everywhere():
    pools = {POOL}
    pools |= {d["work_pool"]["name"] for d in PREFECT_YAML["deployments"]}
    for name in ("worker", "deploy", "<Dockerfile CMD>"):
        for argv in command_lines(SERVICES.get(name, {})):
            command, args = prefect_parse(argv)
            if command == "prefect.cli.worker.start":
                pools.add(args["work_pool_name"])
                assert args["worker_type"] == "process"
            elif command == "prefect.cli.work_pool.create":
                pools.add(args["name"])
                assert args["type"] == "process"
            else:
                assert command == "prefect.cli.deploy._commands.deploy" and args == {"deploy_all": True}
    assert pools == {"worldline-local"}


def test_clients_reach_the_server_with_its_auth_string():
    command, server = prefect_parse(SERVICES["prefect-server"]["command"])
    assert command == "prefect.cli.server.start" and server["host"] == "0.0.0.0"
    auth = env("prefect-server")["PREFECT_SERVER_API_AUTH_STRING"]
    assert re.fullmatch(r"\$\{\w+:\?[^}]+\}", auth), "the auth string must be required, with no default"
    for name in ("deploy", "worker"):
        url = urlsplit(env(name)["PREFECT_API_URL"])
        assert (url.hostname, url.port, url.path) == ("prefect-server", server["port"], "/api")
        assert env(name)["PREFECT_API_AUTH_STRING"] == auth
    health = SERVICES["prefect-server"]["healthcheck"]["test"]
    assert f"http://127.0.0.1:{server['port']}/api/health" in " ".join(health)
    assert SERVICES["prefect-server"]["ports"] == [f"${{BIND_ADDRESS:-127.0.0.1}}:{server['port']}:{server['port']}"]


def test_server_wants_csrf_tokens_and_answers_only_its_own_origins():
    server = env("prefect-server")
    assert server["PREFECT_SERVER_CSRF_PROTECTION_ENABLED"] == "true"
    origins = default(server["PREFECT_SERVER_CORS_ALLOWED_ORIGINS"]).split(",")
    _, start = prefect_parse(SERVICES["prefect-server"]["command"])
    assert "*" not in origins and {urlsplit(o).port for o in origins} == {start["port"]}
    assert f"{urlsplit(default(server['PREFECT_UI_API_URL'])).scheme}://{urlsplit(default(server['PREFECT_UI_API_URL'])).netloc}" in origins
    for name in ("deploy", "worker"):
        assert env(name)["PREFECT_CLIENT_CSRF_SUPPORT_ENABLED"] == "true"


def test_ray_dashboard_listens_on_localhost_unless_asked():
    # Its job API runs code: reachable from the compose network only when RAY_DASHBOARD_HOST says so.
    head = SERVICES["ray-head"]["command"]
    host = flag(head, "--dashboard-host")
    assert re.fullmatch(r"\$\{RAY_DASHBOARD_HOST:-127\.0\.0\.1\}", host)
    assert default(host) == "127.0.0.1"


def test_server_uses_the_postgres_service():
    db = env("postgres")
    url = urlsplit(bare(env("prefect-server")["PREFECT_API_DATABASE_CONNECTION_URL"]))
    assert url.scheme == "postgresql+asyncpg" and url.hostname == "postgres" and url.port == 5432
    assert (url.username, url.password, url.path) == (db["POSTGRES_USER"], bare(db["POSTGRES_PASSWORD"]),
                                                      f"/{db['POSTGRES_DB']}")
    assert "pg_isready" in " ".join(SERVICES["postgres"]["healthcheck"]["test"])


def test_worker_runs_curate_tasks_on_the_ray_head():
    head = SERVICES["ray-head"]["command"]
    assert head[:3] == ["ray", "start", "--head"] and "--block" in head
    worker_node = SERVICES["ray-worker"]["command"]
    assert flag(worker_node, "--address") == f"ray-head:{flag(head, '--port')}" and "--block" in worker_node
    address = urlsplit(env("worker")["WORLDLINE_RAY_ADDRESS"])
    assert (address.scheme, address.hostname, address.port) == ("ray", "ray-head", int(flag(head, "--ray-client-server-port")))
    assert env("worker")["WORLDLINE_TASK_RUNNER"] == "ray"


def test_every_worldline_variable_is_a_setting_and_parses(monkeypatch):
    fields = {f"WORLDLINE_{name.upper()}" for name in Settings.model_fields}
    for name in SERVICES:
        used = {k: v for k, v in env(name).items() if k.startswith("WORLDLINE_")}
        assert set(used) <= fields, f"{name}: {sorted(set(used) - fields)} are not fields of schemas.settings.Settings"
        for key, value in used.items():
            monkeypatch.setenv(key, value)
        settings = Settings()
        for key, value in used.items():
            assert str(getattr(settings, key.removeprefix("WORLDLINE_").lower())) == value


def test_every_prefect_variable_is_a_prefect_setting():
    from prefect.settings import Settings as PrefectSettings
    from prefect.settings.legacy import _get_valid_setting_names

    valid = _get_valid_setting_names(PrefectSettings)
    assert {k for k in image_env() if k.startswith("PREFECT_")} <= valid
    for name in SERVICES:
        unknown = {k for k in env(name) if k.startswith("PREFECT_")} - valid
        assert not unknown, f"{name}: Prefect has no settings {sorted(unknown)}"


def test_one_data_volume_at_the_data_root():
    workdir = instructions("WORKDIR")[-1]
    with_data = {name for name in SERVICES if "WORLDLINE_DATA_ROOT" in env(name)}
    assert with_data >= {"worker", "ray-head", "ray-worker"}  # the lineage writer and the nodes running its tasks
    roots = {env(name)["WORLDLINE_DATA_ROOT"] for name in with_data}
    assert len(roots) == 1
    (root,) = roots
    for name in SERVICES:
        mounts = [v for v in SERVICES[name].get("volumes", []) if v.startswith("worldline-data:")]
        assert mounts == ([f"worldline-data:{root}"] if name in with_data else []), name
    # prefect.yaml's relative inbox, resolved in the image's project root (where `deploy` runs,
    # so where the pull step sends flow runs), is a folder in the volume from the start
    assert not any("working_dir" in s for s in SERVICES.values())
    curate = next(d for d in PREFECT_YAML["deployments"] if d["entrypoint"].endswith(":curate"))
    for inbox in curate["parameters"]["inputs"]:
        assert f"{workdir}/{inbox}".startswith(root + "/")
        assert any(run.startswith("mkdir -p ") and f"{workdir}/{inbox}" in run.split("&&")[0].split()
                   for run in instructions("RUN"))
    used = {v.split(":")[0] for s in SERVICES.values() for v in s.get("volumes", [])}
    assert used == set(COMPOSE["volumes"]) == {"worldline-data", "postgres-data"}


def test_healthchecks_and_start_order():
    for name, service in SERVICES.items():
        if name not in ONE_SHOT:
            assert service.get("healthcheck", {}).get("test"), f"{name} has no healthcheck"
        for dep, rule in (service.get("depends_on") or {}).items():
            assert dep in SERVICES, f"{name} depends on unknown {dep}"
            expected = "service_completed_successfully" if dep in ONE_SHOT else "service_healthy"
            assert rule["condition"] == expected, f"{name} -> {dep}"
    assert SERVICES["deploy"]["restart"] == "no"
    _, worker = prefect_parse(SERVICES["worker"]["command"])
    assert worker["with_healthcheck"] is True
    port = env("worker")["PREFECT_WORKER_WEBSERVER_PORT"]
    assert env("worker")["PREFECT_WORKER_WEBSERVER_HOST"] == "127.0.0.1"  # only its own healthcheck calls it
    assert f"http://127.0.0.1:{port}/health" in " ".join(SERVICES["worker"]["healthcheck"]["test"])

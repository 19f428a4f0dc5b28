"""The curate flow on a process pool writes the same shards and lineage as on threads."""

from prefect.task_runners import ProcessPoolTaskRunner

from flows.curate import curate
from flows.runners import ray_worker_env, task_runner
from schemas.settings import Settings

from tests.support import curate_on, runner_inbox


def test_process_runner_gives_the_same_shards_and_lineage(prefect_harness, tmp_path, monkeypatch):
    inbox = runner_inbox(tmp_path / "inbox")
    runner = task_runner(Settings(task_runner="process", workers=2))
    assert isinstance(runner, ProcessPoolTaskRunner)
    threads = curate_on(curate.with_options(task_runner=task_runner(Settings())), tmp_path / "threads",
                        monkeypatch, inbox)
    processes = curate_on(curate.with_options(task_runner=runner), tmp_path / "processes", monkeypatch, inbox)
    assert threads[0]["status"] == processes[0]["status"] == "partial" and processes[0]["failed"] == 1
    assert threads[0]["counts"] == processes[0]["counts"] and processes[0]["clips"] >= 1
    assert threads[1] and threads[1] == processes[1]  # byte-identical shards under the same paths
    assert threads[2] == processes[2]  # the same lineage rows, written once by the flow process


def test_ray_workers_get_the_client_side_only():
    environ = {"PREFECT_API_URL": "http://127.0.0.1:4200/api", "PREFECT_API_AUTH_STRING": "worldline:s3cret",
               "PREFECT_SERVER_API_AUTH_STRING": "worldline:s3cret", "WORLDLINE_WORKERS": "2",
               "PREFECT_API_DATABASE_CONNECTION_URL": "postgresql+asyncpg://prefect:pw@postgres/prefect",
               "MUJOCO_GL": "egl", "HOME": "/root"}
    assert ray_worker_env(environ) == {"PREFECT_API_URL": "http://127.0.0.1:4200/api", "WORLDLINE_WORKERS": "2",
                                       "PREFECT_API_AUTH_STRING": "worldline:s3cret", "MUJOCO_GL": "egl"}

"""The curate flow on a local Ray cluster writes the same shards and lineage as on threads."""

import pytest

pytest.importorskip("prefect_ray")

from flows.curate import curate  # noqa: E402
from flows.runners import task_runner  # noqa: E402
from schemas.settings import Settings  # noqa: E402

from tests.support import curate_on, runner_inbox  # noqa: E402


@pytest.fixture(scope="module")
def inbox(tmp_path_factory):
    return runner_inbox(tmp_path_factory.mktemp("inbox"))


@pytest.mark.slow
def test_ray_runner_gives_the_same_shards_and_lineage(prefect_harness, tmp_path, monkeypatch, inbox):
    ray_runner = task_runner(Settings(task_runner="ray", workers=2))
    assert type(ray_runner).__name__ == "WorkerEnvRayTaskRunner"
    local = curate_on(curate.with_options(task_runner=task_runner(Settings())), tmp_path / "local", monkeypatch, inbox)
    on_ray = curate_on(curate.with_options(task_runner=ray_runner), tmp_path / "ray", monkeypatch, inbox)
    assert local[0]["status"] == on_ray[0]["status"] == "partial" and on_ray[0]["failed"] == 1
    assert local[0]["counts"] == on_ray[0]["counts"] and on_ray[0]["clips"] >= 1
    assert local[1] and local[1] == on_ray[1]  # byte-identical shards under the same relative paths
    assert local[2] == on_ray[2]  # the same lineage rows, written once by the flow process


def test_the_runner_is_a_setting():
    from prefect.task_runners import ThreadPoolTaskRunner

    runner = task_runner(Settings(task_runner="local", workers=3))
    assert isinstance(runner, ThreadPoolTaskRunner) and runner._max_workers == 3
    remote = task_runner(Settings(task_runner="ray", ray_address="ray://head:10001"))
    assert remote.address == "ray://head:10001" and "num_cpus" not in remote.init_kwargs

"""The curate flow on a local Ray cluster writes the same shards and lineage as on threads."""

import hashlib

import pytest

pytest.importorskip("prefect_ray")

from flows.curate import curate  # noqa: E402
from flows.runners import task_runner  # noqa: E402
from schemas.settings import Settings  # noqa: E402
from tasks.manifests import load  # noqa: E402
from tasks.mp4 import write_mp4  # noqa: E402
from tasks.sim.episode import rollout  # noqa: E402
from warehouse.store import Warehouse  # noqa: E402

from tests.support import MANIFESTS  # noqa: E402

MANIFEST = MANIFESTS / "conveyor_push.yaml"
LINEAGE = """SELECT kind, count(*) FROM artifacts GROUP BY kind
             UNION ALL SELECT 'edges', count(*) FROM edges
             UNION ALL SELECT 'rejections', count(*) FROM rejections ORDER BY 1"""


@pytest.fixture(scope="module")
def inbox(tmp_path_factory):
    folder = tmp_path_factory.mktemp("inbox")
    scenario = load(MANIFEST).model_copy(update={"horizon_s": 3.0})
    for seed in (1, 2):
        write_mp4(folder / f"episode_{seed}.mp4", rollout(scenario, seed).frames["overhead"], 30)
    (folder / "broken.mp4").write_bytes(b"not a video" * 50)
    return folder


def _run(root, monkeypatch, inbox, flow):
    monkeypatch.setenv("WORLDLINE_DATA_ROOT", str(root))
    summary = flow([str(inbox)], str(MANIFEST))
    shards = {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
              for p in sorted((root / "shards").rglob("*.parquet"))}
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, rows = wh.query(LINEAGE)
    return summary, shards, rows


@pytest.mark.slow
def test_ray_runner_gives_the_same_shards_and_lineage(prefect_harness, tmp_path, monkeypatch, inbox):
    ray_runner = task_runner(Settings(task_runner="ray", workers=2))
    assert type(ray_runner).__name__ == "WorkerEnvRayTaskRunner"
    local = _run(tmp_path / "local", monkeypatch, inbox, curate.with_options(task_runner=task_runner(Settings())))
    on_ray = _run(tmp_path / "ray", monkeypatch, inbox, curate.with_options(task_runner=ray_runner))
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

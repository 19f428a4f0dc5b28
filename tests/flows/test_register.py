from typer.testing import CliRunner

from flows.cli import app
from flows.register import register
from schemas.manifest import manifest_hash
from schemas.settings import Settings
from tasks.manifests import load
from warehouse.store import Warehouse

from tests.support import MANIFESTS

GOOD = MANIFESTS / "bin_pick_dim_forklift.yaml"


def test_register_records_manifest_and_run(prefect_harness, data_root):
    digest = register(str(GOOD))
    assert digest == manifest_hash(load(GOOD))
    register(str(GOOD))  # a second run adds a run row, nothing else
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        counts = wh.counts()
        _, runs = wh.query("SELECT flow, status, manifest_hash, prefect_flow_run_id IS NOT NULL FROM runs")
    assert counts["manifests"] == 1 and counts["artifacts"] == 1 and counts["runs"] == 2
    assert runs == [("register", "completed", digest, True)] * 2


def test_audit_through_the_cli_binds_parameters(prefect_harness, data_root):
    digest = register(str(GOOD))
    runner = CliRunner()
    result = runner.invoke(app, ["audit", "runs", "--manifest", digest, "--format", "json"])
    assert result.exit_code == 0 and '"status": "completed"' in result.output
    result = runner.invoke(app, ["audit", "runs", "--manifest", f"{digest}' OR '1'='1", "--format", "csv"])
    assert result.exit_code == 2 and "no such manifest in lineage" in result.output  # one bound value, no match
    result = runner.invoke(app, ["audit", "ancestry", "--artifact", "x'); DROP TABLE runs; --", "--format", "csv"])
    assert result.exit_code == 2 and "no such artifact in lineage" in result.output
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        assert wh.counts()["runs"] == 1

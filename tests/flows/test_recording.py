"""The stage seam: `RunContext.stage` knows whether a stage is done, times it, and writes its record with its lineage."""

from flows.recording import RunContext
from schemas.records import ArtifactRecord, LineageBatch, RunRecord
from schemas.settings import Settings
from warehouse.store import Warehouse

DIGEST = "m" * 64


def test_a_stage_is_done_once_finished_and_while_its_files_are_there(tmp_path):
    with Warehouse(tmp_path / "lineage.duckdb") as warehouse:
        warehouse.start_run(RunRecord(run_id="r1", flow="probe", manifest_hash=None, prefect_flow_run_id=None))
        run = RunContext(run_id="r1", flow="probe", warehouse=warehouse, manifest_hash=DIGEST, settings=Settings())
        out = tmp_path / "out.bin"
        stage = run.stage("probe", "k1", [out])
        assert not stage.done
        out.write_bytes(b"x")
        made = LineageBatch(artifacts=[ArtifactRecord(artifact_id="a1", kind="report", uri="out.bin", sha256=None,
                                                      stage_run_id=stage.id)])
        record = stage.finish(2, 1, made, attrs={"note": "probe"})
        assert record.stage_run_id == stage.id == run.stage_run_id("probe", "k1")
        assert (record.manifest_hash, record.n_in, record.n_out, record.status, record.attrs) == \
            (DIGEST, 2, 1, "completed", {"note": "probe"})
        assert warehouse.query("SELECT stage_run_id FROM artifacts WHERE artifact_id = 'a1'")[1] == [(stage.id,)]
        assert run.stage("probe", "k1", [out]).done
        out.unlink()
        assert not run.stage("probe", "k1", [out]).done  # its file is gone: do it again
        assert {k: s.done for k, s in run.stages("probe", ["k1", "k2"]).items()} == {"k1": True, "k2": False}


def test_a_failed_stage_is_not_done_and_the_manifest_hash_can_be_another(tmp_path):
    with Warehouse(tmp_path / "lineage.duckdb") as warehouse:
        warehouse.start_run(RunRecord(run_id="r1", flow="probe", manifest_hash=None, prefect_flow_run_id=None))
        run = RunContext(run_id="r1", flow="probe", warehouse=warehouse, manifest_hash=DIGEST, settings=Settings())
        record = run.stage("probe", "k1", manifest_hash=None).finish(1, 0, status="failed")
        assert (record.manifest_hash, record.status) == (None, "failed")
        assert not run.stage("probe", "k1").done

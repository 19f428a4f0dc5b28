"""Every flow run publishes a markdown summary and progress the Prefect UI shows."""

from prefect import flow
from prefect.client.orchestration import get_client
from prefect.client.schemas.filters import ArtifactFilter, ArtifactFilterFlowRunId

from flows.register import register
from flows.report import markdown_table, progress, publish
from tests.support import MANIFESTS


def _artifacts(flow_run_id):
    with get_client(sync_client=True) as api:
        return api.read_artifacts(artifact_filter=ArtifactFilter(flow_run_id=ArtifactFilterFlowRunId(any_=[flow_run_id])))


def test_markdown_table_escapes_cells():
    assert markdown_table(("a", "b"), [(1, "x|y"), (None, 2)]).splitlines() == [
        "| a | b |", "|---|---|", "| 1 | x\\|y |", "|  | 2 |"]


def test_progress_and_summary_reach_the_api(prefect_harness):
    @flow(name="report-probe")
    def probe() -> str:
        from prefect.runtime import flow_run

        with progress(4, "units") as bar:
            for _ in range(4):
                bar.advance()
        publish("probe", "four units", markdown_table(("unit",), [(i,) for i in range(4)]), "probe summary")
        return flow_run.id

    artifacts = _artifacts(probe())
    by_type = {a.type: a for a in artifacts}
    assert by_type["progress"].data == 100.0 and by_type["progress"].description == "units: 4 of 4"
    assert by_type["markdown"].key == "probe-summary" and "| 3 |" in by_type["markdown"].data


def test_register_publishes_its_summary(prefect_harness, data_root):
    state = register(str(MANIFESTS / "conveyor_push.yaml"), return_state=True)
    artifacts = _artifacts(state.state_details.flow_run_id)
    (summary,) = [a for a in artifacts if a.key == "register-summary"]
    assert "conveyor_push" in summary.data and "distractors" in summary.data

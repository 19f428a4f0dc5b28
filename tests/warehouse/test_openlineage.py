"""OpenLineage run events: emitted by real flow runs, valid for the client, equal to the lineage rows."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from openlineage.client.event_v2 import InputDataset, Job, OutputDataset, Run, RunEvent, RunState
from openlineage.client.facet_v2 import dataset_version_dataset, error_message_run, tags_run
from openlineage.client.serde import Serde

from flows.recording import recorded_run
from schemas.settings import Settings
from warehouse import openlineage
from warehouse.store import Warehouse


def events(data_root: Path) -> list[dict]:
    return [json.loads(line) for line in (data_root / openlineage.EVENTS_FILE).read_text().splitlines()]


def rebuilt(event: dict) -> RunEvent:
    """The event made again from its JSON by the client's own classes, whose validators check
    the run id (a UUID), the event time, the URLs and every required field."""
    def dataset(cls, d: dict):
        facets = {}
        for key, facet in d.get("facets", {}).items():
            if key == "version":
                facets[key] = dataset_version_dataset.DatasetVersionDatasetFacet(
                    datasetVersion=facet["datasetVersion"], producer=facet["_producer"])
            else:
                facets[key] = openlineage.WorldlineDatasetFacet(
                    artifactId=facet["artifactId"], kind=facet["kind"], sha256=facet.get("sha256"),
                    manifestHash=facet.get("manifestHash"), producer=facet["_producer"])
        return cls(namespace=d["namespace"], name=d["name"], facets=facets)

    run_facets = {}
    for key, facet in event["run"].get("facets", {}).items():
        if key == "errorMessage":
            run_facets[key] = error_message_run.ErrorMessageRunFacet(
                message=facet["message"], programmingLanguage=facet["programmingLanguage"], producer=facet["_producer"])
        elif key == "tags":  # the client's own version tag
            run_facets[key] = tags_run.TagsRunFacet(tags=[tags_run.TagsRunFacetFields(**t) for t in facet["tags"]],
                                                    producer=facet["_producer"])
        else:
            run_facets[key] = openlineage.WorldlineRunFacet(
                flow=facet["flow"], manifestHash=facet.get("manifestHash"), status=facet.get("status"),
                producer=facet["_producer"])
    return RunEvent(eventType=RunState(event["eventType"]), eventTime=event["eventTime"], producer=event["producer"],
                    run=Run(runId=event["run"]["runId"], facets=run_facets),
                    job=Job(namespace=event["job"]["namespace"], name=event["job"]["name"]),
                    inputs=[dataset(InputDataset, d) for d in event.get("inputs", [])],
                    outputs=[dataset(OutputDataset, d) for d in event.get("outputs", [])])


def check_valid(event: dict) -> None:
    again = json.loads(Serde.to_json(rebuilt(event)))
    assert again == event, "the event does not round-trip through the client's classes"
    assert event["schemaURL"].startswith("https://openlineage.io/spec/")


def check_runs(data_root: Path, runs: list[tuple]) -> None:
    """The events of a corpus run then a curate run (``runs``: their (run_id, flow, status) rows):
    START and COMPLETE each, valid for the client, the curate run's datasets equal to its lineage
    rows, and each run's report page. Called by tests/flows/test_corpus.py, which runs both flows."""
    seen = events(data_root)
    for event in seen:
        check_valid(event)
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, written = wh.query(
            "SELECT a.uri, a.sha256 FROM artifacts a JOIN stage_runs s ON a.stage_run_id = s.stage_run_id "
            "WHERE s.run_id = $r AND a.uri IS NOT NULL", {"r": runs[1][0]})
    assert [(e["run"]["runId"], e["eventType"]) for e in seen] == [
        (runs[0][0], "START"), (runs[0][0], "COMPLETE"), (runs[1][0], "START"), (runs[1][0], "COMPLETE")]
    assert [e["job"]["name"] for e in seen[::2]] == ["worldline.corpus", "worldline.curate"]
    end = seen[3]
    assert end["run"]["facets"]["worldline"]["status"] == runs[1][2] == "completed"
    outputs = {(d["name"], d["facets"]["version"]["datasetVersion"]) for d in end["outputs"]}
    assert outputs == {(str((data_root / uri).resolve()), sha) for uri, sha in written}
    assert {d["facets"]["worldline"]["kind"] for d in end["outputs"]} >= {"clip", "shard"}
    # The source video was recorded by the corpus run: for curate it is an input, not an output.
    inputs = {d["facets"]["worldline"]["kind"] for d in end["inputs"]}
    assert "raw_video" in inputs and not inputs & {"clip", "shard"}
    assert all(Path(d["name"]).is_file() for d in end["inputs"] + end["outputs"])
    # Each run also wrote its report page (flows/announce.py), the curate run's with its clips.
    page = data_root / "reports" / f"{runs[1][0]}.html"
    assert page.is_file() and "<img" in page.read_text()
    assert (data_root / "reports" / f"{runs[0][0]}.html").is_file()


def test_a_failed_run_emits_fail_with_the_error(data_root):
    with pytest.raises(RuntimeError, match="disk on fire"):
        with recorded_run("probe", Settings()):
            raise RuntimeError("disk on fire")
    start, end = events(data_root)
    for event in (start, end):
        check_valid(event)
    assert (start["eventType"], end["eventType"]) == ("START", "FAIL")
    assert end["run"]["runId"] == start["run"]["runId"]
    assert end["run"]["facets"]["errorMessage"]["message"] == "RuntimeError: disk on fire"
    assert end["outputs"] == [] and end["inputs"] == []


def test_emission_can_be_turned_off_and_never_fails_a_run(data_root, monkeypatch):
    monkeypatch.setenv("OPENLINEAGE_DISABLED", "true")
    with recorded_run("probe", Settings()):
        pass
    assert not (data_root / openlineage.EVENTS_FILE).exists()
    monkeypatch.delenv("OPENLINEAGE_DISABLED")

    class Broken:
        def emit(self, event):
            raise ConnectionError("collector down")

    monkeypatch.setattr(openlineage, "client", lambda root: Broken())
    with recorded_run("probe", Settings()) as run:
        run_id = run.run_id
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        assert wh.query("SELECT status FROM runs WHERE run_id = $r", {"r": run_id})[1] == [("completed",)]

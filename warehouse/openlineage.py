"""OpenLineage run events for flow runs, built from the run's lineage rows.

Each recorded flow run emits a START event when it begins and a COMPLETE or FAIL event when it
ends (a run that ends ``partial``, some inputs quarantined, is COMPLETE with the message in a
facet). The job is ``worldline.<flow>`` in namespace ``worldline``; the run id is the run row's
id (the Prefect flow run id when there is one). The end event lists as outputs every artifact
the run's stage runs wrote, and as inputs every parent of those outputs (lineage edges) that
the run did not write itself. A dataset is named by its file: namespace ``file``, name the
absolute path under the data root (an artifact with no file, a judged but rejected clip, is
left out), with the standard ``version`` facet holding its sha256 and a ``worldline`` facet
with the artifact id, kind, sha256 and manifest hash; the run carries a ``worldline`` facet
with the flow, the manifest hash and the final status.

Transport: when ``OPENLINEAGE_URL`` or ``OPENLINEAGE_CONFIG`` or any ``OPENLINEAGE__...``
variable is set, the client's own configuration from the environment (HTTP to a Marquez, say);
otherwise a file, ``<data_root>/openlineage/events.jsonl``, one event per line, appended.
``OPENLINEAGE_DISABLED=true`` turns emission off. An event that cannot be sent is logged and
never fails the run.
"""

from __future__ import annotations

import logging
import os
from datetime import datetime, timezone
from pathlib import Path

import attr
from openlineage.client import OpenLineageClient
from openlineage.client.event_v2 import InputDataset, Job, OutputDataset, Run, RunEvent, RunState
from openlineage.client.facet_v2 import DatasetFacet, RunFacet, dataset_version_dataset, error_message_run
from openlineage.client.transport.file import FileConfig, FileTransport

from warehouse.store import Warehouse

NAMESPACE = "worldline"
EVENTS_FILE = "openlineage/events.jsonl"
PRODUCER = "https://github.com/worldline/worldline"
FACET_SCHEMA = "https://github.com/worldline/worldline/blob/main/docs/lineage.md#openlineage"
log = logging.getLogger("worldline.openlineage")


@attr.define
class WorldlineRunFacet(RunFacet):
    flow: str
    manifestHash: str | None = attr.field(default=None)  # noqa: N815
    status: str | None = attr.field(default=None)

    @staticmethod
    def _get_schema() -> str:
        return FACET_SCHEMA


@attr.define
class WorldlineDatasetFacet(DatasetFacet):
    artifactId: str  # noqa: N815
    kind: str
    sha256: str | None = attr.field(default=None)
    manifestHash: str | None = attr.field(default=None)  # noqa: N815

    @staticmethod
    def _get_schema() -> str:
        return FACET_SCHEMA


def _configured_elsewhere() -> bool:
    return any(k == "OPENLINEAGE_URL" or k == "OPENLINEAGE_CONFIG" or k.startswith("OPENLINEAGE__")
               for k in os.environ)


def client(data_root: Path | str) -> OpenLineageClient | None:
    """The client runs emit through, or None when ``OPENLINEAGE_DISABLED`` is true."""
    if os.environ.get("OPENLINEAGE_DISABLED", "").lower() in ("1", "true", "yes"):
        return None
    if _configured_elsewhere():
        return OpenLineageClient()
    path = Path(data_root) / EVENTS_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    return OpenLineageClient(transport=FileTransport(FileConfig(log_file_path=str(path), append=True)))


def run_datasets(warehouse: Warehouse, run_id: str) -> tuple[list[tuple], list[tuple]]:
    """(inputs, outputs) of a run as (artifact id, kind, uri, sha256, manifest hash) rows."""
    written = ("SELECT a.artifact_id FROM artifacts a JOIN stage_runs s ON a.stage_run_id = s.stage_run_id "
               "WHERE s.run_id = $run")
    columns = "a.artifact_id, a.kind, a.uri, a.sha256, a.manifest_hash"
    _, outputs = warehouse.query(f"SELECT {columns} FROM artifacts a WHERE a.artifact_id IN ({written}) "
                                 "AND a.uri IS NOT NULL ORDER BY a.artifact_id", {"run": run_id})
    _, inputs = warehouse.query(
        f"SELECT DISTINCT {columns} FROM edges e JOIN artifacts a ON a.artifact_id = e.parent_id "
        f"WHERE e.child_id IN ({written}) AND e.parent_id NOT IN ({written}) AND a.uri IS NOT NULL "
        "ORDER BY a.artifact_id", {"run": run_id})
    return inputs, outputs


def _dataset(cls, row: tuple, data_root: Path):
    artifact_id, kind, uri, sha256, manifest_hash = row
    path = Path(uri.removeprefix("file://"))
    name = str(path if path.is_absolute() else (data_root / path).resolve())
    facets: dict = {"worldline": WorldlineDatasetFacet(artifactId=artifact_id, kind=kind, sha256=sha256,
                                                       manifestHash=manifest_hash, producer=PRODUCER)}
    if sha256:
        facets["version"] = dataset_version_dataset.DatasetVersionDatasetFacet(datasetVersion=sha256,
                                                                               producer=PRODUCER)
    return cls(namespace="file", name=name, facets=facets)


def event(state: RunState, run_id: str, flow: str, data_root: Path | str, manifest_hash: str | None = None,
          status: str | None = None, message: str | None = None,
          inputs: list[tuple] = (), outputs: list[tuple] = ()) -> RunEvent:
    """One run event; ``inputs``/``outputs`` rows as ``run_datasets`` returns them."""
    root = Path(data_root).resolve()
    facets: dict = {"worldline": WorldlineRunFacet(flow=flow, manifestHash=manifest_hash, status=status,
                                                   producer=PRODUCER)}
    if message:
        facets["errorMessage"] = error_message_run.ErrorMessageRunFacet(message=message, programmingLanguage="python",
                                                                        producer=PRODUCER)
    return RunEvent(eventType=state, eventTime=datetime.now(timezone.utc).isoformat(), producer=PRODUCER,
                    run=Run(runId=run_id, facets=facets), job=Job(namespace=NAMESPACE, name=f"worldline.{flow}"),
                    inputs=[_dataset(InputDataset, r, root) for r in inputs],
                    outputs=[_dataset(OutputDataset, r, root) for r in outputs])


def emit(sender: OpenLineageClient | None, build) -> None:
    """Send ``build()``'s event; a failure to build or send it is logged, never raised."""
    if sender is None:
        return
    try:
        sender.emit(build())
    except Exception as exc:  # lineage export must never fail the run it describes
        log.warning("OpenLineage: event not sent: %s: %s", type(exc).__name__, exc)


def end_state(status: str) -> RunState:
    return RunState.FAIL if status == "failed" else RunState.COMPLETE

"""What a finished flow run tells the world beside its lineage rows: the OpenLineage end event
(warehouse/openlineage.py) and the report page published as Prefect artifacts (flows/report.py).
Neither can fail the run: a failure is logged as a warning."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from warehouse import openlineage
from warehouse.store import Warehouse

if TYPE_CHECKING:
    from flows.recording import RunContext

log = logging.getLogger("worldline")


def finished(sender, warehouse: Warehouse, ctx: RunContext, status: str, message: str | None) -> None:
    """The run's OpenLineage COMPLETE or FAIL event, then its report page."""
    def build():
        inputs, outputs = openlineage.run_datasets(warehouse, ctx.run_id)
        return openlineage.event(openlineage.end_state(status), ctx.run_id, ctx.flow, ctx.settings.data_root,
                                 ctx.manifest_hash, status, message, inputs, outputs)
    openlineage.emit(sender, build)
    page(warehouse, ctx)


def page(warehouse: Warehouse, ctx: RunContext) -> None:
    """The run's report page (``report_pages`` setting; inside a Prefect flow run only)."""
    from flows.recording import current_flow_run_id

    if not ctx.settings.report_pages or current_flow_run_id() is None:
        return
    try:
        from flows.report import publish_page

        publish_page(warehouse, ctx.run_id, ctx.flow, ctx.settings.data_root)
    except Exception as exc:  # a page must never fail the run it describes
        log.warning("report page of run %s not written: %s: %s", ctx.run_id, type(exc).__name__, exc)

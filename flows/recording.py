"""How a flow records itself: one run row, manifest rows, and batched lineage writes.

The flow process is the only writer (DuckDB locks the file per process); tasks return
`LineageBatch`es and the flow hands them to `RunContext.write`. A stage over one input goes
through `RunContext.stage`: whether a finished run covered it already, its timing, its
stage-run record and the lineage write that finishes it. A run holds the data root's
writer lock (warehouse/lock.py; the command that started it usually holds it already), and an
interrupted run is closed as failed with the signal named.
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from flows import announce, ephemeral
from schemas.hashing import stable_id
from schemas.manifest import ScenarioManifest
from schemas.records import LineageBatch, RunRecord, StageRunRecord
from schemas.settings import Settings
from tasks import faults, manifests
from warehouse import lock, openlineage
from warehouse.store import Warehouse

_LIVE: set[str] = set()  # runs this process has started and not finished


def current_flow_run_id() -> str | None:
    from prefect.runtime import flow_run

    return flow_run.id


@dataclass
class RunContext:
    run_id: str
    flow: str
    warehouse: Warehouse
    manifest_hash: str | None
    settings: Settings
    status: str = "completed"
    message: str | None = None
    written: int = 0
    failures: list[str] = field(default_factory=list)

    def stage_run_id(self, stage: str, input_key: str) -> str:
        return stable_id("stage_run", stage, input_key)

    def pending(self, stage: str, input_keys: list[str]) -> list[str]:
        """Input keys this stage has not finished yet (a completed stage run is the marker)."""
        done = self.warehouse.completed_stage_runs(stage, input_keys)
        return [k for k in input_keys if k not in done]

    def stage(self, name: str, key: str, outputs: Iterable[Path] = (), manifest_hash: Any = ...,
              started: float | None = None) -> Stage:
        """Stage ``name`` over input ``key``, timed from now (or ``started``). ``manifest_hash``
        defaults to the run's. Lineage is asked whether it is done only when `Stage.done` is read."""
        return Stage(self, name, key, self.manifest_hash if manifest_hash is ... else manifest_hash,
                     time.perf_counter() if started is None else started, tuple(outputs))

    def stages(self, name: str, keys: Iterable[str], manifest_hash: Any = ...) -> dict[str, Stage]:
        """`stage` for many inputs of one stage, whether each is done looked up in lineage at once."""
        keys = list(keys)
        todo = set(self.pending(name, keys))
        out = {k: self.stage(name, k, manifest_hash=manifest_hash) for k in keys}
        for key, stage in out.items():
            stage._done = key not in todo
        return out

    def write(self, batch: LineageBatch) -> None:
        if len(batch):
            self.written += self.warehouse.write(batch)

    def fail_input(self, what: str) -> None:
        self.failures.append(what)
        self.status = "partial"


@dataclass
class Stage:
    """One stage over one input (`RunContext.stage`); `finish` records it with its lineage."""

    run: RunContext
    name: str
    key: str
    manifest_hash: str | None
    started: float  # time.perf_counter() when the stage started (`restart` moves it)
    outputs: tuple[Path, ...] = ()
    _done: bool | None = None

    @property
    def done(self) -> bool:
        """A finished run covered this input and every one of its ``outputs`` is still there: skip it."""
        if self._done is None:
            self._done = not self.run.pending(self.name, [self.key]) and all(Path(p).exists() for p in self.outputs)
        return self._done

    def restart(self) -> Stage:
        """Time the stage from now (when its work starts later than it was looked up)."""
        self.started = time.perf_counter()
        return self

    @property
    def id(self) -> str:
        """The stage run's id: its lineage rows point at it before the record is written."""
        return self.run.stage_run_id(self.name, self.key)

    def record(self, n_in: int, n_out: int, attrs: dict[str, Any] | None = None,
               status: str = "completed") -> StageRunRecord:
        return StageRunRecord(stage_run_id=self.id, run_id=self.run.run_id, stage=self.name, input_key=self.key,
                              manifest_hash=self.manifest_hash, status=status, n_in=n_in, n_out=n_out,
                              seconds=round(time.perf_counter() - self.started, 3), attrs=attrs or {})

    def finish(self, n_in: int, n_out: int, batch: LineageBatch | None = None, attrs: dict[str, Any] | None = None,
               status: str = "completed") -> StageRunRecord:
        """The stage-run record (the marker a re-run skips on) written with ``batch`` in one write."""
        record = self.record(n_in, n_out, attrs, status)
        self.run.write(LineageBatch(stage_runs=[record]).extend(batch or LineageBatch()))
        return record


@contextmanager
def recorded_run(flow: str, settings: Settings, manifest: ScenarioManifest | None = None,
                 source_uri: str | None = None, params: dict[str, Any] | None = None) -> Iterator[RunContext]:
    with lock.writer(settings.data_root, settings.lock_timeout):
        with _recorded(flow, settings, manifest, source_uri, params) as ctx:
            yield ctx


def failure_message(exc: BaseException) -> str:
    """The run row's message for a run that raised ``exc``."""
    from flows.ephemeral import signal_name

    name = signal_name(exc)
    return f"interrupted by {name}" if name else f"{type(exc).__name__}: {exc}"[:2000]


@contextmanager
def _recorded(flow: str, settings: Settings, manifest: ScenarioManifest | None, source_uri: str | None,
              params: dict[str, Any] | None) -> Iterator[RunContext]:
    prefect_id = current_flow_run_id()
    run_id = prefect_id or str(uuid.uuid4())
    digest = manifest.sha256 if manifest is not None else None
    warehouse = Warehouse(settings.warehouse_path, lock_timeout=settings.lock_timeout)
    warehouse.before_commit = lambda: faults.point("lineage")
    _LIVE.add(run_id)
    try:
        if manifest is not None:
            warehouse.write(manifests.lineage(manifest, source_uri))
        warehouse.start_run(RunRecord(run_id=run_id, flow=flow, manifest_hash=digest,
                                      prefect_flow_run_id=prefect_id, params=params or {}))
        warehouse.close_interrupted_runs(_LIVE)  # rows left 'running' by a killed process
        lineage_events = openlineage.client(settings.data_root)
        openlineage.emit(lineage_events, lambda: openlineage.event(
            openlineage.RunState.START, run_id, flow, settings.data_root, digest))
        ctx = RunContext(run_id=run_id, flow=flow, warehouse=warehouse, manifest_hash=digest, settings=settings)
        warehouse.prepare_forced_finish()
        ephemeral.before_forced_exit.append(on_forced_exit := lambda: _close_on_forced_exit(warehouse, run_id))
        try:
            yield ctx
        except BaseException as exc:
            warehouse.finish_run(run_id, "failed", failure_message(exc))
            announce.finished(lineage_events, warehouse, ctx, "failed", failure_message(exc))
            raise
        message = ctx.message
        if ctx.failures and not message:
            message = f"{len(ctx.failures)} input(s) failed: " + "; ".join(ctx.failures)[:1800]
        warehouse.finish_run(run_id, ctx.status, message)
        announce.finished(lineage_events, warehouse, ctx, ctx.status, message)
    finally:
        if "on_forced_exit" in locals():
            ephemeral.before_forced_exit.remove(on_forced_exit)
        _LIVE.discard(run_id)
        warehouse.close()


def _close_on_forced_exit(warehouse: Warehouse, run_id: str) -> None:
    """The run row closed as interrupted when the command is forced out before the flow's thread
    got there. Not through the warehouse's lock: a thread the signal interrupted may hold it (a
    suite run found the row still 'running' when this waited for it)."""
    if run_id in _LIVE:
        warehouse.finish_run_forced(run_id, f"interrupted by {ephemeral.signal_name() or 'a signal'}")

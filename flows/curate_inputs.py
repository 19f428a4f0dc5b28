"""The curate flow's handling of its inputs, one at a time: an input quarantined with its
reason, an analysis that comes back (or why the input is quarantined instead), and a source
that changed on disk after it was hashed. A batch never dies on one input; the machine's
faults (a full disk, a data root that cannot be written) stop the run and blame no input."""

from __future__ import annotations

from pathlib import Path

from prefect import get_run_logger

from flows.recording import RunContext
from schemas import paths
from schemas.errors import EnvironmentFault
from schemas.hashing import stable_id
from tasks import faults
from tasks.curate import analyse, lineage
from tasks.curate.decode import DecodeError
from tasks.curate.inputs import Input, changed, damage, decode_reason


def quarantine(run: RunContext, item: Input, stage: str, reason: str, detail: str) -> None:
    source, detail = paths.escaped(item.path), paths.escaped(detail)
    failed = run.stage(stage, stable_id("quarantine", source, item.sha256 or ""))
    failed.finish(1, 0, lineage.quarantined(source, item.sha256, stage, reason, detail, run.manifest_hash, failed.id),
                  attrs=paths.escaped({"source": source, "reason": reason}), status="failed")
    run.fail_input(f"{source}: {detail}")
    get_run_logger().warning(f"quarantined {source}: {detail}")  # shown without -v too


def analysed(run: RunContext, item: Input, future) -> analyse.VideoAnalysis | None:
    """The analysis of one input, or None when the input is quarantined instead (it did not
    decode, it is damaged, or it changed on disk while it was analysed)."""
    try:
        result = future.result()
    except EnvironmentFault:
        raise  # the machine's fault (a full disk): the run stops, the input is not blamed
    except DecodeError as exc:
        quarantine(run, item, "decode", decode_reason(str(exc)), str(exc))
        return None
    except Exception as exc:  # a batch never dies on one video
        if (fault := faults.machine(exc, item.path, "analysing", run.settings.data_root)) is not None:
            raise fault from exc
        quarantine(run, item, "analyse", type(exc).__name__, f"{item.path}: {exc}")
        return None
    if (damaged := damage(result.decode)) is not None:
        quarantine(run, item, "decode", damaged[0], f"{item.path}: {damaged[1]}")
        return None
    if (moved := changed(item)) is not None:
        quarantine(run, item, "analyse", moved[0], f"{item.path}: {moved[1]}")
        return None
    return result


def source_changed(run: RunContext, item: Input | None, targets: list[Path] | None = None) -> bool:
    """Whether ``item``'s file changed since it was hashed: then it fails as an input, and the
    clips just encoded from it (``targets``, when given) are removed, since their frames may
    not be the bytes lineage records them under."""
    moved = changed(item) if item is not None else None
    if moved is None:
        return False
    for target in targets or []:
        target.unlink(missing_ok=True)
    run.fail_input(paths.escaped(f"{item.path}: {moved[1]}"))
    get_run_logger().warning(paths.escaped(f"{item.path}: {moved[1]}"))
    return True

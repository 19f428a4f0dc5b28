"""What users see of a flow run: a markdown summary artifact and live progress.

Progress is a Prefect progress artifact (the UI shows it on the flow run) and, when the flow
runs from a terminal, a rich progress bar on the command's stderr console (flows/console.py),
the one Prefect's log lines print through, so they print above the bar instead of tearing it.
"""

from __future__ import annotations

import json
import os
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Iterator

from prefect.artifacts import (create_image_artifact, create_link_artifact, create_markdown_artifact,
                               create_progress_artifact, update_progress_artifact)

from flows import console
from tasks import progress as ticks
from tasks.tables import markdown_table  # noqa: F401  (the flows' reports build tables with it)


def publish(flow: str, title: str, body: str, description: str) -> str:
    """One markdown artifact per flow run, keyed `<flow>-summary` so the UI keeps its history."""
    text = f"## {flow}: {title}\n\n{body}"
    create_markdown_artifact(markdown=text, key=f"{flow}-summary", description=description)
    return text


def publish_page(warehouse, run_id: str, flow: str, data_root: Path) -> Path:
    """The run's HTML report page (tasks/report) written under ``<data_root>/reports/`` and
    published as a Prefect link artifact, its pictures as image artifacts."""
    from tasks.report import default_path, write_report

    page = default_path(data_root, run_id)
    images = page.with_suffix("")
    write_report(warehouse, run_id, page, data_root=data_root, images_dir=images)
    create_link_artifact(link=page.resolve().as_uri(), link_text=f"{flow} run {run_id[:12]}: report page",
                         key=f"{flow}-report", description="the run's tables, plots, contact sheets and lineage")
    for png in sorted(images.glob("*.png")):
        create_image_artifact(image_url=png.resolve().as_uri(), key=f"{flow}-{png.stem}"[:100],
                              description=f"{flow}: {png.stem}")
    return page


class Progress:
    def __init__(self, total: int, description: str, bar=None, task_id=None, artifact: bool = True):
        self.total, self.done, self.description = max(total, 0), 0, description
        self._bar, self._task = bar, task_id
        self._artifact = create_progress_artifact(0.0, description=description) if total and artifact else None

    def advance(self, n: int = 1) -> None:
        self.done = min(self.total, self.done + n)
        if self._artifact is not None:
            update_progress_artifact(self._artifact, 100.0 * self.done / self.total,
                                     description=f"{self.description}: {self.done} of {self.total}")
        if self._bar is not None:
            self._bar.update(self._task, completed=self.done)


@contextmanager
def progress(total: int, description: str, parts: dict[str, tuple[str, int]] | None = None,
             topic: str | None = None) -> Iterator[Progress]:
    """Progress over `total` units; a terminal bar only when stderr is a terminal (not in logs or
    CI). ``parts``: {topic: (description, total)}, a bar each below it, moved by what tasks
    report on that topic (tasks/progress.py) while they run, in this process; ``topic`` moves
    the bar itself that way, and then it is the terminal's only (no Prefect artifact)."""
    if not console.err.is_terminal or not total:
        yield Progress(total, description, artifact=topic is None)
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress as Bar, TextColumn, TimeRemainingColumn

    with Bar(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
             console=console.err, transient=True) as bar, ExitStack() as stack:
        main = bar.add_task(description, total=total)
        bars = {**({topic: main} if topic else {}),
                **{key: bar.add_task(text, total=units) for key, (text, units) in (parts or {}).items()}}
        for key, task in bars.items():
            stack.enter_context(ticks.listening(key, lambda task=task, **said: bar.update(task, **said)))
        yield Progress(total, description, bar, main, artifact=topic is None)


def write_json(path: Path, body: dict) -> None:
    """Write ``body`` as sorted JSON, atomically (a temporary beside it, then a rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(body, indent=1, sort_keys=True))
    os.replace(tmp, path)

"""One self-contained HTML page about a run or an artifact (issue 30 point 6).

``write_report(warehouse, id_or_prefix, out_path)`` resolves a run id or an artifact id (or a
prefix of exactly one), and writes one HTML file: no scripts, no external style sheets, every
picture embedded as a base64 PNG data URI, so the file can be mailed, attached to a Prefect
run or opened from disk.

A run's page: the run's row, its stage runs, what it produced per kind, its rejections and
metrics (tables and matplotlib plots), contact sheets of the videos it wrote, the PNGs it
wrote, the lineage of its outputs as a graph, and links to its files. An artifact's page: its
row, metrics and rejections, the run that produced it (row and stage runs), its contact sheet
when it is a video, its ancestors and descendants as a graph and as tables, and links.
An unknown id is refused (InvalidInput, exit 2) with the closest ids that do exist.
"""

from __future__ import annotations

import base64
import html
import json
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path

from schemas.errors import InvalidInput
from tasks.report import figures
from warehouse import report_queries as rq
from warehouse.store import Warehouse

FILES_SHOWN = 200  # rows of a run's file table
GRAPH_SUBJECTS = 12  # a run's outputs drawn in its lineage graph
GRAPH_RELATIVES = 40  # ancestors (and descendants) drawn
SHEET_VIDEOS = 8  # videos in a contact sheet
SHEET_COLUMNS = 6  # frames per video
IMAGES_SHOWN = 8  # PNG files a run wrote, embedded
METRIC_VALUES = 20_000  # values of one metric name plotted
IMAGE_MAX_BYTES = 4 * 1024 * 1024
VIDEO_KINDS = ("clip", "episode_video")
CLOSEST = 5


PAGE_START = "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
GENERATOR = "worldline report"


class UnknownId(InvalidInput):
    """No run or artifact has this id, or several start with it; the message lists the
    closest ids (``matches``)."""

    def __init__(self, message: str, matches: Sequence[str] = ()):
        super().__init__(message)
        self.matches = list(matches)


@dataclass(frozen=True)
class Subject:
    what: str  # "run" or "artifact"
    id: str


@dataclass
class Report:
    """The page and the pictures in it (name -> PNG bytes), for callers that publish them too."""

    subject: Subject
    title: str
    html: str
    images: dict[str, bytes] = field(default_factory=dict)


# -- which run or artifact --------------------------------------------------------------------
def resolve(warehouse: Warehouse, given: str) -> Subject:
    """The run or artifact ``given`` names: its whole id, or a prefix of exactly one id."""
    given = given.strip()
    if not given:
        raise UnknownId("report: give a run id or an artifact id (or the start of one)")
    runs, artifacts = rq.runs_starting(warehouse, given), rq.artifacts_starting(warehouse, given)
    if given in runs:
        return Subject("run", given)
    if given in artifacts:
        return Subject("artifact", given)
    found = [Subject("run", r) for r in runs] + [Subject("artifact", a) for a in artifacts]
    if len(found) == 1:
        return found[0]
    if found:
        more = rq.runs_starting(warehouse, given, CLOSEST) + rq.artifacts_starting(warehouse, given, CLOSEST)
        raise UnknownId(f"report: {given!r} is the start of more than one id ({', '.join(more[:CLOSEST])}, ...); "
                        "give more characters", more)
    close = rq.closest_ids(warehouse, given, CLOSEST)
    if not close:
        raise UnknownId(f"report: no run or artifact has id {given!r}, and none is close")
    listed = "; ".join(f"{identifier} ({what})" for identifier, what in close)
    raise UnknownId(f"report: no run or artifact has id {given!r}; closest: {listed}", [i for i, _ in close])


# -- HTML pieces ------------------------------------------------------------------------------
STYLE = """
body { font: 14px/1.45 system-ui, -apple-system, "Segoe UI", sans-serif; margin: 24px auto; max-width: 1240px;
       color: #1d1d1f; padding: 0 16px; }
h1 { font-size: 22px; margin-bottom: 4px; } h2 { font-size: 17px; margin-top: 28px; border-bottom: 1px solid #ddd; }
.sub { color: #666; margin-top: 0; } code, td.id { font-family: ui-monospace, Menlo, Consolas, monospace; font-size: 12px; }
table { border-collapse: collapse; margin: 8px 0; font-size: 13px; }
th, td { border: 1px solid #e2e2e2; padding: 3px 8px; text-align: left; vertical-align: top; }
th { background: #f4f4f6; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
td.json { max-width: 520px; word-break: break-all; font-size: 11px; color: #444; }
img { max-width: 100%; height: auto; display: block; margin: 8px 0; border: 1px solid #eee; }
.status { padding: 1px 8px; border-radius: 9px; font-weight: 600; }
.completed { background: #d8f0dd; } .partial { background: #fdf0c8; } .failed { background: #f8d7d7; }
.running { background: #dbe8fb; } .missing { color: #b00020; } .note { color: #666; font-size: 12px; }
figure { margin: 8px 0 16px; } figcaption { color: #555; font-size: 12px; }
"""


def esc(value: object) -> str:
    return html.escape("" if value is None else str(value))


@dataclass(frozen=True)
class Raw:
    """HTML already escaped, put into a table cell as it is (with a CSS class, if any)."""

    html: str
    css: str = ""


def cell(column: str, value: object) -> Raw:
    """How a value of ``column`` is shown: numbers right-aligned, ids monospaced, JSON cut at 600
    characters, times to the second."""
    if isinstance(value, Raw):
        return value
    if value is None:
        return Raw("")
    if isinstance(value, bool):
        return Raw(str(value))
    if isinstance(value, (int, float)):
        return Raw(esc(f"{value:,}" if isinstance(value, int) and column != "step" else f"{value:.6g}"), "num")
    if isinstance(value, datetime):
        return Raw(esc(value.isoformat(sep=" ", timespec="seconds")))
    if isinstance(value, timedelta):
        return Raw(f"{value.total_seconds():.1f} s", "num")
    if column in ("params", "attrs", "scores") or isinstance(value, (dict, list)):
        text = value if isinstance(value, str) else json.dumps(value, sort_keys=True)
        return Raw(esc(text[:600]) + ("…" if len(text) > 600 else ""), "json")
    if column.endswith("_id") or column in ("input_key", "manifest_hash", "sha256", "ancestor", "descendant"):
        return Raw(esc(value), "id")
    return Raw(esc(value))


def table(columns: Sequence[str], rows: Sequence[Sequence[object]], empty: str = "none") -> str:
    """An HTML table of query rows (a Raw value goes in as it is)."""
    if not rows:
        return f'<p class="note">{esc(empty)}</p>'
    head = "".join(f"<th>{esc(c)}</th>" for c in columns)
    body = []
    for row in rows:
        cells = (cell(column, value) for column, value in zip(columns, row))
        body.append("<tr>" + "".join(f'<td class="{c.css}">{c.html}</td>' if c.css else f"<td>{c.html}</td>"
                                     for c in cells) + "</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def record(columns: Sequence[str], row: Sequence[object]) -> str:
    """One row shown as a two-column table (field, value)."""
    return table(["field", "value"], [(c, cell(c, v)) for c, v in zip(columns, row)])


def data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


class Page:
    """Collects the sections of one page and its pictures."""

    def __init__(self, data_root: Path):
        self.data_root = Path(data_root)
        self.parts: list[str] = []
        self.images: dict[str, bytes] = {}

    def add(self, text: str) -> None:
        self.parts.append(text)

    def section(self, title: str, *body: str) -> None:
        self.parts.append(f"<section><h2>{esc(title)}</h2>{''.join(body)}</section>")

    def figure(self, name: str, png: bytes | None, caption: str) -> str:
        """An embedded picture; ``name`` (lowercase letters, digits and dashes, as a Prefect
        artifact key wants them) is its key in ``images``."""
        if not png:
            return ""
        self.images[re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")] = png
        return (f'<figure><img alt="{esc(caption)}" src="{data_uri(png)}"><figcaption>{esc(caption)}'
                "</figcaption></figure>")

    def path(self, uri: str) -> Path:
        try:
            return (self.data_root / uri).resolve()
        except (OSError, RuntimeError):  # a symlink loop (a quarantined input): the path as recorded
            return Path(os.path.abspath(self.data_root / uri))

    def link(self, uri: str | None) -> Raw:
        """A file:// link to a file lineage recorded, marked when it is not on disk."""
        if not uri:
            return Raw('<span class="note">not written</span>')
        path = self.path(uri)
        missing = "" if path.exists() else ' <span class="missing">(missing)</span>'
        return Raw(f'<a href="{esc(path.as_uri())}">{esc(uri)}</a>{missing}')

    def files(self, columns: Sequence[str], rows: Sequence[tuple], uri_column: str = "uri") -> str:
        at = list(columns).index(uri_column)
        shown = [tuple(self.link(v) if i == at else v for i, v in enumerate(row)) for row in rows]
        return table(columns, shown)

    def contact_sheet(self, name: str, videos: Sequence[tuple[str, str, str]], caption: str) -> str:
        """Frames of each (artifact id, kind, uri) video; an unreadable one is named under the sheet."""
        rows, problems = [], []
        for artifact_id, kind, uri in videos[:SHEET_VIDEOS]:
            path = self.path(uri)
            try:
                rows.append((f"{kind} {figures.short(artifact_id)}", figures.sample_frames(path, SHEET_COLUMNS)))
            except Exception as exc:  # a missing or undecodable file is said on the page, not fatal
                problems.append(f"{uri}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}")
        body = self.figure(name, figures.contact_sheet(rows, SHEET_COLUMNS), caption)
        if problems:
            body += '<p class="note">not shown: ' + "; ".join(esc(p) for p in problems) + "</p>"
        return body

    def embedded_images(self, images: Sequence[tuple[str, str, str]]) -> str:
        out = []
        for artifact_id, kind, uri in images[:IMAGES_SHOWN]:
            path = self.path(uri)
            if path.is_file() and path.stat().st_size <= IMAGE_MAX_BYTES:
                out.append(self.figure(f"{kind}-{figures.short(artifact_id)}", path.read_bytes(), f"{kind}: {uri}"))
        return "".join(out)

    def html(self, title: str, subtitle: str) -> str:
        return (f"{PAGE_START}<meta name=\"generator\" content=\"{GENERATOR}\">"
                "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
                f"<title>{esc(title)}</title><style>{STYLE}</style></head><body>"
                f"<h1>{esc(title)}</h1><p class=\"sub\">{subtitle}</p>{''.join(self.parts)}</body></html>\n")


# -- sections ---------------------------------------------------------------------------------
def _numbers(page: Page, warehouse: Warehouse, run_id: str) -> None:
    cols, rows = rq.stage_runs_table(warehouse, run_id)
    page.section("Stage runs", table(cols, rows, empty="no stage runs recorded"),
                 page.figure("stages", figures.stage_plot(rq.stage_totals(warehouse, run_id)),
                             "seconds, inputs and outputs per stage"))
    cols, rows = rq.run_artifact_counts(warehouse, run_id)
    page.section("Produced", table(cols, rows, empty="nothing recorded as produced by this run"))
    cols, rows = rq.run_rejection_counts(warehouse, run_id)
    page.section("Rejections", table(cols, rows, empty="no rejections"),
                 page.figure("rejections", figures.rejection_plot(rows), "rejections per stage and reason"))
    cols, rows = rq.run_metric_summary(warehouse, run_id)
    page.section("Metrics", table(cols, rows, empty="no metrics"),
                 page.figure("metrics", figures.metric_plot(rq.run_metrics(warehouse, run_id, METRIC_VALUES)),
                             f"metrics: series by step, or spread over subjects (the first {METRIC_VALUES:,} "
                             "values of each)"))


def _lineage(page: Page, warehouse: Warehouse, subjects: Sequence[str], descendants: bool,
             what: str = "") -> tuple[list, list]:
    """The lineage graph of ``subjects``: their ancestors and (for one artifact) descendants.
    Returns the (ancestor rows, descendant rows) shown."""
    ancestors = rq.ancestors(warehouse, subjects, GRAPH_RELATIVES)
    below = rq.descendants(warehouse, subjects[0], GRAPH_RELATIVES) if descendants else []
    known = rq.kinds_of(warehouse, subjects)
    nodes = [figures.Node(s, known.get(s, ("?", None))[0], 0, True) for s in subjects]
    nodes += [figures.Node(a, kind or "?", -depth) for a, depth, kind, _ in ancestors]
    nodes += [figures.Node(d, kind or "?", depth) for d, depth, kind, _ in below]
    edges = rq.edges_among(warehouse, [n.artifact_id for n in nodes])
    n_up = rq.count_ancestors(warehouse, subjects)
    n_down = rq.count_descendants(warehouse, subjects[0]) if descendants else 0
    note = what + f"{len(ancestors)} of {n_up} ancestors" + (f", {len(below)} of {n_down} descendants" if descendants else "")
    page.section("Lineage", page.figure("lineage", figures.lineage_graph(nodes, edges, note),
                                        f"lineage: {note}; arrows point from parent to child"))
    return ancestors, below


def _run_page(page: Page, warehouse: Warehouse, run_id: str) -> tuple[str, str]:
    cols, rows = rq.run_table(warehouse, run_id)
    row = dict(zip(cols, rows[0]))
    page.section("Run", record(cols, rows[0]))
    _numbers(page, warehouse, run_id)
    videos = rq.run_videos(warehouse, run_id, VIDEO_KINDS, SHEET_VIDEOS) or \
        rq.run_videos(warehouse, run_id, ("raw_video",), SHEET_VIDEOS)
    if videos:
        page.section("Contact sheet", page.contact_sheet(
            "contact-sheet", videos, f"{SHEET_COLUMNS} frames spread over each of the first {len(videos)} videos"))
    images = page.embedded_images(rq.run_images(warehouse, run_id, IMAGES_SHOWN))
    if images:
        page.section("Images the run wrote", images)
    fcols, files = rq.run_artifacts_table(warehouse, run_id, FILES_SHOWN)
    total = sum(r[1] for r in rq.run_artifact_counts(warehouse, run_id)[1])
    if files:
        subjects = [a for _, a, *_ in files[:GRAPH_SUBJECTS]]
        _lineage(page, warehouse, subjects, descendants=False,
                 what=f"{len(subjects)} of the run's {total} outputs (yellow), ")
    page.section("Files", page.files(fcols, files),
                 f'<p class="note">{len(files)} of {total} artifacts</p>' if total > len(files) else "")
    status = esc(row["status"])
    return (f"Run {run_id}", f'{esc(row["flow"])} run, <span class="status {status}">{status}</span>')


def _artifact_page(page: Page, warehouse: Warehouse, artifact_id: str) -> tuple[str, str]:
    cols, rows = rq.artifact_table(warehouse, artifact_id)
    row = dict(zip(cols, rows[0]))
    page.section("Artifact", record(cols, [page.link(v) if c == "uri" else v for c, v in zip(cols, rows[0])]))
    mcols, mrows = rq.artifact_metrics(warehouse, artifact_id)
    jcols, jrows = rq.artifact_rejections(warehouse, artifact_id)
    page.section("Metrics and rejections", table(mcols, mrows, empty="no metrics"),
                 table(jcols, jrows, empty="not rejected"))
    uri = row["uri"] or ""
    if uri.lower().endswith(".mp4"):
        page.section("Contact sheet", page.contact_sheet("contact-sheet", [(artifact_id, row["kind"], uri)],
                                                         f"{SHEET_COLUMNS} frames spread over the video"))
    elif uri.lower().endswith(".png"):
        page.section("Image", page.embedded_images([(artifact_id, row["kind"], uri)]))
    ancestors, below = _lineage(page, warehouse, [artifact_id], descendants=True)
    page.section("Ancestors", page.files(["ancestor", "depth", "kind", "uri"], ancestors))
    page.section("Descendants", page.files(["descendant", "depth", "kind", "uri"], below))
    run_id = row["run_id"]
    if run_id:
        cols, rows = rq.run_table(warehouse, run_id)
        if rows:
            page.section(f"The run that produced it: {run_id}", record(cols, rows[0]))
            cols, rows = rq.stage_runs_table(warehouse, run_id)
            page.section("Its stage runs", table(cols, rows))
    return f"{row['kind']} {artifact_id}", f"artifact, produced by run <code>{esc(run_id or 'none recorded')}</code>"


# -- entry points -----------------------------------------------------------------------------
REPORTS_DIR = "reports"


def default_path(data_root: Path | str, subject_id: str) -> Path:
    """Where a page goes unless told otherwise: ``<data_root>/reports/<id>.html`` (its pictures,
    when written too, in ``<data_root>/reports/<id>/``)."""
    return Path(data_root) / REPORTS_DIR / f"{subject_id}.html"


def build_report(warehouse: Warehouse, given: str, data_root: Path | str | None = None) -> Report:
    """The page of the run or artifact ``given`` names (see module doc), not yet written."""
    subject = resolve(warehouse, given)
    page = Page(Path(data_root) if data_root is not None else Path(getattr(warehouse, "source", warehouse.path)).parent)
    title, subtitle = (_run_page if subject.what == "run" else _artifact_page)(page, warehouse, subject.id)
    return Report(subject, title, page.html(title, subtitle), page.images)


def check_out_path(path: Path) -> None:
    """InvalidInput, in one line, unless ``path`` is new or a report page written before: a
    folder, a device or any other file is not replaced (`--out lineage.duckdb` replaced the
    warehouse with the page)."""
    if not path.exists() and not path.is_symlink():
        return
    if path.is_dir():
        raise InvalidInput(f"--out {path}: a folder; give the page's file path")
    if not path.is_file():
        raise InvalidInput(f"--out {path}: not a regular file; not replaced")
    try:
        with open(path, "rb") as f:
            head = f.read(512).decode("utf-8", errors="replace")
    except OSError as exc:
        raise InvalidInput(f"--out {path}: cannot be read ({exc.strerror}); not replaced") from None
    if not (head.startswith(PAGE_START) and (GENERATOR in head or "<meta name=\"viewport\"" in head[len(PAGE_START):][:80])):
        raise InvalidInput(f"--out {path}: exists and is not a Worldline report page; not replaced (give a new path)")


def write_report(warehouse: Warehouse | Path | str, id_or_prefix: str, out_path: Path | str | None = None,
                 data_root: Path | str | None = None, images_dir: Path | str | None = None) -> Path:
    """Write the page of the run or artifact ``id_or_prefix`` names to ``out_path`` (atomically;
    default ``default_path``); returns the path. ``warehouse``: an open Warehouse or the path of
    one (opened read-only). ``data_root``: what artifact uris are relative to (default: the
    warehouse file's folder). ``images_dir``: also write each picture there as ``<name>.png``
    (for Prefect image artifacts). An unknown id raises UnknownId naming the closest ids."""
    if not isinstance(warehouse, Warehouse):
        with Warehouse(warehouse, read_only=True) as wh:
            return write_report(wh, id_or_prefix, out_path, data_root if data_root is not None else Path(warehouse).parent,
                                images_dir)
    root = Path(data_root) if data_root is not None else Path(getattr(warehouse, "source", warehouse.path)).parent
    if out_path is not None:
        check_out_path(Path(out_path))
    report = build_report(warehouse, id_or_prefix, root)
    out_path = Path(out_path) if out_path is not None else default_path(root, report.subject.id)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_path.with_name(f".{out_path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(report.html, encoding="utf-8")
        os.replace(tmp, out_path)
    except BaseException:
        tmp.unlink(missing_ok=True)  # no half page left beside it
        raise
    if images_dir is not None:
        folder = Path(images_dir)
        folder.mkdir(parents=True, exist_ok=True)
        for name, png in report.images.items():
            (folder / f"{name}.png").write_bytes(png)
    return out_path

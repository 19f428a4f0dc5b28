"""The report page (tasks/report, issue 30 point 6) on a warehouse written by the real writer
(conftest.py): the run's and the artifact's tables, images that decode, a page that needs
nothing outside itself, ids by prefix, and unknown ids answered with the closest ones."""

from __future__ import annotations

import base64
import io
import re

import pytest
from PIL import Image

from schemas.errors import EXIT_INVALID
from tasks.report import UnknownId, build_report, default_path, write_report
from tasks.report.figures import Node, layered
from tasks.report.page import Page
from warehouse.store import Warehouse

DATA_URI = re.compile(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"')


def pictures(html: str) -> list[Image.Image]:
    out = []
    for encoded in DATA_URI.findall(html):
        image = Image.open(io.BytesIO(base64.b64decode(encoded, validate=True)))
        image.load()  # decodes every pixel: a truncated or garbled PNG raises here
        out.append(image)
    return out


def page_of(lineage, given: str, tmp_path) -> str:
    return write_report(lineage.warehouse, given, tmp_path / "page.html").read_text(encoding="utf-8")


def test_run_page_has_the_runs_tables_plots_and_files(lineage, tmp_path):
    html = page_of(lineage, lineage.curate_run, tmp_path)
    assert f"<title>Run {lineage.curate_run}</title>" in html
    for section in ("Run", "Stage runs", "Produced", "Rejections", "Metrics", "Contact sheet", "Lineage", "Files"):
        assert f"<h2>{section}</h2>" in html
    for cell in ("<td>decode</td>", "<td>encode</td>", "<td>shard</td>", "<td>blurry</td>", "<td>blur</td>"):
        assert cell in html
    assert '<td class="num">1.25</td>' in html  # the encode stage's seconds
    for uri in ("clips/clip_a.mp4", "clips/clip_b.mp4", "raw/source.mp4", "shards/part-00000.parquet"):
        assert f'<a href="{(lineage.root / uri).resolve().as_uri()}">{uri}</a>' in html
    assert lineage.rejected in html and "not written" in html  # the rejected clip has no file
    images = pictures(html)
    assert len(images) == 5  # stages, rejections, metrics, contact sheet, lineage
    assert all(i.format == "PNG" and i.width > 100 and i.height > 50 for i in images)


def test_page_is_self_contained(lineage, tmp_path):
    html = page_of(lineage, lineage.curate_run, tmp_path)
    assert "<script" not in html and "<link" not in html and "@import" not in html
    assert all(src.startswith("data:image/png;base64,") for src in re.findall(r'src="([^"]*)"', html))
    assert not re.search(r"url\(", html)
    hrefs = re.findall(r'href="([^"]*)"', html)
    assert hrefs and all(h.startswith("file://") for h in hrefs)  # links to files only


def test_same_lineage_gives_the_same_page(lineage, tmp_path):
    first = write_report(lineage.warehouse, lineage.curate_run, tmp_path / "a.html").read_bytes()
    assert write_report(lineage.warehouse, lineage.curate_run, tmp_path / "b.html").read_bytes() == first


def test_artifact_page_shows_its_lineage_both_ways_and_its_run(lineage, tmp_path):
    html = page_of(lineage, lineage.shard, tmp_path)
    assert f"<title>shard {lineage.shard}</title>" in html
    ancestors = html[html.index("<h2>Ancestors</h2>"):html.index("<h2>Descendants</h2>")]
    descendants = html[html.index("<h2>Descendants</h2>"):]
    for artifact in (*lineage.clips, lineage.raw):
        assert artifact in ancestors
    assert lineage.checkpoint in descendants and lineage.plot in descendants
    assert "(missing)" in descendants  # the checkpoint's file is not on disk
    assert f"The run that produced it: {lineage.curate_run}" in html
    assert "4 of 4 ancestors, 2 of 2 descendants" in html
    assert len(pictures(html)) == 1  # the lineage graph; a shard is no video


def test_a_clip_page_has_its_contact_sheet(lineage, tmp_path):
    with Warehouse(lineage.warehouse, read_only=True) as wh:
        report = build_report(wh, lineage.clips[0])
    assert set(report.images) == {"contact-sheet", "lineage"}
    sheet = Image.open(io.BytesIO(report.images["contact-sheet"]))
    assert sheet.width > 6 * 100  # six frames side by side


def test_a_run_that_wrote_a_png_embeds_it(lineage, tmp_path):
    html = page_of(lineage, lineage.train_run, tmp_path)
    assert "<h2>Images the run wrote</h2>" in html and "report: plots/loss.png" in html
    assert '<span class="status partial">partial</span>' in html and "one input failed" in html
    assert (lineage.root / "plots/loss.png").read_bytes() in [base64.b64decode(s) for s in DATA_URI.findall(html)]
    assert len(pictures(html)) == 4  # stages, the loss series, the embedded PNG, lineage


def test_images_dir_gets_each_picture(lineage, tmp_path):
    write_report(lineage.warehouse, lineage.curate_run, tmp_path / "page.html", images_dir=tmp_path / "img")
    names = sorted(p.name for p in (tmp_path / "img").iterdir())
    assert names == ["contact-sheet.png", "lineage.png", "metrics.png", "rejections.png", "stages.png"]


def test_picture_names_are_prefect_artifact_keys(lineage):
    with Warehouse(lineage.warehouse, read_only=True) as wh:
        names = set(build_report(wh, lineage.train_run).images)
    assert names == {"stages", "metrics", f"report-{lineage.plot[:12]}", "lineage"}
    assert all(re.fullmatch(r"[a-z0-9-]+", name) for name in names)  # what create_image_artifact's key allows


def test_without_out_path_the_page_goes_under_the_data_root(lineage):
    path = write_report(lineage.warehouse, lineage.shard[:10])
    assert path == default_path(lineage.root, lineage.shard) == lineage.root / "reports" / f"{lineage.shard}.html"
    assert f"<title>shard {lineage.shard}</title>" in path.read_text(encoding="utf-8")


def test_a_unique_prefix_names_a_run_or_an_artifact(lineage, tmp_path):
    assert f"<title>shard {lineage.shard}</title>" in page_of(lineage, lineage.shard[:8], tmp_path)
    assert f"<title>Run {lineage.train_run}</title>" in page_of(lineage, "run-t", tmp_path)


def test_a_prefix_of_several_ids_lists_them(lineage, tmp_path):
    with pytest.raises(UnknownId, match="more than one id") as caught:
        write_report(lineage.warehouse, "run-", tmp_path / "page.html")
    assert caught.value.matches == [lineage.curate_run, lineage.train_run]
    assert not (tmp_path / "page.html").exists()


def test_an_unknown_id_lists_the_closest_matches(lineage, tmp_path):
    with pytest.raises(UnknownId) as caught:
        write_report(lineage.warehouse, "run-curate-0002", tmp_path / "page.html")
    assert caught.value.exit_code == EXIT_INVALID
    assert caught.value.matches[0] == lineage.curate_run
    assert str(caught.value).startswith("report: no run or artifact has id 'run-curate-0002'; closest: "
                                        f"{lineage.curate_run} (run curate)")
    typo = lineage.shard[:10] + ("0" if lineage.shard[10] != "0" else "1") + lineage.shard[11:]  # one wrong digit
    with pytest.raises(UnknownId) as caught:
        write_report(lineage.warehouse, typo, tmp_path / "page.html")
    assert caught.value.matches[0] == lineage.shard and "(shard)" in str(caught.value)
    assert not (tmp_path / "page.html").exists()


def test_a_piece_of_an_id_finds_it_and_nothing_alike_says_so(lineage, tmp_path):
    with pytest.raises(UnknownId) as caught:
        write_report(lineage.warehouse, "curate-0001", tmp_path / "page.html")
    assert caught.value.matches[0] == lineage.curate_run
    with pytest.raises(UnknownId, match="no run or artifact has id 'zzzz-yyyy', and none is close") as caught:
        write_report(lineage.warehouse, "zzzz-yyyy", tmp_path / "page.html")
    assert caught.value.matches == []


def test_an_unreadable_video_is_named_not_fatal(lineage, tmp_path):
    (tmp_path / "broken.mp4").write_bytes(b"not a video")
    page = Page(tmp_path)
    body = page.contact_sheet("sheet", [("a" * 24, "clip", "broken.mp4"), ("b" * 24, "clip", "gone.mp4")], "c")
    assert "not shown: broken.mp4: " in body and "gone.mp4: " in body and "sheet" not in page.images


def test_lineage_columns_put_children_right_of_parents():
    nodes = [Node("m", "manifest", -1), Node("r", "raw_video", 0, True), Node("c", "clip", 0, True),
             Node("s", "shard", 0, True), Node("x", "clip", 0, True)]
    edges = [("m", "r", "derived"), ("r", "c", "derived"), ("c", "s", "shard_of"), ("r", "x", "derived")]
    assert layered(nodes, edges) == {"m": 0, "r": 1, "c": 2, "x": 2, "s": 3}


def test_metrics_are_summed_up_whole_and_plotted_from_the_first_values(lineage):
    from warehouse import report_queries as rq

    with Warehouse(lineage.warehouse, read_only=True) as wh:
        _, summary = rq.run_metric_summary(wh, lineage.train_run)
        plotted = rq.run_metrics(wh, lineage.train_run, per_name=4)
    assert summary == [("loss", 10, 0.1, pytest.approx(sum(1 / (s + 1) for s in range(10)) / 10), 1.0)]
    assert [(name, step) for name, step, _, _ in plotted] == [("loss", s) for s in range(4)]

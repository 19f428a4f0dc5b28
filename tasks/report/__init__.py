"""The report page (issue 30 point 6): one self-contained HTML file about a run or an artifact.
``page.py`` resolves the id and lays out the page; ``figures.py`` draws its pictures with
matplotlib; the SQL is in warehouse/report_queries.py."""

from tasks.report.page import Report, UnknownId, build_report, default_path, write_report

__all__ = ["Report", "UnknownId", "build_report", "default_path", "write_report"]

"""What the curate flow reports: clips kept and rejected, by stage and reason."""

from __future__ import annotations

from collections import Counter

from schemas.records import ClipRecord
from tasks.curate.analyse import VideoAnalysis
from tasks.tables import markdown_table


def tally(analyses: list[VideoAnalysis], unique: list[ClipRecord], encoded: list[ClipRecord]) -> Counter:
    """(stage, outcome) -> clips: the encoded ones, each rejection reason, and the duplicates."""
    counts = Counter(("kept", "encoded") for _ in encoded)
    for a in analyses:
        counts.update((c.reject_stage, c.reject_reason) for c in a.clips if not c.kept)
    counts[("dedup", "duplicate")] = len([c for a in analyses for c in a.clips if c.kept]) - len(unique)
    return counts


def table(counts: Counter) -> str:
    return markdown_table(("stage", "outcome", "clips"), [(s, o, n) for (s, o), n in sorted(counts.items())])

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


def smeared(analyses: list[VideoAnalysis]) -> list[str]:
    """One line per source with frames smeared by decoder concealment (``tasks/curate/smear.py``):
    the decoder did not flag them, so the file is named here; the clips holding them are
    rejected as ``quality:smeared``, the rest of the file is curated."""
    lines = []
    for a in analyses:
        if n := a.decode.get("smeared", 0):
            frames = ", ".join(map(str, a.decode.get("smeared_frames", [])))
            lines.append(f"{a.source}: {n} frame(s) smeared by decoder concealment (frames {frames}"
                         f"{', ...' if n > len(a.decode.get('smeared_frames', [])) else ''}); the clips holding "
                         "them are rejected as quality:smeared")
    return lines

"""Is a file still the one lineage recorded? Hash it as lineage did, compare, refuse a mismatch.

Lineage records a file artifact's sha256 over its bytes (a checkpoint's over its
``model.safetensors``, the file its uri names; an episode's over its ``steps.parquet``), so one
streamed hash of the file the uri names is what every check compares. Nothing here reads the
warehouse: a flow looks up what lineage claims about a path (``warehouse.integrity``) and
hands the rows in, so these checks run and test without a database.

Three outcomes for a file a stage is about to read (``match``):
- a lineage row at its uri has its bytes, or (for a copy elsewhere) a row of its kind has: use
  that artifact;
- rows at its uri exist but none has its bytes: ``TamperedArtifact`` (exit 5), naming the
  file, both hashes and the artifact;
- lineage knows neither: None, and the caller decides (a training input is refused, a
  checkpoint brought from elsewhere is an external input).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from schemas.errors import InvalidInput, TamperedArtifact
from schemas.hashing import sha256_file

PROBLEMS = ("missing", "changed", "conflict")  # what `worldline verify` reports, in this order
# ... and, after them, what it lists without failing: an input (a file the user gave, never one
# Worldline wrote) rewritten in place and curated again, whose earlier row is history.
NOTES = ("superseded",)
INPUT_KINDS = frozenset({"raw_video"})


@dataclass(frozen=True)
class Recorded:
    """One artifact row as lineage holds it (``warehouse.integrity`` returns these fields)."""

    artifact_id: str
    kind: str
    uri: str
    sha256: str
    manifest_hash: str | None = None


def file_sha256(path: Path | str) -> str:
    """The sha256 lineage records for a file: of its bytes, streamed (shards can be large)."""
    return sha256_file(str(path))


def uri_of(path: Path, root: Path) -> str:
    """The uri lineage gives a file: relative to the (resolved) data root when under it."""
    path, root = Path(path).resolve(), Path(root).resolve()
    return path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)


def path_of(uri: str, root: Path) -> Path:
    """The file a uri names: absolute as it is; relative under the data root. Curate records
    an input video by the path it was given, which may be relative to the directory it ran in:
    when nothing is under the root there but that path exists, it is the one."""
    if os.path.isabs(uri):
        return Path(uri)
    under = Path(root) / uri
    return under if under.exists() or not Path(uri).exists() else Path(uri)


def tampered(path: Path | str, got: str, row: Recorded) -> TamperedArtifact:
    return TamperedArtifact(f"{path}: sha256 {got[:12]} differs from lineage's {row.sha256[:12]} "
                            f"({row.kind} {row.artifact_id[:12]}); run `worldline verify`")


def check(path: Path | str, row: Recorded, digest: str | None = None) -> str:
    """The file's sha256 when it is ``row``'s bytes (``digest`` when already hashed); else
    TamperedArtifact."""
    got = digest or file_sha256(path)
    if got != row.sha256:
        raise tampered(path, got, row)
    return got


def match(path: Path | str, uri: str, digest: str, kind: str, claims: Sequence[Recorded]) -> Recorded | None:
    """The artifact a file of ``kind`` at ``uri`` with sha256 ``digest`` is, given the lineage
    rows that claim its uri or its bytes (newest first); TamperedArtifact when rows claim the uri
    and none has these bytes; None when lineage knows neither."""
    here = [c for c in claims if c.uri == uri]
    if same := [c for c in here if c.sha256 == digest]:
        return same[0]
    if here:
        raise tampered(path, digest, here[0])
    return next((c for c in claims if c.kind == kind and c.sha256 == digest), None)


def unknown(path: Path | str, digest: str, what: str, hint: str) -> InvalidInput:
    """The one-line refusal of a file lineage has never seen (nothing is registered for it)."""
    return InvalidInput(f"{path}: lineage has no {what} with these bytes (sha256 {digest[:12]}); {hint}")


# -- the audit: every recorded file against the disk --------------------------------------
@dataclass(frozen=True)
class Finding:
    """One artifact whose file differs from lineage: ``problem`` is one of PROBLEMS."""

    problem: str
    kind: str
    artifact_id: str
    uri: str
    lineage_sha256: str
    file_sha256: str | None


def audit(rows: Iterable[Recorded], root: Path) -> tuple[list[Finding], int, int]:
    """(findings, artifacts checked, files hashed) of lineage's file artifacts under ``root``.

    Each file is hashed once however many rows name it. Per file: ``missing`` when it is gone;
    ``conflict`` for every row when rows name it with different sha256s (a file rewritten in
    place, or one path recorded twice: lineage cannot say which bytes its descendants saw);
    ``changed`` when all rows agree and the bytes differ; ``superseded`` (a note, not a problem)
    for the earlier rows of an input video rewritten in place and curated again, whose newest
    bytes one row records.
    """
    by_path: dict[Path, list[Recorded]] = {}
    checked = 0
    for row in rows:
        by_path.setdefault(path_of(row.uri, root), []).append(row)
        checked += 1
    findings, hashed = [], 0
    for path, named in sorted(by_path.items(), key=lambda item: str(item[0])):
        if not path.is_file():
            findings += [Finding("missing", r.kind, r.artifact_id, r.uri, r.sha256, None) for r in named]
            continue
        got = file_sha256(path)
        hashed += 1
        if len({r.sha256 for r in named}) > 1 and got in {r.sha256 for r in named} and all(
                r.kind in INPUT_KINDS for r in named):
            findings += [Finding("superseded", r.kind, r.artifact_id, r.uri, r.sha256, got) for r in named
                         if r.sha256 != got]
        elif len({r.sha256 for r in named}) > 1:
            findings += [Finding("conflict", r.kind, r.artifact_id, r.uri, r.sha256, got) for r in named]
        else:
            findings += [Finding("changed", r.kind, r.artifact_id, r.uri, r.sha256, got) for r in named
                         if r.sha256 != got]
    findings.sort(key=lambda f: ((PROBLEMS + NOTES).index(f.problem), f.uri, f.artifact_id))
    return findings, checked, hashed

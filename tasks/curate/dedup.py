"""Near-duplicate clips: perceptual hashes of sampled frames, grouped so each copy keeps one clip.

In three steps: each clip's signature (``dedup_signature.py``), candidate pairs and the checks
that accept them (``dedup_pairs.py``), and here the groups and the clip records.

Groups are stars around the best copy (resolution, then quality score, then smallest id), so a
chain of near misses cannot merge two unrelated clips, and the result is the same whatever
order the clips arrive in.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

import numpy as np
from pydantic import BaseModel, ConfigDict

from schemas.records import ClipRecord
from tasks.curate.dedup_pairs import candidates, footage_distance, hash_distance, nearest
from tasks.curate.dedup_signature import DEFAULT_CROPS, ClipSignature, Crop, DedupConfig, sample_positions, signature

__all__ = ["DEFAULT_CROPS", "ClipSignature", "Crop", "DedupConfig", "DedupResult", "apply", "group", "quality_key",
           "sample_positions", "signature"]


class DedupResult(BaseModel):
    """groups: kept id -> every member (kept first, then sorted); removed: removed id -> kept id."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    groups: dict[str, tuple[str, ...]]
    kept: tuple[str, ...]
    removed: dict[str, str]
    candidates: int = 0  # pairs proposed by LSH
    hash_pairs: int = 0  # pairs within hash_max
    checked: int = 0  # pairs given the pixel check (max_neighbours per clip)
    verified: int = 0  # pairs that passed the pixel check
    redecoded: int = 0  # clips whose sampled frames were decoded again for the pixel check


def group(
    signatures: Mapping[str, ClipSignature],
    quality: Mapping[str, tuple],
    config: DedupConfig = DedupConfig(),
    exact: Callable[[list[str]], Mapping[str, ClipSignature]] | None = None,
) -> DedupResult:
    """Group duplicate clips and keep the best of each group.

    quality: clip id -> comparable tuple, higher is better (see ``quality_key``); ties go to
    the smallest clip id. Clips without an entry rank lowest. ``exact``, given the ids of
    clips whose signatures are not exact and that reach the pixel check, returns their
    signatures from exactly the sampled frames: two copies of fast motion agree only at the
    same moments, and the analysis pass may have decoded each at different ones.
    """
    ids = sorted(signatures)
    if not ids:
        return DedupResult(groups={}, kept=(), removed={})
    size, offsets = config.thumb_size, 2 * config.time_radius + 1
    want = ((config.frames, len(config.crops)), (config.frames, offsets, size, size))
    for i in ids:
        have = (signatures[i].hashes.shape, signatures[i].thumbs.shape)
        if have != want:
            raise ValueError(f"dedup.group: clip {i}: signature shapes {have} do not fit this config {want}: made with another config?")
    hashes = np.stack([signatures[i].hashes for i in ids])
    pairs = candidates(hashes, config)
    dist, hyp, clear = hash_distance(hashes, pairs)
    close = nearest(pairs, dist, config)
    redecode = sorted({ids[i] for i in np.unique(pairs[close]) if not signatures[ids[i]].exact})
    if exact is not None and redecode:
        signatures = {**signatures, **{k: v for k, v in exact(redecode).items() if k in signatures}}
    neighbours: dict[str, set[str]] = {}
    verified = 0
    for p in close:
        a, b = ids[pairs[p, 0]], ids[pairs[p, 1]]
        if footage_distance(signatures[a], signatures[b], int(hyp[p]), bool(clear[p]), config) <= config.residual_max:
            neighbours.setdefault(a, set()).add(b)
            neighbours.setdefault(b, set()).add(a)
            verified += 1
    # Best first: by id, then (stable sort) by quality descending.
    order = sorted(sorted(ids), key=lambda i: quality.get(i, ()), reverse=True)
    rank = {c: r for r, c in enumerate(order)}
    keeper: dict[str, str] = {}
    for c in order:
        reps = [n for n in neighbours.get(c, ()) if keeper.get(n) == n]
        keeper[c] = min(reps, key=rank.__getitem__) if reps else c
    groups: dict[str, list[str]] = {}
    for c in order:
        groups.setdefault(keeper[c], []).append(c)
    return DedupResult(
        groups={k: (k, *sorted(m for m in v if m != k)) for k, v in sorted(groups.items())},
        kept=tuple(sorted(groups)),
        removed={c: k for c, k in sorted(keeper.items()) if c != k},
        candidates=len(pairs),
        hash_pairs=int((dist <= config.hash_max).sum()),
        checked=len(close),
        verified=verified,
        redecoded=len(redecode) if exact is not None else 0,
    )


def quality_key(clip: ClipRecord, config: DedupConfig = DedupConfig()) -> tuple[int, float]:
    """(pixels, config.quality_score) of a clip, higher is better; a missing score ranks lowest."""
    return clip.width * clip.height, float(clip.scores.get(config.quality_score, float("-inf")))


def apply(clips: Iterable[ClipRecord], signatures: Mapping[str, ClipSignature], result: DedupResult) -> list[ClipRecord]:
    """Clip records with phash set and dedup_group = the kept clip's id.

    Removed copies are marked rejected by stage "dedup" with reason "duplicate" (one reason, so
    counts per reason stay meaningful; the kept copy is their dedup_group).
    """
    out = []
    for clip in clips:
        update: dict = {}
        if clip.clip_id in signatures:
            update["phash"] = signatures[clip.clip_id].phash
        kept = result.removed.get(clip.clip_id)
        if kept is not None:
            update.update(dedup_group=kept, kept=False, reject_stage="dedup", reject_reason="duplicate")
        elif clip.clip_id in result.groups:
            update["dedup_group"] = clip.clip_id
        out.append(clip.model_copy(update=update))
    return out

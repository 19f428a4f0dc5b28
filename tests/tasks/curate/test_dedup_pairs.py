"""Candidate pairs from banded LSH, against a brute-force count, and in crowded buckets."""

from __future__ import annotations

import itertools

import numpy as np

from tasks.curate import dedup_pairs
from tasks.curate.dedup_signature import DedupConfig


def _brute_candidates(hashes: np.ndarray, min_collisions: int) -> set[tuple[int, int]]:
    """Slow reference: count (frame, band) slots where one clip's whole picture matches any crop of the other."""
    n, f, c = hashes.shape
    out = set()
    for i, j in itertools.combinations(range(n), 2):
        hits = 0
        for k in range(f):
            for b in range(dedup_pairs.BANDS):
                band = lambda h: {int(x) >> (b * dedup_pairs.BAND_BITS) & 0xFFFF for x in h}  # noqa: E731
                hits += bool(band(hashes[i, k, :1]) & band(hashes[j, k]) or band(hashes[j, k, :1]) & band(hashes[i, k]))
        if hits >= min_collisions:
            out.add((i, j))
    return out


def test_lsh_candidates_match_a_brute_force_count():
    rng = np.random.default_rng(3)
    n, f, c = 60, 3, 4
    hashes = rng.integers(0, 2**63, size=(n, f, c), dtype=np.uint64)
    for i in range(0, n, 6):  # plant near copies: a few flipped bits, in one crop
        hashes[i + 1, :, 2] = hashes[i, :, 0] ^ np.uint64(1 << int(rng.integers(0, 64)))
        hashes[i + 2] = hashes[i] ^ np.uint64(0b1001)
    got = {tuple(map(int, p)) for p in dedup_pairs.candidates(hashes, DedupConfig(min_collisions=2))}
    assert got == _brute_candidates(hashes, 2)
    assert len(got) >= 2 * n // 6


def test_crowded_buckets_are_split_not_dropped():
    """400 clips of one 'scene': bands 0 and 1 each take one of 4 values (100 clips per bucket,
    crowded past max_bucket=50). Copies that share only those two bands are still proposed, via
    the (band 0, band 1) buckets of about 25 clips, and far from all pairs are."""
    rng = np.random.default_rng(5)
    n, f, c = 400, 3, 4
    hashes = rng.integers(0, 2**63, size=(n, 1, c), dtype=np.uint64).repeat(f, axis=1)
    low = rng.integers(0, 4, n).astype(np.uint64) | (rng.integers(0, 4, n).astype(np.uint64) << np.uint64(16))
    hashes = (hashes & ~np.uint64(0xFFFFFFFF)) | low[:, None, None]
    copies = [(i, i + 1) for i in range(0, 40, 2)]
    for i, j in copies:
        hashes[j] = hashes[i] ^ np.uint64(0x0001_0001_0000_0000)  # differs in bands 2 and 3
    got = {tuple(map(int, p)) for p in dedup_pairs.candidates(hashes, DedupConfig(max_bucket=50))}
    assert set(copies) <= got
    assert len(got) < 0.1 * n * (n - 1) / 2

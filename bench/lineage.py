"""Lineage warehouse at scale: load 1,000,000 artifacts with their edges, then time the audits.

Prints the insert rate and p50/p95 latency of the ancestry audit (per starting kind) and of
the rejections-by-manifest audit. Target (issue 2): ancestry p95 <= 50 ms at 1M artifacts.

    .venv/bin/python bench/lineage.py [--artifacts 1000000] [--queries 200]
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, RejectionRecord  # noqa: E402
from warehouse import audit  # noqa: E402
from warehouse.store import Warehouse  # noqa: E402

BATCH = 50_000


def plan(total: int, manifests: int = 20):
    """manifest -> raw video (1%) -> clip (~97%) -> shard (1 per 100 clips) -> checkpoint (1 per 50 shards)."""
    raws = max(1, total // 100)
    shards = max(1, total // 100)
    checkpoints = max(1, shards // 50)
    clips = total - manifests - raws - shards - checkpoints
    return manifests, raws, clips, shards, checkpoints


def generate(total: int, rnd: random.Random):
    n_man, n_raw, n_clip, n_shard, n_ckpt = plan(total)
    man = [f"{i:064x}" for i in range(n_man)]

    def art(aid, kind, m):
        return ArtifactRecord(artifact_id=aid, kind=kind, uri=f"{kind}/{aid}", sha256="0" * 64, bytes=1000,
                              manifest_hash=m)

    batch = LineageBatch()
    for m in man:
        batch.artifacts.append(art(m, "manifest", m))
    raw_manifest = {}
    for i in range(n_raw):
        m = man[i % n_man]
        raw_manifest[i] = m
        batch.artifacts.append(art(f"raw{i}", "raw_video", m))
        batch.edges.append(EdgeRecord(parent_id=m, child_id=f"raw{i}", relation="generated"))
    yield batch
    batch = LineageBatch()
    for i in range(n_clip):
        r = rnd.randrange(n_raw)
        m = raw_manifest[r]
        cid = f"clip{i}"
        batch.artifacts.append(art(cid, "clip", m))
        batch.edges.append(EdgeRecord(parent_id=f"raw{r}", child_id=cid, relation="split_from"))
        if rnd.random() < 0.3:
            batch.rejections.append(RejectionRecord(artifact_id=cid, stage=rnd.choice(["motion", "quality", "text"]),
                                                    reason=rnd.choice(["static", "blur", "overlay_text"]),
                                                    scores={"s": rnd.random()}, manifest_hash=m))
        else:
            batch.edges.append(EdgeRecord(parent_id=cid, child_id=f"shard{i % n_shard}", relation="shard_of"))
        if len(batch.artifacts) >= BATCH:
            yield batch
            batch = LineageBatch()
    for s in range(n_shard):
        batch.artifacts.append(art(f"shard{s}", "shard", man[s % n_man]))
        batch.edges.append(EdgeRecord(parent_id=f"shard{s}", child_id=f"ckpt{s % n_ckpt}", relation="trained_on"))
    for c in range(n_ckpt):
        batch.artifacts.append(art(f"ckpt{c}", "checkpoint", man[c % n_man]))
    yield batch


def timed(wh: Warehouse, name: str, params: list[dict]) -> list[float]:
    sql = audit.load(name)
    out = []
    for p in params:
        t0 = time.perf_counter()
        wh.query(sql, p)
        out.append((time.perf_counter() - t0) * 1000)
    return out


def pct(values: list[float], q: float) -> float:
    return statistics.quantiles(values, n=100, method="inclusive")[int(q) - 1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--artifacts", type=int, default=1_000_000)
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--db", type=Path, default=None)
    args = ap.parse_args()
    rnd = random.Random(0)
    db = args.db or Path(tempfile.mkdtemp(prefix="wl-bench-")) / "lineage.duckdb"
    n_man, n_raw, n_clip, n_shard, n_ckpt = plan(args.artifacts)
    with Warehouse(db) as wh:
        t0 = time.perf_counter()
        rows = 0
        for batch in generate(args.artifacts, rnd):
            rows += wh.write(batch)
        load_s = time.perf_counter() - t0
        counts = wh.counts()
        print(f"loaded {counts['artifacts']:,} artifacts, {counts['edges']:,} edges, {counts['rejections']:,} "
              f"rejections ({rows:,} rows) in {load_s:.1f} s: {rows / load_s:,.0f} rows/s, "
              f"{counts['artifacts'] / load_s:,.0f} artifacts/s")
        starts = {
            "clip": [{"artifact": f"clip{rnd.randrange(n_clip)}"} for _ in range(args.queries)],
            "shard (~70 clips)": [{"artifact": f"shard{rnd.randrange(n_shard)}"} for _ in range(args.queries)],
        }
        timed(wh, "ancestry", starts["clip"][:5])  # warm-up
        print(f"{'query':40s} {'p50 ms':>8s} {'p95 ms':>8s}")
        worst = 0.0
        for label, params in starts.items():
            ms = timed(wh, "ancestry", params)
            worst = max(worst, pct(ms, 95))
            print(f"{'ancestry from ' + label:40s} {pct(ms, 50):8.1f} {pct(ms, 95):8.1f}")
        ms = timed(wh, "rejections", [{"manifest": f"{rnd.randrange(n_man):064x}"} for _ in range(args.queries)])
        print(f"{'rejections by manifest':40s} {pct(ms, 50):8.1f} {pct(ms, 95):8.1f}")
        ms = timed(wh, "ancestry", [{"artifact": f"ckpt{rnd.randrange(n_ckpt)}"} for _ in range(min(20, args.queries))])
        print(f"{'ancestry from checkpoint (~3,500 nodes)':40s} {pct(ms, 50):8.1f} {pct(ms, 95):8.1f}")
        print(f"target: ancestry p95 <= 50 ms for clips and shards: {'met' if worst <= 50 else 'MISSED'} ({worst:.1f} ms)")


if __name__ == "__main__":
    main()

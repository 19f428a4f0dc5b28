"""What the read snapshot costs the writer (issue 30): bench/lineage.py's generated lineage loaded
three times, with no snapshot, with one published after every batch, and with the default
throttle (snapshot.MIN_INTERVAL_S, COST_FACTOR), then single publishes of the loaded file timed.

    .venv/bin/python bench/snapshot.py [--artifacts 100000] [--batch 5000] [--repeat 20]
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

import bench.lineage as lineage  # noqa: E402
from warehouse import snapshot  # noqa: E402
from warehouse.store import Warehouse  # noqa: E402


def load(db: Path, artifacts: int, publishing: str) -> tuple[float, int, list[float]]:
    """Seconds to load, rows written, and each publish's seconds; ``publishing``: "never",
    "every" batch, or as the "throttle" allows."""
    costs: list[float] = []
    real, throttle = snapshot.publish, (snapshot.MIN_INTERVAL_S, snapshot.COST_FACTOR)

    def timed(con, path, src):
        costs.append(real(con, path, src))
        return costs[-1]

    snapshot.publish = (lambda con, path, src: 0.0) if publishing == "never" else timed
    if publishing == "every":
        snapshot.MIN_INTERVAL_S, snapshot.COST_FACTOR = 0.0, 0.0
    try:
        with Warehouse(db, lock_timeout=0) as wh:
            t0, rows = time.perf_counter(), 0
            for batch in lineage.generate(artifacts, random.Random(0)):
                rows += wh.write(batch)
            return time.perf_counter() - t0, rows, costs
    finally:
        snapshot.publish = real
        snapshot.MIN_INTERVAL_S, snapshot.COST_FACTOR = throttle


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--artifacts", type=int, default=100_000)
    ap.add_argument("--batch", type=int, default=5_000)
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    lineage.BATCH = args.batch
    root = Path(tempfile.mkdtemp(prefix="wl-snapshot-"))
    plain, rows, _ = load(root / "plain" / "lineage.duckdb", args.artifacts, "never")
    throttled, _, few = load(root / "throttled" / "lineage.duckdb", args.artifacts, "throttle")
    db = root / "snap" / "lineage.duckdb"
    with_snap, _, costs = load(db, args.artifacts, "every")
    print(f"load of {args.artifacts:,} artifacts ({rows:,} rows, batches of {args.batch:,}): "
          f"{plain:.2f} s without snapshots, {throttled:.2f} s with the default throttle ({len(few)} publishes), "
          f"{with_snap:.2f} s publishing after each batch ({len(costs)} publishes, "
          f"+{(with_snap - plain) / max(1, len(costs)) * 1000:.0f} ms each)")
    size = db.stat().st_size
    with Warehouse(db, lock_timeout=0) as wh:  # the finished file: a publish that has nothing to checkpoint
        wh.publish_snapshot()  # opens the descriptor publishes copy from
        src = snapshot.publisher(db).fd
        full = [snapshot.publish(wh.con, db, src) * 1000 for _ in range(args.repeat)]
        t = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            snapshot._copy(src, root / "copy.duckdb")
            t.append((time.perf_counter() - t0) * 1000)
    print(f"file {size / 2**20:.1f} MiB: publish (checkpoint, copy, rename) median {statistics.median(full):.1f} ms, "
          f"max {max(full):.1f} ms; the copy alone median {statistics.median(t):.1f} ms; "
          f"publishes during the load median {statistics.median(costs) * 1000:.1f} ms, max {max(costs) * 1000:.1f} ms")


if __name__ == "__main__":
    main()

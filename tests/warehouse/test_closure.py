"""The ancestry closure the writer keeps must equal a walk of the edges, however batches arrive."""

from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch
from warehouse import audit
from warehouse.store import Warehouse


def reference_ancestors(edges: set[tuple[str, str]], start: str) -> dict[str, int]:
    """Breadth-first walk: ancestor -> shortest depth."""
    depth, frontier, seen = 1, {start}, {}
    while frontier:
        parents = {p for p, c in edges if c in frontier} - set(seen) - {start}
        for p in parents:
            seen[p] = depth
        frontier, depth = parents, depth + 1
    return seen


@st.composite
def dags(draw):
    n = draw(st.integers(2, 14))
    pairs = draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)), max_size=40))
    edges = sorted({(f"n{min(a, b)}", f"n{max(a, b)}") for a, b in pairs if a != b})  # parent index < child index
    cuts = draw(st.lists(st.integers(0, len(edges)), max_size=4))
    order = draw(st.permutations(edges))  # batches may arrive in any order
    return n, order, sorted(set(cuts))


@settings(max_examples=25, deadline=None)
@given(dags())
def test_closure_equals_walk(tmp_path_factory, dag):
    n, order, cuts = dag
    path = tmp_path_factory.mktemp("closure") / "w.duckdb"
    with Warehouse(path) as wh:
        wh.write(LineageBatch(artifacts=[ArtifactRecord(artifact_id=f"n{i}", kind="clip", uri=f"u{i}", sha256=None)
                                         for i in range(n)]))
        bounds = [0, *cuts, len(order)]
        for lo, hi in zip(bounds, bounds[1:]):
            wh.write(LineageBatch(edges=[EdgeRecord(parent_id=p, child_id=c) for p, c in order[lo:hi]]))
        sql, _ = audit.bind("ancestry", {"artifact": "x"})
        for i in range(n):
            _, rows = wh.query(sql, {"artifact": f"n{i}"})
            got = {r[2]: r[0] for r in rows if r[0] > 0}
            assert got == reference_ancestors(set(order), f"n{i}")
            assert all(r[1] == "clip" for r in rows)

"""demo: the whole loop on built-in generated data, with the embedded defaults."""

from __future__ import annotations

from pathlib import Path

from prefect import flow

from flows.corpus import corpus
from flows.curate import curate
from flows.register import register
from flows.report import markdown_table, publish
from flows.simulate import simulate
from flows.tokenize import tokenize
from schemas import paths
from schemas.settings import Settings

MANIFESTS = Path(__file__).resolve().parent.parent / "manifests"
# Simulated and then curated: normal light, and dim light (which the quality filter rejects).
DEMO = {"conveyor_push.yaml": 3, "bin_pick_dim_forklift.yaml": 2}


@flow(name="demo", log_prints=True)
def demo() -> list[dict]:
    """Register every manifest, simulate episodes and curate them per manifest, train a tiny
    tokenizer on the push episodes' shards, then generate a labelled minute of raw footage
    (simulator and procedural, with defects) and curate it."""
    for path in sorted(MANIFESTS.glob("*.yaml")):
        register(str(path))
    results = []
    for name, episodes in DEMO.items():
        manifest = str(MANIFESTS / name)
        digest = simulate(manifest, episodes=episodes)["manifest_hash"]
        folder = paths.resolve(Settings().data_root, paths.EPISODES_OF_MANIFEST, manifest_hash=digest)
        results.append(curate([str(folder)], manifest))
    # A tiny tokenizer on the push episodes' shards: the next step of the loop, in seconds.
    pushed = results[0]
    if pushed["shards"]:
        tokenize(pushed["manifest_hash"], preset_name="tiny-dv4x8x8", steps=30, size=64)
    footage = corpus(minutes=1.0, seed=1, width=640, height=360)
    results.append(curate(footage["videos"]))
    publish("demo", f"{len(results)} curate runs", markdown_table(
        ("curate run", "manifest", "status", "inputs", "clips kept", "shards"),
        [(r["run_id"], (r["manifest_hash"] or "")[:12], r["status"], r["inputs"], r["clips"], len(r["shards"]))
         for r in results]), "the demo's curate runs")
    return results

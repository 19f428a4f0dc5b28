"""demo: the whole loop on built-in generated data, with the embedded defaults."""

from __future__ import annotations

from pathlib import Path

from prefect import flow

from flows.corpus import corpus
from flows.curate import curate
from flows.evaluate import evaluate
from flows.loop import loop
from flows.physics import evaluate_physics
from flows.policy import train_policy
from flows.register import register
from flows.report import markdown_table, publish
from flows.simulate import simulate
from flows.tokenize import tokenize
from flows.train import train
from schemas import paths
from schemas.settings import Settings

MANIFESTS = Path(__file__).resolve().parent.parent / "manifests"
# Simulated and then curated: normal light, and dim light (which the quality filter rejects).
DEMO = {"conveyor_push.yaml": 3, "bin_pick_dim_forklift.yaml": 2}
PUSH = str(MANIFESTS / "conveyor_push.yaml")


@flow(name="demo", log_prints=True)
def demo() -> dict:
    """Register every manifest, simulate episodes and curate them per manifest, train a tiny
    tokenizer on the push episodes' shards and a tiny world model on its tokens and the
    episodes' actions, check it against the simulator, evaluate two policies on a matched
    panel, generate a labelled minute of raw footage (simulator and procedural, with defects)
    and curate it, and close the loop once for a weak vision policy, beside an untargeted control."""
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
        tokens = tokenize(pushed["manifest_hash"], preset_name="tiny-dv4x8x8", steps=30, size=64)
        # Tiny presets, seconds of training: the loop's shape and its lineage, not its quality.
        world = train(PUSH, tokenizer=tokens["checkpoint_id"], preset_name="tiny-wm",
                      pretrain_steps=30, posttrain_steps=30)
        evaluate_physics(PUSH, world_model=world["posttrain_checkpoint_id"], episodes=2)
        world_model = world["posttrain_checkpoint"]
    else:
        world_model = None
    # Two policies on a matched panel, judged in the simulator and in the world model.
    evaluated = evaluate(PUSH, episodes=1, world_model=world_model)
    footage = corpus(minutes=1.0, seed=1, width=640, height=360)
    results.append(curate(footage["videos"]))
    # One turn of the loop for a weak policy that sees (the overhead camera at 32 px, three
    # demonstrations): its worst cells become new data and post-training, beside an untargeted
    # control that spends the same budget on the manifest as it is.
    seeing = train_policy(PUSH, episodes=3, steps=300, observe="overhead", image_size=32, holdout=0)
    closed = loop(PUSH, policy=f"vision:{seeing['folder']}", episodes=2, worst=2, new_episodes=6, post_steps=300,
                  control=True)
    publish("demo", f"{len(results)} curate runs, one loop", markdown_table(
        ("curate run", "manifest", "status", "inputs", "clips kept", "shards"),
        [(r["run_id"], (r["manifest_hash"] or "")[:12], r["status"], r["inputs"], r["clips"], len(r["shards"]))
         for r in results]), "the demo's curate runs")
    failed = [e for e in evaluated["evaluations"] if any(r["sim"] is not None and r["sim"] < 1 for r in e["table"])]
    return {"curate": results, "loop": closed,
            "audit_evaluation": (failed or evaluated["evaluations"])[-1]["evaluation_id"],
            "loop_before_evaluation": closed["before_evaluation_id"]}

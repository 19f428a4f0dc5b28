"""Tiny episodes simulated on the fly for the export tests: one-second push episodes, one 64 x 48
camera at 30 fps (the MP4s, steps.parquet and meta.json ``worldline simulate`` writes)."""

from __future__ import annotations

from pathlib import Path

from schemas.manifest import manifest_hash
from tasks.manifests import load
from tasks.sim.episode import rollout
from tasks.sim.files import write_episode

from tests.support import MANIFESTS

INSTRUCTION = "push the package onto the green goal marker"  # manifests/conveyor_push.yaml


def manifest_file(folder: Path, camera: str = "overhead", resolution: tuple[int, int] = (64, 48),
                  name: str = "small.yaml") -> Path:
    """conveyor_push for one second with its camera renamed and resized: a manifest YAML."""
    text = (MANIFESTS / "conveyor_push.yaml").read_text()
    text = (text.replace("horizon_s: 5.0", "horizon_s: 1.0").replace("[128, 128]", f"[{resolution[0]}, {resolution[1]}]")
            .replace("- name: overhead", f"- name: {camera}"))
    path = Path(folder) / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def simulate(root: Path, manifest: Path, seeds=(1, 2)) -> str:
    """Episodes of ``manifest`` under ``root`` as simulate lays them out; the manifest hash."""
    scenario = load(manifest)
    digest = manifest_hash(scenario)
    for index, seed in enumerate(seeds):
        write_episode(rollout(scenario, seed), root, digest, index)
    return digest

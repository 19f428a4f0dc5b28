"""register: validate a manifest and record it in lineage (the root of every artifact)."""

from __future__ import annotations

from pathlib import Path

from prefect import flow, task

from flows.params_data import RegisterParams
from flows.recording import recorded_run
from flows.report import markdown_table, publish
from schemas.settings import Settings
from tasks import manifests

load_manifest = task(manifests.load, name="load-manifest")


@flow(name="register", log_prints=True)
def register(manifest_path: str) -> str:
    """Validate first (an invalid manifest writes nothing), then record the manifest and this run."""
    RegisterParams.of(locals())  # every parameter check, for a deployment as for the CLI
    manifest = load_manifest(Path(manifest_path))
    with recorded_run("register", Settings(), manifest, source_uri=manifest_path,
                      params={"manifest": manifest_path}):
        digest = manifest.sha256
        print(f"registered {manifest.name} {digest[:12]} from {manifest_path}")
        publish("register", manifest.name, markdown_table(("manifest", "hash", "source", "stressors"), [
            (manifest.name, digest, manifest_path, ", ".join(sorted(s.kind for s in manifest.stressors)))]),
            "the manifest recorded in lineage")
    return digest

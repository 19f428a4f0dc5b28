"""curate: raw videos -> one decode each (scenes, filters, captions, signatures) -> dedup
-> encode kept clips -> Parquet shards. Every input, clip and shard lands in lineage."""

from __future__ import annotations

import time
from collections import defaultdict
from pathlib import Path

from prefect import flow, get_run_logger, task

from flows.curate_inputs import analysed, quarantine, source_changed
from flows.params_data import CurateParams
from flows.recording import RunContext, recorded_run
from flows.report import progress, publish
from flows.runners import task_runner
from schemas import paths
from schemas.hashing import stable_id
from schemas.manifest import ScenarioManifest
from schemas.errors import EnvironmentFault
from schemas.records import ClipRecord
from schemas.settings import Settings
from tasks import faults, manifests, progress as ticks
from tasks.curate import analyse, dedup, lineage, outputs, report, shards
from tasks.curate.config import CurateConfig, load_config
from tasks.curate.encode import encode_clips
from tasks.curate.inputs import Input, discover, same_bytes
from tasks.guard import clip as face_guard
from tasks.guard.lineage import face_decisions

load_manifest = task(manifests.load, name="load-manifest")
analyse_video = task(analyse.analyse_video, name="analyse-video", retries=0)
encode_video = task(encode_clips, name="encode-clips", retries=1)
write_shards = task(shards.write_shards, name="write-shards", retries=1)
guard_clips = task(face_guard.guard_clips, name="guard-faces", retries=1)


def analyse_all(run: RunContext, inputs: list[Input], config: CurateConfig,
                manifest: ScenarioManifest | None) -> list[analyse.VideoAnalysis]:
    """Each video decoded once, in parallel; finished ones come from the cache (no decode)."""
    root = run.settings.data_root
    config_hash = config.analysis_hash()
    keys = {stable_id(item.sha256, config_hash, run.manifest_hash or ""): item for item in inputs}
    stages = run.stages("analyse", keys)
    config = config.for_batch(sum(not s.done for s in stages.values()), run.settings.workers)
    results, futures = [], {}
    for key, item in keys.items():
        cache = paths.resolve(root, paths.ANALYSIS_FILE, sha256=item.sha256, config_hash=config_hash)
        cached = analyse.load(cache) if stages[key].done else None
        if cached is not None:
            cached.source = str(item.path)  # the name it has now: it may have been renamed since
            cached.clips = [c.model_copy(update={"source_uri": cached.source}) for c in cached.clips]
            results.append(cached)
        else:
            futures[key] = (item, cache, stages[key].restart(),
                            analyse_video.submit(item.path, item.sha256, config, manifest, run.manifest_hash))
    with progress(len(futures), "analyse videos") as bar:
        for item, cache, stage, future in futures.values():
            result = analysed(run, item, future)
            bar.advance()
            if result is None:
                continue
            analyse.save(result, cache)
            rejected = [c for c in result.clips if not c.kept]
            stage.finish(1, len(result.clips), lineage.raw_video(
                str(item.path), item.sha256, item.bytes, run.manifest_hash, stage.id,
                {"info": result.info, "decode": result.decode, **item.attrs}).extend(lineage.clips(rejected, stage.id)),
                attrs=paths.escaped({"source": str(item.path), **result.decode}))
            results.append(result)
    return sorted(results, key=lambda r: r.source)


def deduplicate(run: RunContext, analyses: list[analyse.VideoAnalysis], config: CurateConfig) -> list[ClipRecord]:
    started = time.perf_counter()
    kept = [c for a in analyses for c in a.clips if c.kept]
    signatures = {cid: s for a in analyses for cid, s in a.signatures.items()}
    exact: dict[str, dedup.ClipSignature] = {}
    result = dedup.group(signatures, {c.clip_id: dedup.quality_key(c, config.dedup) for c in kept}, config.dedup,
                         exact=analyse.exact_for(analyse.clip_spans(kept), config, exact))
    outputs.keep_exact(run.settings.data_root, analyses, exact, config)
    judged = dedup.apply(kept, {**signatures, **exact}, result)  # as a re-run will read them
    stage = run.stage("dedup", stable_id("dedup", *sorted(signatures), config.analysis_hash()), started=started)
    removed = [c for c in judged if not c.kept]
    stage.finish(len(kept), len(result.kept), lineage.clips(removed, stage.id),
                 attrs=paths.escaped({"groups": len(result.groups), "redecoded": result.redecoded}))
    return [c for c in judged if c.kept]


def encode_all(run: RunContext, clips: list[ClipRecord], config: CurateConfig,
               inputs: dict[str, Input]) -> list[ClipRecord]:
    """Kept clips only, one forward pass per source; files already encoded are reused; a source
    changed on disk since it was hashed is not encoded (or its new clips are removed)."""
    root = run.settings.data_root
    by_source: dict[str, list[ClipRecord]] = defaultdict(list)
    for clip in clips:
        by_source[clip.source_uri].append(clip)
    config = config.for_batch(len(by_source), run.settings.workers)
    futures, out, encodings = [], [], {}  # encodings: key -> the encode task, whose failure the guard's hides
    for source, group in sorted(by_source.items()):
        group.sort(key=lambda c: c.start_frame)
        targets = [paths.resolve(root, paths.CLIP_FILE, source_id=c.source_id, clip_id=c.clip_id) for c in group]
        key = stable_id("encode", group[0].source_id, config.encode_hash(), *(c.clip_id for c in group))
        redo, stage = False, run.stage("encode", key, targets)
        if stage.done:
            reused = outputs.reused(run.warehouse, group, targets, root)
            if reused is not None:
                out.extend(reused)
                continue
            redo = True  # a clip file changed since: encode the source's spans again (issue 26)
        if source_changed(run, inputs.get(source)):
            continue
        spans = [(c.start_frame, c.end_frame) for c in group]
        encoded = encodings[key] = encode_video.submit(source, spans, targets, config.encode)
        guarded = guard_clips.submit(targets, config.guard, config.encode, wait_for=[encoded])
        futures.append((key, group, targets, stage.restart(), guarded, redo))
    with progress(n := sum(len(f[1]) for f in futures), "kept clips encoded and guarded",  # the guard per clip below
                  {ticks.GUARDED: ("face guard", n)}) as bar:
        for key, group, targets, stage, future, redo in futures:
            try:
                faces = future.result()
            except Exception as exc:
                cause = encodings[key].result(raise_on_failure=False)  # why the guard never ran, if it did not
                cause = cause if isinstance(cause, BaseException) else exc
                if isinstance(cause, EnvironmentFault):
                    raise cause from None  # a full disk: the run stops, the source is not to blame
                if (fault := faults.machine(cause, targets[0].parent, "encoding clips", root)) is not None:
                    raise fault from cause
                run.fail_input(paths.escaped(f"{group[0].source_uri}: encoding failed: {exc}"))
                continue
            finally:
                bar.advance(len(group))
            if source_changed(run, inputs.get(group[0].source_uri), [] if redo else targets):
                continue
            encoded = [outputs.with_file(c, t, root, found) for c, t, found in zip(group, targets, faces)]
            if redo and (differs := outputs.differs(run.warehouse, encoded, targets)):
                run.fail_input(differs)
                continue
            batch = lineage.clips(encoded, stage.id)
            for clip, found in zip(encoded, faces):  # every guard decision is a row (issue 10)
                batch.extend(face_decisions(clip.clip_id, found, stage.id, run.manifest_hash))
            stage.finish(len(group), len(encoded), batch, attrs=paths.escaped(
                {"source": group[0].source_uri, "faces_hidden": sum(len(found) for found in faces)}))
            out.extend(encoded)
    return out


@flow(name="curate", log_prints=True, task_runner=task_runner())  # threads or Ray: WORLDLINE_TASK_RUNNER at import
def curate(inputs: list[str], manifest: str | None = None, config: str | None = None) -> dict:
    """Curate the videos in `inputs` (files or folders) under an optional scenario manifest."""
    CurateParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    cfg = load_config(Path(config) if config else None)
    scenario = load_manifest(Path(manifest)) if manifest else None
    with recorded_run("curate", settings, scenario, source_uri=manifest,
                      params=paths.escaped({"inputs": inputs, "manifest": manifest, "config": config})) as run:
        shards.remove_stale_temporaries(settings.data_root)  # left by a killed run; we hold the writer lock
        outputs.rename_legacy_shards(run.warehouse, settings.data_root)
        found = discover(inputs, skip=paths.output_folders(settings.data_root))  # not its own clips
        for item in (i for i in found if i.problem):
            quarantine(run, item, "input", item.reason or "unusable", f"{item.path}: {item.problem}")
        analyses = analyse_all(run, same_bytes([i for i in found if not i.problem]), cfg, scenario)
        for line in report.smeared(analyses):  # corrupt frames the decoder did not flag: named, not quarantined
            get_run_logger().warning(line)
        unique = deduplicate(run, analyses, cfg)
        encoded = encode_all(run, unique, cfg, {str(i.path): i for i in found})
        started = time.perf_counter()
        written = write_shards(encoded, settings.data_root, run.manifest_hash or "unscoped", cfg.shards)
        stage = run.stage("shard", stable_id("shards", *(s.sha256 for s in written)), started=started)
        stage.finish(len(encoded), len(written), shards.shard_lineage(written, stage.id))
        counts = report.tally(analyses, unique, encoded)
        publish("curate", f"{len(found)} inputs, {len(run.failures)} quarantined, {len(written)} shards",
                report.table(counts), "clips kept and rejected by reason")
        run.message = f"partial: {len(run.failures)} of {len(found)} inputs failed" if run.failures else run.message
        summary = {"run_id": run.run_id, "status": run.status, "inputs": len(found), "failed": len(run.failures),
                   "clips": len(encoded), "shards": [s.uri for s in written], "manifest_hash": run.manifest_hash,
                   "counts": {f"{s}/{r}": n for (s, r), n in sorted(counts.items())}}
    print(summary)
    return summary

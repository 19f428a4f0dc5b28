"""curate: raw videos -> one decode each (scenes, filters, captions, signatures) -> dedup
-> encode kept clips -> Parquet shards. Every input, clip and shard lands in lineage."""

from __future__ import annotations

import time
from collections import Counter, defaultdict
from pathlib import Path

from prefect import flow, task

from flows.recording import RunContext, recorded_run
from flows.report import markdown_table, progress
from flows.report import publish as publish_report
from flows.runners import task_runner
from schemas import paths
from schemas.hashing import sha256_file, stable_id
from schemas.manifest import ScenarioManifest
from schemas.errors import EnvironmentFault
from schemas.records import ClipRecord, LineageBatch, StageRunRecord
from schemas.settings import Settings
from tasks import faults, integrity, manifests
from tasks.curate import analyse, dedup, lineage, shards
from tasks.curate.config import CurateConfig, load_config
from tasks.curate.decode import DecodeError
from tasks.curate.encode import encode_clips
from tasks.curate.inputs import Input, damage, decode_reason, discover
from tasks.guard import clip as face_guard
from tasks.guard.lineage import face_decisions
from warehouse import integrity as claims
from warehouse import migrate

load_manifest = task(manifests.load, name="load-manifest")
analyse_video = task(analyse.analyse_video, name="analyse-video", retries=0)
encode_video = task(encode_clips, name="encode-clips", retries=1)
write_shards = task(shards.write_shards, name="write-shards", retries=1)
guard_clips = task(face_guard.guard_clips, name="guard-faces", retries=1)


def _stage(run: RunContext, stage: str, key: str, n_in: int, n_out: int, t0: float, **attrs) -> StageRunRecord:
    return StageRunRecord(stage_run_id=run.stage_run_id(stage, key), run_id=run.run_id, stage=stage, input_key=key,
                          manifest_hash=run.manifest_hash, n_in=n_in, n_out=n_out,
                          seconds=round(time.perf_counter() - t0, 3), attrs=paths.escaped(attrs))


def _quarantine(run: RunContext, item: Input, stage: str, reason: str, detail: str) -> None:
    source, detail = paths.escaped(item.path), paths.escaped(detail)
    key = stable_id("quarantine", source, item.sha256 or "")
    record = _stage(run, stage, key, 1, 0, time.perf_counter(), source=source, reason=reason)
    run.write(LineageBatch(stage_runs=[record.model_copy(update={"status": "failed"})]).extend(
        lineage.quarantined(source, item.sha256, stage, reason, detail, run.manifest_hash, record.stage_run_id)))
    run.fail_input(f"{source}: {detail}")
    print(f"quarantined {source}: {detail}")


def analyse_all(run: RunContext, inputs: list[Input], config: CurateConfig,
                manifest: ScenarioManifest | None) -> list[analyse.VideoAnalysis]:
    """Each video decoded once, in parallel; finished ones come from the cache (no decode)."""
    root = run.settings.data_root
    config_hash = config.analysis_hash()
    keys = {stable_id(item.sha256, config_hash, run.manifest_hash or ""): item for item in inputs}
    done = set(keys) - set(run.pending("analyse", list(keys)))
    config = config.for_batch(len(keys) - len(done), run.settings.workers)
    results, futures = [], {}
    for key, item in keys.items():
        cache = paths.resolve(root, paths.ANALYSIS_FILE, sha256=item.sha256, config_hash=config_hash)
        cached = analyse.load(cache) if key in done else None
        if cached is not None:
            cached.source = str(item.path)
            results.append(cached)
        else:
            futures[key] = (item, cache, time.perf_counter(),
                            analyse_video.submit(item.path, item.sha256, config, manifest, run.manifest_hash))
    with progress(len(futures), "analyse videos") as bar:
        for key, (item, cache, t0, future) in futures.items():
            result = _analysed(run, item, future)
            bar.advance()
            if result is None:
                continue
            analyse.save(result, cache)
            stage = _stage(run, "analyse", key, 1, len(result.clips), t0, source=str(item.path), **result.decode)
            rejected = [c for c in result.clips if not c.kept]
            batch = LineageBatch(stage_runs=[stage]).extend(
                lineage.raw_video(str(item.path), item.sha256, item.bytes, run.manifest_hash, stage.stage_run_id,
                                  {"info": result.info, "decode": result.decode})).extend(
                lineage.clips(rejected, stage.stage_run_id))
            run.write(batch)
            results.append(result)
    return sorted(results, key=lambda r: r.source)


def _analysed(run: RunContext, item: Input, future) -> analyse.VideoAnalysis | None:
    """The analysis of one input, or None when the input is quarantined instead."""
    try:
        result = future.result()
    except EnvironmentFault:
        raise  # the machine's fault (a full disk): the run stops, the input is not blamed
    except DecodeError as exc:
        _quarantine(run, item, "decode", decode_reason(str(exc)), str(exc))
        return None
    except Exception as exc:  # a batch never dies on one video
        if (fault := faults.disk_full(exc, item.path, "analysing")) is not None:
            raise fault from exc
        _quarantine(run, item, "analyse", type(exc).__name__, f"{item.path}: {exc}")
        return None
    if (damaged := damage(result.decode)) is not None:
        _quarantine(run, item, "decode", damaged[0], f"{item.path}: {damaged[1]}")
        return None
    return result


def deduplicate(run: RunContext, analyses: list[analyse.VideoAnalysis], config: CurateConfig) -> list[ClipRecord]:
    t0 = time.perf_counter()
    kept = [c for a in analyses for c in a.clips if c.kept]
    signatures = {cid: s for a in analyses for cid, s in a.signatures.items()}
    exact: dict[str, dedup.ClipSignature] = {}
    result = dedup.group(signatures, {c.clip_id: dedup.quality_key(c, config.dedup) for c in kept}, config.dedup,
                         exact=analyse.exact_for(analyse.clip_spans(kept), config, exact))
    _keep_exact(run, analyses, exact, config)
    judged = dedup.apply(kept, {**signatures, **exact}, result)  # as a re-run will read them
    key = stable_id("dedup", *sorted(signatures), config.analysis_hash())
    stage = _stage(run, "dedup", key, len(kept), len(result.kept), t0, groups=len(result.groups),
                   redecoded=result.redecoded)
    removed = [c for c in judged if not c.kept]
    run.write(LineageBatch(stage_runs=[stage]).extend(lineage.clips(removed, stage.stage_run_id)))
    return [c for c in judged if c.kept]


def _keep_exact(run: RunContext, analyses: list[analyse.VideoAnalysis], exact: dict[str, dedup.ClipSignature],
                config: CurateConfig) -> None:
    """Signatures dedup had decoded exactly go into their analyses' caches: a re-run decodes nothing."""
    for a in analyses:
        if mine := {cid: s for cid, s in exact.items() if cid in a.signatures}:
            a.signatures.update(mine)
            analyse.save(a, paths.resolve(run.settings.data_root, paths.ANALYSIS_FILE, sha256=a.sha256,
                                          config_hash=config.analysis_hash()))


def encode_all(run: RunContext, clips: list[ClipRecord], config: CurateConfig) -> list[ClipRecord]:
    """Kept clips only, one forward pass per source; files already encoded are reused."""
    root = run.settings.data_root
    by_source: dict[str, list[ClipRecord]] = defaultdict(list)
    for clip in clips:
        by_source[clip.source_uri].append(clip)
    config = config.for_batch(len(by_source), run.settings.workers)
    futures, out = [], []
    encodings = {}  # key -> the encode task, whose own failure the guard task's hides
    for source, group in sorted(by_source.items()):
        group.sort(key=lambda c: c.start_frame)
        targets = [paths.resolve(root, paths.CLIP_FILE, source_id=c.source_id, clip_id=c.clip_id) for c in group]
        key = stable_id("encode", group[0].source_id, config.encode_hash(), *(c.clip_id for c in group))
        redo = False
        if not run.pending("encode", [key]) and all(t.exists() for t in targets):
            reused = _reused(run, group, targets, root)
            if reused is not None:
                out.extend(reused)
                continue
            redo = True  # a clip file changed since: encode the source's spans again (issue 26)
        spans = [(c.start_frame, c.end_frame) for c in group]
        encoded = encodings[key] = encode_video.submit(source, spans, targets, config.encode)
        guarded = guard_clips.submit(targets, config.guard, config.encode, wait_for=[encoded])
        futures.append((key, group, targets, time.perf_counter(), guarded, redo))
    with progress(len(futures), "encode kept clips") as bar:
        for key, group, targets, t0, future, redo in futures:
            try:
                faces = future.result()
            except Exception as exc:
                cause = encodings[key].result(raise_on_failure=False)  # why the guard never ran, if it did not
                cause = cause if isinstance(cause, BaseException) else exc
                if isinstance(cause, EnvironmentFault):
                    raise cause from None  # a full disk: the run stops, the source is not to blame
                if (fault := faults.disk_full(cause, targets[0].parent, "encoding clips")) is not None:
                    raise fault from cause
                run.fail_input(paths.escaped(f"{group[0].source_uri}: encoding failed: {exc}"))
                continue
            finally:
                bar.advance()
            encoded = [_with_file(c, t, root, found) for c, t, found in zip(group, targets, faces)]
            if redo and (differs := _differs(run, encoded, targets)):
                run.fail_input(differs)
                continue
            stage = _stage(run, "encode", key, len(group), len(encoded), t0, source=group[0].source_uri,
                           faces_hidden=sum(len(found) for found in faces))
            batch = LineageBatch(stage_runs=[stage]).extend(lineage.clips(encoded, stage.stage_run_id))
            for clip, found in zip(encoded, faces):  # every guard decision is a row (issue 10)
                batch.extend(face_decisions(clip.clip_id, found, stage.stage_run_id, run.manifest_hash))
            run.write(batch)
            out.extend(encoded)
    return out


def _reused(run: RunContext, group: list[ClipRecord], targets: list[Path], root: Path) -> list[ClipRecord] | None:
    """The clips of a source encoded before, each file hashed once and checked against the
    sha256 lineage recorded for it; None when one differs (or lineage has none), so the source
    is encoded again: its bytes are intact (the clip ids hash them), and with a fixed thread
    count x264 writes the same clips, so encoding again restores what lineage recorded."""
    recorded = claims.recorded(run.warehouse, [c.clip_id for c in group])
    tags = claims.clip_tags(run.warehouse, [c.clip_id for c in group])
    out = []
    for clip, target in zip(group, targets):
        digest = integrity.file_sha256(target)
        row = recorded.get(clip.clip_id)
        if row is None or integrity.Recorded(*row).sha256 != digest:
            want = f"lineage's {row[3][:12]}" if row is not None else "no sha256 in lineage"
            print(paths.escaped(f"{target}: sha256 {digest[:12]} differs from {want}; encoding {clip.source_uri} again"))
            return None
        # The guard's tag belongs to the file: the encode that hid the faces recorded it.
        kept = tuple(dict.fromkeys((*clip.tags, *(t for t in tags.get(clip.clip_id, ()) if t.startswith("guard:")))))
        out.append(_with_file(clip.model_copy(update={"tags": kept}), target, root, sha256=digest))
    return out


def _differs(run: RunContext, encoded: list[ClipRecord], targets: list[Path]) -> str | None:
    """Why clips encoded again to replace changed files still differ from lineage, or None."""
    recorded = claims.recorded(run.warehouse, [c.clip_id for c in encoded])
    for clip, target in zip(encoded, targets):
        if (row := recorded.get(clip.clip_id)) is not None and row[3] != clip.sha256:
            return (f"{target}: changed since lineage recorded it, and encoding it again gave sha256 "
                    f"{clip.sha256[:12]}, not lineage's {row[3][:12]}; its source's clips are left out of the shards")
    return None


def _with_file(clip: ClipRecord, target: Path, root: Path, faces=(), sha256: str | None = None) -> ClipRecord:
    """The clip with its file's uri, size and sha256 (``sha256`` when the caller hashed it already)."""
    tags = (*clip.tags, "guard:faces_hidden") if faces else clip.tags
    return clip.model_copy(update={"uri": str(target.relative_to(root)), "sha256": sha256 or sha256_file(str(target)),
                                   "bytes": target.stat().st_size, "tags": tags})


def rename_legacy_shards(run: RunContext) -> None:
    """Old-layout shards (``part-NNNNN.parquet``, which a later run into the bucket overwrote:
    issue 26) move to their names by content, their rows first; nothing is deleted."""
    root = run.settings.data_root
    for old in shards.legacy_shards(root):
        known = migrate.rename_shard(run.warehouse, old.uri, old.new_uri, old.sha256)
        shards.rename_legacy(root, old)
        print(f"renamed shard {old.uri} to {old.new_uri}"
              + ("" if known else " (no lineage row has its bytes: a shard no run recorded, or one whose row was lost)"))


def publish(run: RunContext, counts: Counter, n_shards: int, inputs: int) -> str:
    table = markdown_table(("stage", "outcome", "clips"), [(s, o, n) for (s, o), n in sorted(counts.items())])
    return publish_report("curate", f"{inputs} inputs, {len(run.failures)} quarantined, {n_shards} shards", table,
                          "clips kept and rejected by reason")


# The runner (threads or Ray) comes from WORLDLINE_TASK_RUNNER when this module is imported.
@flow(name="curate", log_prints=True, task_runner=task_runner())
def curate(inputs: list[str], manifest: str | None = None, config: str | None = None) -> dict:
    """Curate the videos in `inputs` (files or folders) under an optional scenario manifest."""
    settings = Settings()
    cfg = load_config(Path(config) if config else None)
    scenario = load_manifest(Path(manifest)) if manifest else None
    with recorded_run("curate", settings, scenario, source_uri=manifest,
                      params=paths.escaped({"inputs": inputs, "manifest": manifest, "config": config})) as run:
        shards.remove_stale_temporaries(settings.data_root)  # left by a killed run; we hold the writer lock
        rename_legacy_shards(run)
        found = discover(inputs)
        for item in found:
            if item.problem:
                _quarantine(run, item, "input", item.reason or "unusable", f"{item.path}: {item.problem}")
        analyses = analyse_all(run, [i for i in found if not i.problem], cfg, scenario)
        unique = deduplicate(run, analyses, cfg)
        encoded = encode_all(run, unique, cfg)
        t0 = time.perf_counter()
        written = write_shards(encoded, settings.data_root, run.manifest_hash or "unscoped", cfg.shards)
        key = stable_id("shards", *(s.sha256 for s in written))
        run.write(LineageBatch(stage_runs=[_stage(run, "shard", key, len(encoded), len(written), t0)]).extend(
            shards.shard_lineage(written, run.stage_run_id("shard", key))))
        counts = Counter(("kept", "encoded") for _ in encoded)
        for a in analyses:
            counts.update((c.reject_stage, c.reject_reason) for c in a.clips if not c.kept)
        counts[("dedup", "duplicate")] = len([c for a in analyses for c in a.clips if c.kept]) - len(unique)
        publish(run, counts, len(written), len(found))
        if run.failures:
            run.message = f"partial: {len(run.failures)} of {len(found)} inputs failed"
        summary = {"run_id": run.run_id, "status": run.status, "inputs": len(found), "failed": len(run.failures),
                   "clips": len(encoded), "shards": [s.uri for s in written], "manifest_hash": run.manifest_hash,
                   "counts": {f"{s}/{r}": n for (s, r), n in sorted(counts.items())}}
    print(summary)
    return summary

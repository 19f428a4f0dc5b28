"""Curation speed against the codec work alone and against the `scenedetect` command line.

Over the same 720p30 raw footage (default 10 minutes, generated once and cached under
bench/out/speed_corpus/), in one run, back to back:

(a) curate: the curate flow's own functions in its order, on a fresh data root: sha256 and
    `analyse.analyse_video` per source (one decode: scenes, filters, captions, signatures),
    `dedup.group`/`apply` across sources, `encode.encode_clips` per source for the kept clips
    only, then `shards.write_shards`. Prefect and the lineage writes are left out (they are
    the same whatever the footage; the curate flow test covers them).
(b) codec: one full decode of each source plus one encode of (a)'s kept clips with the same
    encoder (`encode.EncodeConfig`, `encode.x264_options`) and the same decoder threading as
    (a)'s encode pass (`CurateConfig.for_batch`): the work no curator can avoid.
(c) scenedetect: `scenedetect -i FILE -o DIR detect-content split-video -p PRESET -crf CRF`
    per source, with Debian's ffmpeg (`make bench-deps`): it decodes twice, filters nothing
    and encodes every scene.

(a) and (b) run sources on the same pool of `--workers` threads (the flow's own runner is a
thread pool) or, with `--pool process`, processes; (c) runs one source at a time and lets
ffmpeg thread itself (it uses every core). `--concurrent` runs (c) alongside (a) and (b)
rather than after them: a shorter run on a busy machine, whose wall times then share the CPU.
Prints wall seconds, CPU seconds (user + system, of this process, of its pool processes with
`--pool process`, and of the scenedetect and ffmpeg processes for (c): less sensitive than
wall time to other load on the machine) and frames/s (source frames / wall seconds), then
the ratios. Targets (issue 4): a/b <= 1.3 and a/c < 1.

    .venv/bin/python bench/curate_speed.py [--minutes 10] [--workers 2] [--pool thread] [--rounds 1]
        [--concurrent] [--no-scenedetect] [--limit N] [--inputs FILE...]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import shutil
import subprocess
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path

import av

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from schemas import paths  # noqa: E402
from schemas.hashing import sha256_file  # noqa: E402
from tasks.corpus.generate import VIDEO_MINUTES, generate_corpus  # noqa: E402
from tasks.curate import analyse, dedup, shards  # noqa: E402
from tasks.curate.config import CurateConfig  # noqa: E402
from tasks.curate.encode import _to_display, _Writer, encode_clips  # noqa: E402
from tasks.video import EncodeConfig, open_video, output_size, probe  # noqa: E402

OUT = Path(__file__).resolve().parent / "out"
SCENEDETECT = Path(sys.executable).with_name("scenedetect")


def corpus(minutes: float, seed: int, width: int, height: int) -> list[Path]:
    """The cached corpus under bench/out/speed_corpus/, generated when any file is missing."""
    root = OUT / "speed_corpus"
    n = max(1, math.ceil(minutes / VIDEO_MINUTES))
    videos = [paths.resolve(root, paths.CORPUS_VIDEO, seed=seed, index=i) for i in range(n)]
    truths = [paths.resolve(root, paths.CORPUS_TRUTH, seed=seed, index=i) for i in range(n)]
    if all(v.exists() and t.exists() for v, t in zip(videos, truths)) and _matches(truths[0], width, height):
        return videos
    print(f"generating {minutes} min of {width}x{height} under {root} (about {minutes * 2:.0f} min of CPU)", flush=True)
    t0 = time.perf_counter()
    made = generate_corpus(root, seed=seed, minutes=minutes, width=width, height=height)
    print(f"generated in {time.perf_counter() - t0:.0f} s", flush=True)
    return [v.video for v in made]


def _matches(truth: Path, width: int, height: int) -> bool:
    body = json.loads(truth.read_text())
    return (body.get("width"), body.get("height")) == (width, height)


class Clock:
    """Wall seconds and CPU seconds (user + system) over a block: of this process, plus its
    finished children when ``children`` (process pools)."""

    def __init__(self, children: bool = False):
        self.who = (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN) if children else (resource.RUSAGE_SELF,)

    def __enter__(self):
        self.t0, self.c0 = time.perf_counter(), self._cpu()
        return self

    def __exit__(self, *exc):
        self.wall, self.cpu = time.perf_counter() - self.t0, self._cpu() - self.c0

    def _cpu(self) -> float:
        return sum(u.ru_utime + u.ru_stime for u in map(resource.getrusage, self.who))


def _analyse(path: Path, config: CurateConfig) -> analyse.VideoAnalysis:
    return analyse.analyse_video(path, sha256_file(str(path)), config)


def _pool(kind: str, workers: int):
    return (ProcessPoolExecutor if kind == "process" else ThreadPoolExecutor)(workers)


def curate_once(videos: list[Path], root: Path, config: CurateConfig, workers: int,
                pool_kind: str = "thread") -> tuple[dict, dict]:
    """(a): the flow's stages over `videos` with a fresh data root. Returns (kept spans per
    source, seconds per stage: wall, and `_cpu` for this process's CPU, pool processes not counted)."""
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(parents=True)
    stages = {}
    with _pool(pool_kind, workers) as pool:
        t0, c0 = time.perf_counter(), time.process_time()
        analyses = list(pool.map(_analyse, videos, [config] * len(videos)))
        stages["analyse"], stages["analyse_cpu"] = time.perf_counter() - t0, time.process_time() - c0

        t0, c0 = time.perf_counter(), time.process_time()
        kept = [c for a in analyses for c in a.clips if c.kept]
        signatures = {cid: s for a in analyses for cid, s in a.signatures.items()}
        result = dedup.group(signatures, {c.clip_id: dedup.quality_key(c, config.dedup) for c in kept}, config.dedup,
                             exact=analyse.exact_for(analyse.clip_spans(kept), config))
        unique = [c for c in dedup.apply(kept, signatures, result) if c.kept]
        stages["dedup"], stages["dedup_cpu"] = time.perf_counter() - t0, time.process_time() - c0

        t0, c0 = time.perf_counter(), time.process_time()
        by_source = defaultdict(list)
        for clip in unique:
            by_source[clip.source_uri].append(clip)
        jobs = []
        for source, group in sorted(by_source.items()):
            group.sort(key=lambda c: c.start_frame)
            targets = [paths.resolve(root, paths.CLIP_FILE, source_id=c.source_id, clip_id=c.clip_id) for c in group]
            spans = [(c.start_frame, c.end_frame) for c in group]
            jobs.append((group, targets, pool.submit(encode_clips, source, spans, targets, config.encode)))
        encoded = []
        for group, targets, future in jobs:
            future.result()
            encoded += [c.model_copy(update={"uri": str(t.relative_to(root)), "sha256": sha256_file(str(t)),
                                             "bytes": t.stat().st_size}) for c, t in zip(group, targets)]
        stages["encode"], stages["encode_cpu"] = time.perf_counter() - t0, time.process_time() - c0
    t0 = time.perf_counter()
    shards.write_shards(encoded, root, "bench", config.shards)
    stages["shards"] = time.perf_counter() - t0
    spans = defaultdict(list)
    for clip in unique:
        spans[clip.source_uri].append((clip.start_frame, clip.end_frame))
    counts = {"scenes": sum(len(a.clips) for a in analyses), "kept_by_filters": len(kept), "kept": len(unique),
              "kept_frames": sum(e - s for group in spans.values() for s, e in group)}
    return dict(spans), {**stages, **counts}


def codec_once(videos: list[Path], spans: dict, root: Path, config: EncodeConfig, workers: int,
               pool_kind: str = "thread") -> None:
    """(b): per source, decode every frame once and encode the frames of the kept spans."""
    shutil.rmtree(root, ignore_errors=True)
    with _pool(pool_kind, workers) as pool:
        for future in [pool.submit(_decode_encode, v, sorted(spans.get(str(v), [])), root, config) for v in videos]:
            future.result()


def _decode_encode(source: Path, spans: list[tuple[int, int]], root: Path, config: EncodeConfig) -> None:
    info = probe(source)
    size = output_size(info)
    container = open_video(source)
    try:
        stream = container.streams.video[0]
        stream.thread_type = config.decode_thread_type  # the same decoder as (a)'s encode pass
        stream.thread_count = config.decode_threads
        writers: dict[int, _Writer] = {}
        starts = {s: j for j, (s, _) in enumerate(spans)}
        ends = defaultdict(list)
        for j, (_, e) in enumerate(spans):
            ends[e].append(j)
        for index, frame in enumerate(container.decode(stream)):
            for j in ends.pop(index, []):
                writers.pop(j).close(*spans[j])
            if index in starts:
                j = starts[index]
                writers[j] = _Writer(root / source.stem / f"{j:04d}.mp4", info, stream, config)
            if writers:
                shown = _to_display(frame, info, size)
                for writer in writers.values():
                    writer.write(shown)
        for j in list(writers):
            writers.pop(j).close(*spans[j])
    finally:
        container.close()


def scenedetect_once(videos: list[Path], root: Path, config: EncodeConfig) -> tuple[float, float]:
    """(c): the scenedetect command line per source, one after another. Returns (wall, CPU)
    seconds, the CPU of each command and the ffmpeg processes it waits for (wait4)."""
    shutil.rmtree(root, ignore_errors=True)
    t0, cpu = time.perf_counter(), 0.0
    for video in videos:
        out = root / video.stem
        out.mkdir(parents=True)
        cmd = [str(SCENEDETECT), "-q", "-i", str(video), "-o", str(out), "detect-content",
               "split-video", "-q", "-p", config.preset, "-crf", str(config.crf)]
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode:
            raise subprocess.CalledProcessError(proc.returncode, cmd)
        cpu += usage.ru_utime + usage.ru_stime
    return time.perf_counter() - t0, cpu


def frame_count(video: Path) -> int:
    with av.open(str(video)) as container:
        return container.streams.video[0].frames or probe(video).n_frames


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=400)
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--workers", type=int, default=2, help="workers for (a) and (b), sources in parallel")
    ap.add_argument("--pool", choices=("thread", "process"), default="thread",
                    help="thread: as the flow runs tasks today; process: sources in separate processes")
    ap.add_argument("--rounds", type=int, default=1, help="repeat (a), (b), (c) back to back")
    ap.add_argument("--limit", type=int, default=0, help="only the first N cached videos (a quick look; never generates)")
    ap.add_argument("--no-scenedetect", action="store_true")
    ap.add_argument("--concurrent", action="store_true",
                    help="run (c) alongside (a) then (b) instead of after them: a shorter run on a busy machine, "
                         "compare CPU seconds then")
    ap.add_argument("--work", type=Path, default=OUT / "speed_run", help="scratch data roots (removed at the end)")
    ap.add_argument("--inputs", type=Path, nargs="+", help="these videos instead of the cached corpus")
    args = ap.parse_args()
    width, height = map(int, args.size.split("x"))
    if args.inputs:
        videos = args.inputs
    elif args.limit:
        videos = [paths.resolve(OUT / "speed_corpus", paths.CORPUS_VIDEO, seed=args.seed, index=i) for i in range(args.limit)]
        if not all(v.exists() and v.with_suffix(".truth.json").exists() for v in videos):
            sys.exit(f"--limit {args.limit}: the first {args.limit} videos are not cached yet (run without --limit)")
    else:
        videos = corpus(args.minutes, args.seed, width, height)
    if not args.no_scenedetect and (shutil.which("ffmpeg") is None or not SCENEDETECT.exists()):
        sys.exit("scenedetect needs ffmpeg on PATH and .venv/bin/scenedetect: run `make bench-deps`")
    # As the curate flow does: one decoder thread per video when every worker has a video.
    config = CurateConfig().for_batch(len(videos), args.workers)
    import scipy.fftpack  # noqa: F401  imagehash's phash imports it on first use: a one-off second, not per frame
    frames = sum(frame_count(v) for v in videos)
    fps = probe(videos[0]).fps
    print(f"corpus: {len(videos)} videos, {frames} frames ({frames / fps / 60:.1f} min) of {args.size} at "
          f"{fps:g} fps; x264 {config.encode.preset} crf {config.encode.crf}, {config.encode.threads} x264 thread "
          f"per clip; decoders {config.analysis.thread_type}/{config.encode.decode_thread_type}; (a) and (b): {args.workers} worker {args.pool}s; (c): one source at a time, ffmpeg threads auto; "
          f"{os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}", flush=True)
    run = args.work
    children = args.pool == "process"
    if args.concurrent and children:
        sys.exit("--concurrent needs --pool thread (CPU of pool processes and scenedetect would mix)")
    for r in range(args.rounds):
        background = None
        if args.concurrent and not args.no_scenedetect:
            background = ThreadPoolExecutor(1)
            c_future = background.submit(scenedetect_once, videos, run / "c", config.encode)
        with Clock(children) as a:
            spans, stats = curate_once(videos, run / "a", config, args.workers, args.pool)
        print(f"round {r + 1} (a) curate      wall {a.wall:7.1f} s  cpu {a.cpu:7.1f} s  {frames / a.wall:6.1f} frames/s  "
              + "  ".join(f"{k} {v:.1f} s" if isinstance(v, float) else f"{k} {v}" for k, v in stats.items()), flush=True)
        with Clock(children) as b:
            codec_once(videos, spans, run / "b", config.encode, args.workers, args.pool)
        print(f"round {r + 1} (b) codec only  wall {b.wall:7.1f} s  cpu {b.cpu:7.1f} s  {frames / b.wall:6.1f} frames/s  "
              f"(decode {frames} frames, encode {stats['kept_frames']})", flush=True)
        line = f"round {r + 1} ratios: a/b wall {a.wall / b.wall:.3f} (target <= 1.3), a/b cpu {a.cpu / b.cpu:.3f}"
        if not args.no_scenedetect:
            if background is not None:
                c_wall, c_cpu = c_future.result()
                background.shutdown()
            else:
                c_wall, c_cpu = scenedetect_once(videos, run / "c", config.encode)
            print(f"round {r + 1} (c) scenedetect wall {c_wall:7.1f} s  cpu {c_cpu:7.1f} s  {frames / c_wall:6.1f} "
                  f"frames/s" + ("  (ran alongside (a) and (b))" if background is not None else ""), flush=True)
            line += f"; a/c wall {a.wall / c_wall:.3f} (target < 1), a/c cpu {a.cpu / c_cpu:.3f}"
        print(line + f"; load {os.getloadavg()[0]:.1f}", flush=True)
    shutil.rmtree(run, ignore_errors=True)


if __name__ == "__main__":
    main()

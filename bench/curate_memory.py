"""Peak memory of curating one video of length L and one of length 2L (issue 4: the ratio < 1.5).

Each measurement runs in a fresh subprocess that curates one video on a fresh data root with
the curate flow's own stages (`curate_speed.curate_once`: analysis, dedup, encode of kept
clips, shards) and reports its peak RSS (VmHWM, the kernel's high-water mark, also read
after each stage to show where the peak is). The videos come from the cached 720p corpus of
`curate_speed.py`: L is raw_0000 and 2L is raw_0000 followed by raw_0001, joined without
re-encoding by ffmpeg's concat demuxer (`make bench-deps`).

    .venv/bin/python bench/curate_memory.py
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

OUT = Path(__file__).resolve().parent / "out"


def hwm_mb() -> float:
    """This process's peak resident set so far, in MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM in /proc/self/status")


def child(video: Path, root: Path) -> None:
    """Curate `video` alone and print one JSON line: frames, kept clips, peak RSS per stage."""
    import resource

    import curate_speed as cs
    from tasks.curate import analyse, shards
    from tasks.curate.config import CurateConfig

    config = CurateConfig()
    marks = {"imports": hwm_mb()}
    originals = analyse.analyse_video, shards.write_shards

    def analysed(*args, **kwargs):  # the high-water mark after each stage, without changing them
        result = originals[0](*args, **kwargs)
        marks["analyse"] = hwm_mb()
        return result

    def sharded(*args, **kwargs):
        marks["encode"] = hwm_mb()
        result = originals[1](*args, **kwargs)
        marks["shards"] = hwm_mb()
        return result

    analyse.analyse_video, shards.write_shards = analysed, sharded
    spans, stats = cs.curate_once([video], root, config, workers=1)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"video": str(video), "kept": stats["kept"], "kept_frames": stats["kept_frames"],
                      "peak_mb": peak, "hwm_mb": {k: round(v, 1) for k, v in marks.items()}}))


def measure(video: Path, root: Path) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", str(video), "--root", str(root)],
                         check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def frames_of(video: Path) -> tuple[int, float]:
    from tasks.video import frame_pts, probe

    info = probe(video)
    return len(frame_pts(video)[0]), info.fps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=400)
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--root", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child, args.root)
        return
    import shutil

    import curate_speed as cs

    if shutil.which("ffmpeg") is None:
        sys.exit("curate_memory.py needs ffmpeg on PATH: run `make bench-deps`")
    videos = cs.corpus(4.0, args.seed, 1280, 720)[:2]
    work = OUT / "memory"
    work.mkdir(parents=True, exist_ok=True)
    double = work / f"seed{args.seed}_raw0000+0001.mp4"
    if not double.exists():
        listing = work / "concat.txt"
        listing.write_text("".join(f"file '{v.resolve()}'\n" for v in videos))
        tmp = double.with_name(f".{double.name}.tmp.mp4")
        subprocess.run(["ffmpeg", "-v", "error", "-y", "-f", "concat", "-safe", "0", "-i", str(listing),
                        "-c", "copy", str(tmp)], check=True)
        tmp.replace(double)
    results = []
    for label, video in (("L", videos[0]), ("2L", double)):
        n, fps = frames_of(video)
        result = measure(video, work / f"root_{label}")
        results.append(result)
        print(f"{label:>2}: {video.name}: {n} frames ({n / fps / 60:.1f} min), {result['kept']} clips kept "
              f"({result['kept_frames']} frames); peak RSS {result['peak_mb']:.0f} MB; high-water mark after "
              + ", ".join(f"{k} {v:.0f}" for k, v in result["hwm_mb"].items()) + " MB", flush=True)
        shutil.rmtree(work / f"root_{label}", ignore_errors=True)
    ratio = results[1]["peak_mb"] / results[0]["peak_mb"]
    print(f"peak RSS ratio 2L/L: {ratio:.3f} (target < 1.5)")


if __name__ == "__main__":
    main()

"""Constants and media factories shared by tests (kept out of conftest so it is imported once).

The factories are plain functions (``bench/reliability.py`` uses them too). Videos are tiny
(64 x 48, 3 s at 15 fps) procedural footage that the curate filters keep, one content seed
per file so no two inputs are duplicates of each other.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable, Sequence
from fractions import Fraction
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
MANIFESTS = REPO / "manifests"

WIDTH, HEIGHT, FPS, FRAMES = 64, 48, 15, 45


def scene_frames(seed: int, width: int = WIDTH, height: int = HEIGHT, n: int = FRAMES) -> list[np.ndarray]:
    """``n`` frames (H x W x 3 uint8 RGB) of procedural corpus footage of content ``seed``."""
    from tasks.corpus.procedural import scene

    source = scene(seed, width, height)
    return [source.frame(t) for t in range(n)]


def write_video(path: Path, frames: Iterable[np.ndarray], fps: float = FPS, times: Sequence[float] | None = None,
                rotation: int = 0, faststart: bool = False, gop: int | None = None) -> Path:
    """H.264 MP4 with PyAV. ``times``: per-frame seconds (variable frame rate, 1 ms ticks);
    ``rotation``: display-matrix degrees; odd sizes are written as 4:4:4 (which allows them)."""
    import av

    frames = list(frames)
    h, w = frames[0].shape[:2]
    options = {"movflags": "+faststart"} if faststart else {}
    with av.open(str(path), "w", format="mp4", options=options) as container:
        stream = container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height = w, h
        stream.pix_fmt = "yuv420p" if w % 2 == 0 and h % 2 == 0 else "yuv444p"
        stream.thread_count = 1
        params = f"keyint={gop}:min-keyint={gop}:scenecut=0" if gop else ""
        stream.options = {"preset": "veryfast", "crf": "18", **({"x264-params": params} if params else {})}
        if times is not None:
            stream.codec_context.time_base = Fraction(1, 1000)
        if rotation:
            stream.set_display_rotation(rotation)
        for i, image in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24")
            if times is not None:
                frame.pts, frame.time_base = int(round(times[i] * 1000)), Fraction(1, 1000)
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path


def good_videos(folder: Path, seeds: Sequence[int] = (0, 2, 3)) -> list[Path]:
    """Plain videos whose clips the filters keep (checked seeds of the procedural footage)."""
    folder.mkdir(parents=True, exist_ok=True)
    return [write_video(folder / f"good_{seed}.mp4", scene_frames(seed)) for seed in seeds]


def unusual_videos(folder: Path) -> list[Path]:
    """Odd but sound inputs that must be curated, not quarantined: variable frame rate, a
    display rotation, odd width and height, and names with spaces, quotes and non-ASCII."""
    folder.mkdir(parents=True, exist_ok=True)
    steps = [1 / 30 if i % 3 else 2 / 15 for i in range(FRAMES - 1)]  # 33 ms and 133 ms frames
    return [
        write_video(folder / "vfr.mp4", scene_frames(4), times=np.concatenate([[0.0], np.cumsum(steps)])),
        write_video(folder / "rotated_90.mp4", scene_frames(5), rotation=90),
        write_video(folder / "odd_63x47.mp4", scene_frames(10, 63, 47)),
        write_video(folder / "name with spaces.mp4", scene_frames(7)),
        write_video(folder / "it's \"quoted\".mp4", scene_frames(8)),
        write_video(folder / "ünïcødé 名前 видео.mp4", scene_frames(9)),
    ]


def small_manifest(folder: Path, horizon_s: float = 2.5) -> Path:
    """``folder/small.yaml``: conveyor_push at 64 x 64 for ``horizon_s`` seconds, a quick episode."""
    text = (MANIFESTS / "conveyor_push.yaml").read_text()
    path = Path(folder) / "small.yaml"
    path.write_text(text.replace("horizon_s: 5.0", f"horizon_s: {horizon_s}").replace("[128, 128]", "[64, 64]"))
    return path


# -- frames that carry their own index (the curate decode and encode tests) ---------------------
def coded(i: int, w: int = 64, h: int = 48) -> np.ndarray:
    """H x W x 3 frame carrying i in two grey blocks (i % 16 and i // 16, 14 levels apart)
    on a textured, moving background."""
    y, x = np.mgrid[0:h, 0:w]
    frame = np.stack([(x * 3 + i) % 256, (y * 5) % 256, ((x + y + 2 * i) * 2) % 256], axis=-1).astype(np.uint8)
    frame[: h // 2, : w // 4] = 20 + 14 * (i % 16)
    frame[: h // 2, w // 4: w // 2] = 20 + 14 * (i // 16)
    return frame


def read_index(image: np.ndarray) -> int:
    """Inverse of ``coded`` for a frame of any size in the original orientation."""
    h, w = image.shape[:2]
    grey = image.astype(np.float64).mean(axis=-1)
    low = grey[h // 16: h // 2 - h // 16, w // 32: w // 4 - w // 32].mean()
    high = grey[h // 16: h // 2 - h // 16, w // 4 + w // 32: w // 2 - w // 32].mean()
    return int(round((low - 20) / 14)) + 16 * int(round((high - 20) / 14))


def _patch_mdhd_timescale(data: bytes, value: int) -> bytes:
    at = data.index(b"mdhd")
    offset = at + 4 + 4 + (16 if data[at + 4] == 1 else 8)  # version/flags, then creation/modification times
    return data[:offset] + struct.pack(">I", value) + data[offset + 4:]


def _raw_avi(path: Path, width: int, height: int) -> Path:
    """A rawvideo AVI of two tiny frames whose headers (avih, strf) then claim width x height."""
    import av

    with av.open(str(path), "w", format="avi") as container:
        stream = container.add_stream("rawvideo", rate=15)
        stream.width, stream.height, stream.pix_fmt = 16, 16, "gray"
        for i in range(2):
            frame = av.VideoFrame.from_ndarray(np.full((16, 16), 40 * i, np.uint8), format="gray")
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    data = bytearray(path.read_bytes())
    avih = data.index(b"avih") + 8
    data[avih + 32: avih + 40] = struct.pack("<II", width, height)  # dwWidth, dwHeight
    strf = data.index(b"strf") + 8
    data[strf + 4: strf + 12] = struct.pack("<ii", width, height)  # BITMAPINFOHEADER biWidth, biHeight
    path.write_bytes(bytes(data))
    return path


def _audio_only(path: Path) -> Path:
    import av

    with av.open(str(path), "w", format="mp4") as container:
        stream = container.add_stream("aac", rate=8000)
        frame = av.AudioFrame.from_ndarray(np.zeros((1, 8000), np.float32), format="fltp", layout="mono")
        frame.sample_rate = 8000
        for packet in [*stream.encode(frame), *stream.encode()]:
            container.mux(packet)
    return path


def _corrupt_middle(path: Path, seed: int) -> Path:
    """Random bytes over three frames in the middle group of pictures (headers kept)."""
    import av

    write_video(path, scene_frames(seed), gop=15)
    with av.open(str(path)) as container:
        packets = [(p.pos, p.size) for p in container.demux(video=0) if p.size]
    data = bytearray(path.read_bytes())
    rng = np.random.default_rng(seed)
    for pos, size in packets[20:23]:
        data[pos + 4: pos + size] = rng.integers(0, 256, size - 4, dtype=np.uint8).tobytes()
    path.write_bytes(bytes(data))
    return path


# file name -> (stage, reason) each bad input must be quarantined with. "locked.mp4" only
# counts where permission bits bind (not as root; see tests/flows/test_reliability.py).
BAD_INPUTS: dict[str, tuple[str, str]] = {
    "empty.mp4": ("input", "empty"),
    "random_bytes.mp4": ("decode", "unreadable"),
    "cut_before_index.mp4": ("input", "truncated"),
    "cut_mid_stream.mp4": ("input", "truncated"),
    "corrupt_middle.mp4": ("decode", "corrupt_frames"),
    "audio_only.mp4": ("decode", "no_video_stream"),
    "one_frame.mp4": ("decode", "single_frame"),
    "fps_0.mp4": ("decode", "absurd_frame_rate"),
    "fps_10000.mp4": ("decode", "absurd_frame_rate"),
    "huge_100000x100000.avi": ("decode", "absurd_frame_size"),
    "loop.mp4": ("input", "symlink_loop"),
    "x.mp4": ("input", "directory"),
    "locked.mp4": ("input", "permission_denied"),
}


def bad_inputs(folder: Path) -> dict[str, tuple[str, str]]:
    """Write every input of ``BAD_INPUTS`` into ``folder``; returns ``BAD_INPUTS``."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "empty.mp4").write_bytes(b"")
    (folder / "random_bytes.mp4").write_bytes(np.random.default_rng(5).integers(0, 256, 4096, np.uint8).tobytes())
    whole = write_video(folder / ".whole.tmp.mp4", scene_frames(20)).read_bytes()
    (folder / "cut_before_index.mp4").write_bytes(whole[: len(whole) // 2])  # moov comes last: lost
    faststart = write_video(folder / ".faststart.tmp.mp4", scene_frames(21), faststart=True).read_bytes()
    (folder / "cut_mid_stream.mp4").write_bytes(faststart[: len(faststart) * 6 // 10])  # index kept, data cut
    (folder / ".whole.tmp.mp4").unlink()
    (folder / ".faststart.tmp.mp4").unlink()
    _corrupt_middle(folder / "corrupt_middle.mp4", 22)
    _audio_only(folder / "audio_only.mp4")
    write_video(folder / "one_frame.mp4", scene_frames(23, n=1))
    zero = write_video(folder / "fps_0.mp4", scene_frames(24, n=10)).read_bytes()
    (folder / "fps_0.mp4").write_bytes(_patch_mdhd_timescale(zero, 0))  # the header's clock ticks 0 times a second
    write_video(folder / "fps_10000.mp4", scene_frames(25, n=10), fps=10000)
    _raw_avi(folder / "huge_100000x100000.avi", 100_000, 100_000)
    os.symlink("loop.mp4", folder / "loop.mp4")  # points at itself
    (folder / "x.mp4").mkdir()
    write_video(folder / "locked.mp4", scene_frames(26))
    os.chmod(folder / "locked.mp4", 0)
    return dict(BAD_INPUTS)


# -- running the curate command in its own process ---------------------------------------------
# What root may do regardless of permission bits; dropping them makes root read files as their
# owner would (mode 000: nobody may), which is how the "no read permission" input is tested.
PERMISSION_CAPS = "-dac_override,-dac_read_search"


def unprivileged_prefix() -> list[str] | None:
    """The command prefix under which permission bits bind: none needed when not root; as root,
    ``setpriv`` without the capabilities that bypass them; None when that is not possible."""
    import shutil

    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    return [setpriv, f"--bounding-set={PERMISSION_CAPS}", "--"] if setpriv else None


def curate_command(inputs: Sequence[Path | str], data_root: Path, fault: str | None = None,
                   api_url: str | None = None, prefix: Sequence[str] = (), workers: int | None = None,
                   timeout: float = 600):
    """Run ``worldline curate INPUTS`` in a fresh process (a SIGKILL ends it and nothing else).

    ``fault`` sets WORLDLINE_FAULT (tasks/faults.py); ``api_url`` points Prefect at a running
    API instead of starting its ~10 s ephemeral server; ``workers`` sets the task runner's
    threads (WORLDLINE_WORKERS). Returns the CompletedProcess.
    """
    import subprocess

    env = {k: v for k, v in os.environ.items() if not k.startswith(("WORLDLINE_", "PREFECT_"))}
    env |= {"WORLDLINE_DATA_ROOT": str(data_root), "PREFECT_HOME": str(Path(data_root) / "prefect"),
            "PYTHONDONTWRITEBYTECODE": "1"}
    if fault:
        env["WORLDLINE_FAULT"] = fault
    if api_url:
        env["PREFECT_API_URL"] = api_url
    if workers:
        env["WORLDLINE_WORKERS"] = str(workers)
    command = [*prefix, str(REPO / ".venv" / "bin" / "python"), "-m", "flows.cli", "curate", *map(str, inputs)]
    return subprocess.run(command, env=env, cwd=REPO, capture_output=True, text=True, timeout=timeout)


# -- lineage and file integrity ---------------------------------------------------------------
# Each query counts rows that must not exist. Run them on a warehouse after any run, killed or not.
LINEAGE_CHECKS: dict[str, str] = {
    "duplicate artifacts": "SELECT count(*) - count(DISTINCT artifact_id) FROM artifacts",
    "duplicate edges": "SELECT count(*) FROM (SELECT 1 FROM edges GROUP BY parent_id, child_id, relation HAVING count(*) > 1)",
    "duplicate ancestry pairs": "SELECT count(*) FROM (SELECT 1 FROM ancestry GROUP BY descendant_id, ancestor_id HAVING count(*) > 1)",
    "duplicate rejections": "SELECT count(*) FROM (SELECT 1 FROM rejections GROUP BY artifact_id, stage HAVING count(*) > 1)",
    "duplicate stage runs": "SELECT count(*) - count(DISTINCT stage_run_id) FROM stage_runs",
    "duplicate clips of one span": "SELECT count(*) FROM (SELECT 1 FROM artifacts WHERE kind = 'clip' "
                                   "GROUP BY attrs->>'source_id', attrs->>'start_frame', attrs->>'end_frame' HAVING count(*) > 1)",
    "edges from unknown parents": "SELECT count(*) FROM edges WHERE parent_id NOT IN (SELECT artifact_id FROM artifacts)",
    "edges to unknown children": "SELECT count(*) FROM edges WHERE child_id NOT IN (SELECT artifact_id FROM artifacts)",
    "rejections of unknown artifacts": "SELECT count(*) FROM rejections WHERE artifact_id NOT IN (SELECT artifact_id FROM artifacts)",
    "artifacts from unknown stage runs": "SELECT count(*) FROM artifacts WHERE stage_run_id IS NOT NULL "
                                         "AND stage_run_id NOT IN (SELECT stage_run_id FROM stage_runs)",
    "rejections from unknown stage runs": "SELECT count(*) FROM rejections WHERE stage_run_id IS NOT NULL "
                                          "AND stage_run_id NOT IN (SELECT stage_run_id FROM stage_runs)",
    "stage runs of unknown runs": "SELECT count(*) FROM stage_runs WHERE run_id NOT IN (SELECT run_id FROM runs)",
    "ancestry of unknown artifacts": "SELECT count(*) FROM ancestry WHERE descendant_id NOT IN (SELECT artifact_id FROM artifacts) "
                                     "OR ancestor_id NOT IN (SELECT artifact_id FROM artifacts)",
    "edges missing from ancestry": "SELECT count(*) FROM edges e WHERE NOT EXISTS (SELECT 1 FROM ancestry a "
                                   "WHERE a.descendant_id = e.child_id AND a.ancestor_id = e.parent_id AND a.depth = 1)",
    "shards without clips": "SELECT count(*) FROM artifacts s WHERE kind = 'shard' AND NOT EXISTS "
                            "(SELECT 1 FROM edges WHERE child_id = s.artifact_id AND relation = 'shard_of')",
    "kept clips without a file": "SELECT count(*) FROM artifacts WHERE kind = 'clip' AND uri IS NULL AND artifact_id NOT IN "
                                 "(SELECT artifact_id FROM rejections)",
    "runs still marked running": "SELECT count(*) FROM runs WHERE status = 'running'",
}


def lineage_problems(warehouse: Path) -> dict[str, int]:
    """Every LINEAGE_CHECKS count that is not zero, plus files on disk and rows that disagree."""
    from warehouse.store import Warehouse

    with Warehouse(warehouse, read_only=True) as wh:
        found = {name: wh.query(sql)[1][0][0] for name, sql in LINEAGE_CHECKS.items()}
        _, rows = wh.query("SELECT kind, uri, sha256 FROM artifacts WHERE kind IN ('clip', 'shard') AND uri IS NOT NULL")
    root = Path(warehouse).parent
    recorded = {uri: sha for _, uri, sha in rows}
    on_disk = {p.relative_to(root).as_posix() for folder in ("clips", "shards") if (root / folder).is_dir()
               for p in (root / folder).rglob("*") if p.is_file()}
    found["files not in lineage (or temporaries)"] = len(on_disk - set(recorded))
    found["lineage files missing on disk"] = len(set(recorded) - on_disk)
    found["files whose bytes differ from lineage"] = sum(
        1 for uri, sha in recorded.items() if uri in on_disk and sha256_of(root / uri) != sha)
    return {name: n for name, n in found.items() if n}


def sha256_of(path: Path) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def shard_digests(root: Path) -> dict[str, str]:
    return {p.relative_to(root).as_posix(): sha256_of(p) for p in sorted((Path(root) / "shards").rglob("*.parquet"))}


RUNNER_LINEAGE = """SELECT kind, count(*) FROM artifacts GROUP BY kind
             UNION ALL SELECT 'edges', count(*) FROM edges
             UNION ALL SELECT 'rejections', count(*) FROM rejections ORDER BY 1"""


def runner_inbox(folder: Path) -> Path:
    """Two 3-second conveyor_push episodes and one unreadable file: what the task-runner tests
    curate on each runner."""
    from tasks.manifests import load
    from tasks.video import write_mp4
    from tasks.sim.episode import rollout

    folder.mkdir(parents=True, exist_ok=True)
    scenario = load(MANIFESTS / "conveyor_push.yaml").model_copy(update={"horizon_s": 3.0})
    for seed in (1, 2):
        write_mp4(folder / f"episode_{seed}.mp4", rollout(scenario, seed).frames["overhead"], 30)
    (folder / "broken.mp4").write_bytes(b"not a video" * 50)
    return folder


def curate_on(flow, root: Path, monkeypatch, inbox: Path) -> tuple[dict, dict[str, str], list]:
    """(summary, shard digests, lineage row counts) of ``flow`` (curate with some task runner)
    over ``inbox`` into data root ``root``."""
    from schemas.settings import Settings
    from warehouse.store import Warehouse

    monkeypatch.setenv("WORLDLINE_DATA_ROOT", str(root))
    summary = flow([str(inbox)], str(MANIFESTS / "conveyor_push.yaml"))
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, rows = wh.query(RUNNER_LINEAGE)
    return summary, shard_digests(root), rows


# -- file names that are not UTF-8 (issue 26) -------------------------------------------------
def undecodable_name(folder: Path, name: bytes) -> Path:
    """``folder / name`` for a name that is not UTF-8 (e.g. ``b"bad\\xff.mp4"``), as the OS lists
    it: a str with surrogate escapes (``os.fsdecode``); its real bytes open the file."""
    return Path(os.fsdecode(os.path.join(os.fsencode(folder), name)))


def rename_to(path: Path, name: bytes) -> Path:
    """Rename ``path`` inside its folder to the raw bytes ``name``; returns the new path."""
    target = undecodable_name(Path(path).parent, name)
    os.rename(os.fsencode(path), os.fsencode(target))
    return target


def escaped_name(path: Path) -> str:
    """How lineage and messages write ``path``: undecodable bytes as ``\\xff`` escapes."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")

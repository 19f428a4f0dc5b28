"""Writing video: x264 kept off AVX-512 for reproducible bytes, and write_mp4's bytes."""

from __future__ import annotations


from tasks.video import probe, write_mp4, x264_cpu_limit
from tests.support import coded


def test_x264_is_kept_off_avx512_only_where_there_is_avx512():
    assert x264_cpu_limit("flags\t\t: fpu sse sse2 ssse3 sse4_1 sse4_2 avx avx2 fma bmi1 bmi2\n") is None
    limit = x264_cpu_limit("processor: 0\nflags\t\t: fpu sse sse2 pni avx avx2 avx512f avx512bw clflush\n")
    assert limit == "MMX2,SSE2,SSE3,AVX,AVX2,Cache64"


def test_write_mp4_gives_the_same_bytes_for_the_same_frames(tmp_path):
    frames = [coded(i) for i in range(12)]
    a = write_mp4(tmp_path / "a.mp4", frames, fps=25)
    b = write_mp4(tmp_path / "b.mp4", iter(frames), fps=25)
    assert a.read_bytes() == b.read_bytes()
    info = probe(a)
    assert (info.n_frames, info.width, info.height) == (12, 64, 48)
    assert not list(tmp_path.glob(".*.tmp*"))

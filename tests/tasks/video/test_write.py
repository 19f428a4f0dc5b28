"""Writing video: x264 kept off AVX-512 for reproducible bytes, write_mp4's bytes, and x264 options
libx264 cannot read refused."""

from __future__ import annotations

import av
import numpy as np
import pytest

from tasks.video import probe, write_mp4, x264, x264_cpu_limit
from tasks.video.write import EncodeConfig, x264_options
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


def test_the_x264_check_reads_options_as_the_encoder_does(tmp_path):
    """What the check accepts changes the stream; what it refuses, libx264 would have dropped."""
    if x264._library() is None:
        pytest.skip("PyAV's wheel has no separate libx264 here")
    frames = [np.full((32, 32, 3), 8 * i, np.uint8) for i in range(30)]

    def key_frames(params: str) -> int:
        path = tmp_path / f"k{len(params)}.mp4"
        with av.open(str(path), "w") as out:
            stream = out.add_stream("libx264", rate=30, options=x264_options(EncodeConfig(x264_params=params)))
            stream.width, stream.height, stream.pix_fmt = 32, 32, "yuv420p"
            for image in frames:
                out.mux(stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")))
            out.mux(stream.encode())
        with av.open(str(path)) as src:
            return sum(packet.is_keyframe for packet in src.demux(video=0) if packet.size)

    assert key_frames("") == 1 and key_frames("keyint=5:min-keyint=5:scenecut=0") == 6
    for typo, said in (("keyitn=5", "no option 'keyitn'"), ("keyint=five", "cannot read keyint='five'")):
        with pytest.raises(ValueError, match=said):
            EncodeConfig(x264_params=typo)

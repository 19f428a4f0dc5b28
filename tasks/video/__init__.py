"""Video I/O for every stage: reading (``read.py``: open, probe, packet index, full decode in
display orientation) and writing (``write.py``: the x264 settings and ``write_mp4``).

Curate, guard, sim, the corpus generator and the panels read and write video through here,
so no stage imports another for it. Imports PyAV, numpy and pydantic, and of ours only
``tasks.faults``.
"""

from tasks.video.read import DecodeError, SourceInfo, display_frames, frame_pts, is_reference, nal_length_size
from tasks.video.read import open_video, output_size, probe
from tasks.video.write import EncodeConfig, write_mp4, x264_cpu_limit, x264_options

__all__ = ["DecodeError", "EncodeConfig", "SourceInfo", "display_frames", "frame_pts", "is_reference",
           "nal_length_size", "open_video", "output_size", "probe", "write_mp4", "x264_cpu_limit", "x264_options"]

"""Video I/O for every stage: reading (``read.py``: open, probe, packet index, full decode in
display orientation, the stored frames of the project's own videos) and writing (``write.py``: the x264 settings and ``write_mp4``; ``x264.py`` checks x264 options
with libx264 itself).

Curate, guard, sim, the corpus generator and the panels read and write video through here,
so no stage imports another for it. Imports PyAV, numpy and pydantic, and of ours only
``tasks.faults``.
"""

from tasks.video.read import DecodeError, SourceInfo, display_frames, frame_pts, frame_rate, is_reference
from tasks.video.read import nal_length_size, open_video, output_size, probe, read_frames, stored_frames
from tasks.video.write import EncodeConfig, write_mp4, x264_cpu_limit, x264_options

__all__ = ["DecodeError", "EncodeConfig", "SourceInfo", "display_frames", "frame_pts", "frame_rate", "is_reference",
           "nal_length_size", "open_video", "output_size", "probe", "read_frames", "stored_frames", "write_mp4",
           "x264_cpu_limit", "x264_options"]

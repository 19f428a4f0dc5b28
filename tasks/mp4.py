"""``write_mp4``, kept importable here for the modules that import it from this path; it lives
in ``tasks/video/write.py`` with the rest of the project's video I/O."""

from tasks.video.write import write_mp4

__all__ = ["write_mp4"]

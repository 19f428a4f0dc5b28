"""What the curate flow reports: the files with concealment-smeared frames are named."""

from tasks.curate.analyse import VideoAnalysis
from tasks.curate.report import smeared


def test_files_with_smeared_frames_are_named_with_their_frames():
    clean = VideoAnalysis(source="a.mp4", sha256="0" * 64, bytes=1, decode={"frames": 10, "smeared": 0})
    broken = VideoAnalysis(source="b.mp4", sha256="1" * 64, bytes=1,
                           decode={"frames": 280, "smeared": 1, "smeared_frames": [229]})
    many = VideoAnalysis(source="c.mp4", sha256="2" * 64, bytes=1,
                         decode={"frames": 900, "smeared": 25, "smeared_frames": list(range(20))})
    old = VideoAnalysis(source="d.mp4", sha256="3" * 64, bytes=1, decode={"frames": 5})  # cached before the count
    lines = smeared([clean, broken, many, old])
    assert lines[0] == ("b.mp4: 1 frame(s) smeared by decoder concealment (frames 229); the clips holding them "
                        "are rejected as quality:smeared")
    assert len(lines) == 2 and lines[1].startswith("c.mp4: 25 frame(s)") and "19, ...)" in lines[1]

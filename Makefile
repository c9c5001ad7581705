# fixbench: `make bench` sets up and runs the main job; `make test` sets up and runs the tests.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: setup bench test lint clean

# Pinned, reproducible install. torch is pinned on its own line: 2.13.0 is a local CPU wheel here,
# and any other spec would pull gigabytes of CUDA packages.
$(STAMP): pyproject.toml requirements.lock
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -r requirements.lock
	$(BIN)/pip install -q --no-deps -e .
	touch $(STAMP)

setup: $(STAMP)

bench: setup
	$(BIN)/fixbench validate
	$(BIN)/fixbench run bench/matrices/default.toml --out results/default
	$(BIN)/fixbench report results/default
	$(BIN)/fixbench export results/default --format iohprofiler
	$(BIN)/fixbench export results/default --format marl-eval

test: setup
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q -n 2 --benchmark-disable

lint: setup
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis .ruff_cache

# fixbench: `make bench` sets up and runs the main job; `make test` sets up and runs the tests.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
TESTED := $(VENV)/.installed-test
# Lines of requirements.lock installed --no-deps by `make bench` and `make test`, so that a set-up machine
# runs every planner (the paper matrix's mappo, ippo and qmix need them): the marl extra (benchmarl,
# torchrl, tensordict) and marl-eval's loader. Their declared requirements would pull another torch, torchvision
# and av (benchmarl) or pandas 1.4 (id-marl-eval); what they import is pinned in the lock beside them.
NODEPS := ^(benchmarl|torchrl|tensordict|id-marl-eval)==

.PHONY: setup bench test lint clean browser

# Pinned, reproducible install. torch is pinned on its own line: 2.13.0 is a local CPU wheel here,
# and any other spec would pull gigabytes of CUDA packages.
$(STAMP): pyproject.toml requirements.lock
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q torch==2.13.0
	grep -v -E '$(NODEPS)' requirements.lock > $(VENV)/requirements-deps.txt
	$(BIN)/pip install -q -r $(VENV)/requirements-deps.txt
	$(BIN)/pip install -q --no-deps -e .
	touch $(STAMP)

setup: $(STAMP)

$(TESTED): $(STAMP)
	grep -E '$(NODEPS)' requirements.lock > $(VENV)/requirements-nodeps.txt
	$(BIN)/pip install -q --no-deps -r $(VENV)/requirements-nodeps.txt
	touch $(TESTED)

# Debian's chromium for tests/test_html.py, where apt is there and we are root; never fails the build
# (without it those tests skip).
browser:
	@command -v chromium >/dev/null || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null \
		&& apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } \
		|| echo "chromium not installed: tests/test_html.py skips"

bench: $(TESTED)
	$(BIN)/fixbench validate
	$(BIN)/fixbench run bench/matrices/default.toml --out results/default
	$(BIN)/fixbench report results/default
	$(BIN)/fixbench export results/default --format iohprofiler
	$(BIN)/fixbench export results/default --format marl-eval

test: $(TESTED) browser
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup --benchmark-disable --durations=20

lint: setup
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis .ruff_cache

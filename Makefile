# Set-up and everyday commands. `make run` and `make test` work on a fresh machine.
PYTHON ?= $(shell for p in python3.12 $${PYENV_ROOT:-$$HOME/.pyenv}/versions/3.12*/bin/python3.12 $$HOME/.pyenv/versions/3.12*/bin/python3.12 /usr/bin/python3.12 /usr/local/bin/python3.12; do $$p -c 'import sys; assert sys.version_info[:2] == (3, 12)' 2>/dev/null && { command -v $$p || echo $$p; } && break; done)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
DEV_STAMP := $(VENV)/.installed-dev

.PHONY: run test venv lock bench clean

$(PY):
	@test -n "$(PYTHON)" || { echo "python3.12 not found: install Python 3.12 or pass PYTHON=/path/to/python3.12"; exit 1; }
	$(PYTHON) -m venv $(VENV)

# Python writes each module's bytecode into .venv (and mwbx/__pycache__) at its first
# import, as pip would have for every file at install: scripts/install_lock.sh skips
# that (half of pip's time), so make's commands let Python write it.
unexport PYTHONDONTWRITEBYTECODE

# What running needs, at the versions and hashes of requirements.lock (pip and setuptools
# included: mwbx itself installs without build isolation); the tests' extras (browser,
# property tests, Warp, linter) only for `make test`, from requirements-dev.lock.
$(STAMP): $(PY) pyproject.toml requirements.lock
	bash scripts/install_lock.sh $(PY) requirements.lock
	$(PY) -m pip install -q --no-deps --no-build-isolation -e .
	@touch $(STAMP)

$(DEV_STAMP): $(STAMP) requirements-dev.lock
	bash scripts/install_lock.sh $(PY) requirements-dev.lock
	@touch $(DEV_STAMP)

venv: $(DEV_STAMP)

# Re-resolve pyproject.toml into requirements.lock and requirements-dev.lock (commit both):
# keeps the locked versions and adds what is new; UPGRADE=1 takes the newest ones allowed.
lock: $(PY)
	UPGRADE=$(UPGRADE) PY=$(PY) bash scripts/lock.sh

# Sample the default scene and print a summary.
run: $(STAMP)
	$(VENV)/bin/mwbx sample configs/quickstart.yaml --worlds 256 --out out/quickstart

# The linter, then the whole test suite (the browser test installs Debian's chromium when it can),
# in TEST_WORKERS processes, a test file each at a time (its module fixtures built once).
TEST_WORKERS ?= 2
test: $(DEV_STAMP)
	-@bash scripts/ensure_chromium.sh
	$(PY) -m ruff check mwbx scripts tests
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile --durations=25 tests

# Every benchmark: tables on stdout, JSON (and plots) in out/bench/, then docs/benchmarks.md from them.
bench: $(DEV_STAMP)
	$(PY) -m pip install -q -e ".[dev,bench]"
	$(PY) scripts/bench_sampler.py
	$(PY) scripts/bench_codec.py
	$(PY) scripts/bench_queries.py --real 1024
	$(PY) scripts/bench_geometry_tightness.py
	$(PY) scripts/bench_viewer.py --browser --screenshot docs/viewer_screenshot.png
	$(PY) scripts/bench_refine.py
	$(PY) scripts/bench_tower.py
	$(PY) scripts/bench_steps.py
	$(PY) scripts/bench_page_refine.py
	$(PY) scripts/bench_bank.py
	$(PY) scripts/bench_browse.py --browser
	$(PY) scripts/bench_solve.py
	$(PY) scripts/scene_counts.py
	$(PY) scripts/make_benchmarks_doc.py

clean:
	rm -rf out .pytest_cache .hypothesis

# Two entry points (see README): `make run` and `make test`. Both create .venv on first use and
# (re)install the project from pyproject.toml whenever pyproject.toml changes, so they are
# idempotent on a fresh machine. `make run` installs only what serving needs (the package's
# dependencies); `make test` and `make bench` add the test and bench extras.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV ?= .venv
BIN := $(VENV)/bin
RUN_STAMP := $(VENV)/.installed-run
TEST_STAMP := $(VENV)/.installed-test
WARM_UP := $(BIN)/python -c 'from raytrace.solver.tracer import warm_up; print(f"tracer kernels compiled in {warm_up():.1f} s")'
# the built-in CT abdomen, built once from its vendored files and cached (~1 min of CPU the first time;
# raytrace/body/abdomen.py): at install, and before serving when its sources changed since
BUILD_PHANTOMS := $(BIN)/python -m raytrace.body.abdomen

.PHONY: run test bench openapi clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(RUN_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	$(WARM_UP)
	$(BUILD_PHANTOMS)
	touch $(RUN_STAMP)

# the test extra holds everything serving needs too: once it is installed, `make run` has nothing to add
$(TEST_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test,bench]'
	$(WARM_UP)
	$(BUILD_PHANTOMS)
	touch $(TEST_STAMP) $(RUN_STAMP)

run: $(RUN_STAMP)
	@$(BUILD_PHANTOMS)
	$(BIN)/capsule-rt serve

CHROMIUM ?= /usr/bin/chromium
# pytest-xdist workers: one per CPU this process may use (the suite's servers and jobs are per worker)
TEST_WORKERS ?= $(shell $(PYTHON) -c 'import os; print(len(os.sched_getaffinity(0)))' 2>/dev/null || echo 2)

test: $(TEST_STAMP)
	@test -x $(CHROMIUM) || echo "make test: no Chromium at $(CHROMIUM), so the browser tests (viewer, /docs) \
	are skipped; install Debian's package to run them: apt-get install chromium"
	$(BIN)/ruff check .
	$(BIN)/mypy
	CAPSULE_RT_CHROMIUM=$(CHROMIUM) $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile

bench: $(TEST_STAMP)
	$(BIN)/python -m bench $(BENCH_ARGS)

openapi: $(RUN_STAMP)
	$(BIN)/capsule-rt openapi

# Also numba's on-disk kernel cache (raytrace/engine/__pycache__/*.nbi, *.nbc; keyed on the engine's
# sources, so a stale one is never loaded: this only reclaims the space) and, when NUMBA_CACHE_DIR is
# set, the engine's entries there.
clean:
	rm -rf $(VENV) .pytest_cache bench/results
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
	if [ -n "$$NUMBA_CACHE_DIR" ] && [ -d "$$NUMBA_CACHE_DIR" ]; then \
		find "$$NUMBA_CACHE_DIR" -path '*/engine_*' \( -name '*.nbi' -o -name '*.nbc' \) -delete; fi

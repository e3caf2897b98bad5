# Two entry points (see README): `make run` and `make test`. Both create
# .venv on first use and (re)install the project from pyproject.toml whenever
# pyproject.toml changes, so they are idempotent on a fresh machine.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test bench openapi clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,bench]'
	$(BIN)/python -c 'from raytrace.solver.tracer import warm_up; print(f"tracer kernels compiled in {warm_up():.1f} s")'
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/capsule-rt serve

CHROMIUM ?= /usr/bin/chromium

test: $(STAMP)
	@test -x $(CHROMIUM) || echo "make test: no Chromium at $(CHROMIUM), so the browser tests (viewer, /docs) \
	are skipped; install Debian's package to run them: apt-get install chromium"
	$(BIN)/ruff check .
	CAPSULE_RT_CHROMIUM=$(CHROMIUM) $(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/python -m bench $(BENCH_ARGS)

openapi: $(STAMP)
	$(BIN)/capsule-rt openapi

# Also numba's on-disk kernel cache (raytrace/engine/__pycache__/*.nbi, *.nbc; keyed on the engine's
# sources, so a stale one is never loaded: this only reclaims the space) and, when NUMBA_CACHE_DIR is
# set, the engine's entries there.
clean:
	rm -rf $(VENV) .pytest_cache bench/results
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
	if [ -n "$$NUMBA_CACHE_DIR" ] && [ -d "$$NUMBA_CACHE_DIR" ]; then \
		find "$$NUMBA_CACHE_DIR" -path '*/engine_*' \( -name '*.nbi' -o -name '*.nbc' \) -delete; fi

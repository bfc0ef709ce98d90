# Every target works on a fresh machine: it creates .venv and installs what it needs.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: test lint bench bench-quick demo clean

# System packages the project needs (installed only when missing, and only as root):
# python3-venv for the environment, chromium for the dashboard's browser test, gcc and
# python3-dev to compile the planner's hot modules (setup.py; without them it stays pure Python),
# iproute2 for the network namespaces of the partition test.
SYSTEM_PACKAGES := python3-venv chromium gcc python3-dev iproute2

$(STAMP): pyproject.toml setup.py
	@{ $(PY) -c 'import venv, ensurepip' 2>/dev/null && command -v chromium >/dev/null \
	   && command -v gcc >/dev/null && command -v ip >/dev/null \
	   && $(PY) -c 'import os, sysconfig; assert os.path.exists(sysconfig.get_path("include") + "/Python.h")' 2>/dev/null; } || { \
	  [ "$$(id -u)" = 0 ] && apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
	    --no-install-recommends $(SYSTEM_PACKAGES) >/dev/null; } || echo "make: could not install $(SYSTEM_PACKAGES) (not root?)"
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP) $(NATIVE_STAMP)

# The planner's mypyc-compiled modules (setup.py) go stale when their sources change: the import
# then falls back to the sources, slower, with a RuntimeWarning. Rebuild them first. (The stamp is
# make's own: the build writes one too, but only when it compiled.)
NATIVE_STAMP := $(VENV)/.native

$(NATIVE_STAMP): setup.py $(wildcard drona_gcs/planner/*.py) | $(STAMP)
	$(BIN)/pip install --quiet --no-deps -e .
	touch $@

# The tests that fly fleets of real processes, which keep real time (a cell every tau). With
# CAP_SYS_NICE (root's) they run one at a time beside two workers for the rest, whose tests of the
# core yield the CPU to them (tests/conftest.py): two fleets at once on two cores starved each
# other's vehicles, which ran late. Elsewhere two workers take a file each, as before.
FLEET_TESTS := tests/integration tests/fleet/bench/test_coordination.py tests/fleet/bench/test_delivery.py
CAP_SYS_NICE := $(shell cap=$$(awk '/^CapEff:/ {print $$2}' /proc/self/status 2>/dev/null); \
	echo $$(( 0x$${cap:-0} >> 23 & 1 )))

test: $(STAMP) $(NATIVE_STAMP)
	$(BIN)/ruff check drona_gcs fleet api tests
	$(BIN)/mypy
ifeq ($(CAP_SYS_NICE),1)
	@fleets=$$(mktemp); $(BIN)/pytest -q $(FLEET_TESTS) > $$fleets 2>&1 & lane=$$!; \
	$(BIN)/pytest -q -n 2 --dist loadfile $(FLEET_TESTS:%=--ignore=%); rest=$$?; \
	wait $$lane; flown=$$?; echo "--- $(FLEET_TESTS), one fleet at a time:"; cat $$fleets; rm -f $$fleets; \
	[ $$rest = 0 ] && [ $$flown = 0 ]
else
	$(BIN)/pytest -q -n 2 --dist loadfile
endif

lint: $(STAMP)
	$(BIN)/ruff check drona_gcs fleet api tests
	$(BIN)/mypy

bench: $(STAMP) $(NATIVE_STAMP)
	$(BIN)/drona bench planner

bench-quick: $(STAMP) $(NATIVE_STAMP)
	$(BIN)/drona bench planner --quick

demo: $(STAMP) $(NATIVE_STAMP)
	$(BIN)/drona demo

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache build
	rm -f drona_gcs/planner/*.so drona_gcs/planner/_native_sources.*.sha256

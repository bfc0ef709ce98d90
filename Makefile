# Every target works on a fresh machine: it creates .venv and installs what it needs.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: test lint bench bench-quick demo clean

# System packages the project needs (installed only when missing, and only as root):
# python3-venv for the environment, chromium for the dashboard's browser test.
SYSTEM_PACKAGES := python3-venv chromium

$(STAMP): pyproject.toml
	@{ $(PY) -c 'import venv, ensurepip' 2>/dev/null && command -v chromium >/dev/null; } || { \
	  [ "$$(id -u)" = 0 ] && apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
	    --no-install-recommends $(SYSTEM_PACKAGES) >/dev/null; } || echo "make: could not install $(SYSTEM_PACKAGES) (not root?)"
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/ruff check drona_gcs fleet api tests
	$(BIN)/mypy
	$(BIN)/pytest -q

lint: $(STAMP)
	$(BIN)/ruff check drona_gcs fleet api tests
	$(BIN)/mypy

bench: $(STAMP)
	$(BIN)/drona bench planner

bench-quick: $(STAMP)
	$(BIN)/drona bench planner --quick

demo: $(STAMP)
	$(BIN)/drona demo

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache

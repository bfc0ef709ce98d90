# Every target works on a fresh machine: it creates .venv and installs what it needs.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: test lint bench demo clean

$(STAMP): pyproject.toml
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

demo: $(STAMP)
	@echo "The demo fleet arrives with the service issue; meanwhile: $(BIN)/drona plan --help"

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache

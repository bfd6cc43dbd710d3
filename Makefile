# Two commands do all the set-up on a fresh machine:
#   make run    -> creates .venv, installs qmdf (CPU torch), runs the pipeline on the embedded teacup
#   make test   -> the same set-up, then the fast test tier (tests marked slow left out)
#   make test-all -> every test (what CI runs)
VENV ?= .venv
PY := $(VENV)/bin/python
ARGS ?=
PYTEST_ARGS ?=

.PHONY: setup run test test-all lint plugins clean-runs

setup:
	@bash scripts/setup.sh

run: setup
	$(PY) -m qmdf $(ARGS)

test: setup
	$(PY) -m pytest -m "not slow" $(PYTEST_ARGS)

test-all: setup
	$(PY) -m pytest $(PYTEST_ARGS)

lint: setup
	$(PY) -m ruff check qmdf tests
	$(PY) -m ruff format --check qmdf tests

plugins: setup
	$(PY) -m qmdf.plugins

clean-runs:
	rm -rf runs/20* runs/multirun runs/.cache

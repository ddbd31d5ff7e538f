# Two commands on a fresh machine: `make dataset` (the mini data set) and `make test`.
# Everything runs inside .venv, which the first target that needs it creates.

PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup assets dataset test bench clean-assets

setup: $(STAMP)

$(STAMP): requirements.txt pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	$(PY) -m pip install --quiet --no-deps -e .
	touch $(STAMP)

assets: setup
	$(PY) -m syneepose assets

DATA ?= data/mini

dataset: assets
	$(PY) -m syneepose render --preset mini --out $(DATA)
	$(PY) -m syneepose templates --preset mini --out $(DATA)

test: assets
	$(PY) -m pytest -x -q

bench: assets
	$(PY) benchmarks/assets_build.py
	$(PY) benchmarks/render.py

clean-assets:
	rm -rf assets

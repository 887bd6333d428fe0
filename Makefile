# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
# Torch is installed first as torch==2.13.0 (a local CPU wheel); the package's torch range is then
# already satisfied, so pip never pulls a CUDA build.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.agrivio-installed

.PHONY: demo test lint venv clean-cache

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/agrivio demo

# ruff (the rule set in pyproject.toml) and mypy on the libraries, then the tests
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy

test: lint
	$(PY) -m pytest -q

clean-cache:
	rm -rf data/cache

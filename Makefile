# Two entry points on a fresh machine with Python 3.11: `make demo` and `make test`.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
DATA_ROOT ?= ../shared/data
# Test processes (pytest-xdist); each test file runs whole in one of them, so its module fixtures are built once.
TEST_WORKERS ?= 2

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

.PHONY: install demo test bench
install: $(VENV)/.installed

# The real Shelf frames when the data folder is there, else the synthetic scene (the job says which).
demo: install
	$(if $(wildcard $(DATA_ROOT)/shelf),MVMOCAP_DATA_ROOT=$(DATA_ROOT)) $(PY) -m experiments.shelf_jcsat --out runs/demo

test: install
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder --data-root=$(DATA_ROOT)

bench: install
	$(PY) -m experiments.bench_geometry --json

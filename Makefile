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

.PHONY: install browser demo test bench
install: $(VENV)/.installed

# The real Shelf frames when the data folder is there, else the synthetic scene (the job says which).
demo: install
	$(if $(wildcard $(DATA_ROOT)/shelf),MVMOCAP_DATA_ROOT=$(DATA_ROOT)) $(PY) -m experiments.shelf_jcsat --out runs/demo

# The scene viewer's browser test (tests/test_scene_viewer.py) runs Debian's headless chromium: installed here when it
# is missing and apt can (as root, or with sudo that asks no password); otherwise that test is skipped (under
# CI=true it fails).
browser:
	@if [ ! -x /usr/bin/chromium ] && command -v apt-get >/dev/null; then \
	  if [ "$$(id -u)" -eq 0 ]; then sudo=""; elif sudo -n true 2>/dev/null; then sudo="sudo -n"; else exit 0; fi; \
	  $$sudo env DEBIAN_FRONTEND=noninteractive sh -c 'apt-get update -qq && apt-get install -y -qq chromium' \
	    || echo "chromium could not be installed: tests/test_scene_viewer.py's browser test will be skipped"; \
	fi

test: install browser
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder --data-root=$(DATA_ROOT)

bench: install
	$(PY) -m experiments.bench_geometry --json

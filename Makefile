# o3d_terrain: set-up, demo, tests, benchmarks.
#   make demo   - create .venv, install, run the demo pipelines on a generated scene -> out/
#   make test   - create .venv, install with test tools, run the test suite
#   make lint   - ruff check with the rules pinned in pyproject.toml ([tool.ruff.lint])
#   make bench  - install the peers (bench extra) and regenerate docs/benchmarks.md
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
STAMP  := $(VENV)/.installed
export NUMBA_CACHE_DIR ?= $(CURDIR)/.venv/numba_cache

.PHONY: demo test lint bench venv syslibs clean

# The open3d wheel loads the system library libusb-1.0 at import time.
syslibs:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then \
	  if [ "$$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "Installing libusb-1.0-0 (needed by the open3d wheel)..."; \
	    (apt-get install -y -qq libusb-1.0-0 >/dev/null 2>&1 || \
	     (apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq libusb-1.0-0 >/dev/null)) || \
	     { echo "error: could not install libusb-1.0-0; run: apt-get update && apt-get install -y libusb-1.0-0"; exit 1; }; \
	  else \
	    echo "error: the open3d wheel needs the system library libusb-1.0-0, which is missing."; \
	    echo "       Install it, then run make again:  sudo apt-get install -y libusb-1.0-0"; \
	    echo "       (Fedora: sudo dnf install libusb1;  macOS: brew install libusb)"; \
	    exit 1; \
	  fi; \
	fi

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip >/dev/null 2>&1 || true
	$(PIP) install -q -e '.[las,dev]'
	@touch $(STAMP)

venv: syslibs $(STAMP)

demo: venv
	$(VENV)/bin/o3d-terrain run pipelines/demo.yaml --output out/demo
	$(VENV)/bin/o3d-terrain run pipelines/stereo_terrain.yaml --output out/stereo_demo

test: venv
	$(PY) -m pytest -q

# ruff comes with the dev extra, which the venv installs for the tests
lint: venv
	$(VENV)/bin/ruff check

bench: venv
	$(PIP) install -q -e '.[las,dev,bench]'
	$(PY) benchmarks/run_all.py --write-docs

clean:
	rm -rf $(VENV) out build *.egg-info

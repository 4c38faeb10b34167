# The two commands of the README: `make demo` and `make test`. Each installs what is missing
# (Debian packages when root or with sudo, a .venv, the package with its extras) and runs.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(VENV)/bin/pip
DEMO_DIR ?= demo-out
# Persistent build dir (pyproject: build-dir) => incremental rebuilds.
STAMP  := $(VENV)/.ibrtools-installed

.PHONY: setup system-deps build test typecheck demo bench clean check-asan check-tsan

setup: system-deps $(STAMP)

system-deps:
	@PYTHON=$(PYTHON) tools/install-system-deps.sh

$(VENV)/bin/python:
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip

# Reinstall when the build description or sources change; the CMake build dir persists.
$(STAMP): $(VENV)/bin/python pyproject.toml CMakeLists.txt $(shell find cpp python cli -name '*.cpp' -o -name '*.h' -o -name '*.py' 2>/dev/null)
	flock $(VENV)/.install-lock sh -c "$(PIP) install -q scikit-build-core pybind11 ninja cmake && \
	  $(PIP) install -q --no-build-isolation -e '.[test,bench,colmap,flip]' && touch $(STAMP)"


build: setup

test: setup typecheck
	$(PY) -m pytest -q -n 2 tests

# mypy --strict on the typed public API, the _core stub and tests/typing_usage.py (pyproject
# [tool.mypy]; docs/api.md); ~10 s from a cold cache. `make test` runs it first.
typecheck: setup
	$(PY) -m mypy

# Sanitizers (docs/robustness.md): the extension built with ASan+UBSan (or TSan) in build/asan
# (build/tsan), run against python/ibrtools from a staging dir; the normal .venv install is not
# touched: the whole suite under ASan, the multithreaded kernels' tests (pytest marker `kernel`)
# under TSan.
check-asan: setup
	tools/sanitize.sh asan

check-tsan: setup
	tools/sanitize.sh tsan -n 2 -m kernel

demo: setup
	$(VENV)/bin/ibr-preprocess synth:objects -o $(DEMO_DIR)/scene --views 12 --size 480x360
	$(VENV)/bin/ibr-render $(DEMO_DIR)/scene --method dibr --holdout v003 v009 --report-html -o $(DEMO_DIR)/render
	@echo "demo: images and report.json in $(DEMO_DIR)/render; open $(DEMO_DIR)/render/report.html in a browser"

bench: setup
	$(PY) benchmarks/bench_raycast.py --write-docs
	$(PY) benchmarks/bench_metrics.py --write
	$(PY) benchmarks/bench_dibr.py --write-docs

clean:
	rm -rf build $(VENV) $(DEMO_DIR)

# Two commands do everything on a fresh machine:
#   make demo   renders the default demo film (embedded data, no downloads)
#   make test   runs the whole test suite (Python 3.13 + bpy, the core on Python 3.11 + numpy 1.26, and
#               the extension zip installed into Pythons holding only what Blender 5.2 and 5.0 ship)
PY313 ?= $(shell command -v python3.13 || pyenv which python3.13 2>/dev/null || echo python3)
PY311 ?= $(shell command -v python3.11 || pyenv which python3.11 2>/dev/null || echo python3)
VENV := .venv
VENV311 := .venv311
# Blender-only Pythons: nothing but the bpy wheel and its dependencies (see tests/extension).
BPY52 := build/venv-bpy52
BPY50 := build/venv-bpy50
PYTEST_ARGS ?=

.PHONY: demo test test-main test-core311 test-extension test-slurm test-bench bench extension clean

$(VENV)/.stamp: requirements.txt pyproject.toml
	$(PY313) -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip
	$(VENV)/bin/pip install -q -r requirements.txt
	$(VENV)/bin/pip install -q --no-deps -e .
	touch $@

$(VENV311)/.stamp: requirements-core311.txt pyproject.toml
	$(PY311) -m venv $(VENV311)
	$(VENV311)/bin/pip install -q --upgrade pip
	$(VENV311)/bin/pip install -q -r requirements-core311.txt
	$(VENV311)/bin/pip install -q --no-deps -e .
	touch $@

$(BPY52)/.stamp: requirements-blender.txt
	rm -rf $(BPY52)
	$(PY313) -m venv $(BPY52)
	$(BPY52)/bin/pip install -q -r requirements-blender.txt
	touch $@

$(BPY50)/.stamp: requirements-blender311.txt
	rm -rf $(BPY50)
	$(PY311) -m venv $(BPY50)
	$(BPY50)/bin/pip install -q -r requirements-blender311.txt
	touch $@

# The compiled kernels (native/) as a wheel, installed into both test Pythons; where it is not
# installed (platforms it is not built for) their NumPy twins run.
NATIVE_SRC := $(wildcard native/src/*.c native/src/*.h) native/nephele_native/__init__.py native/build.py
build/native/.stamp: $(NATIVE_SRC)
	rm -rf build/native/dist
	$(PY313) native/build.py --wheel build/native/dist
	touch $@

$(VENV)/.native: $(VENV)/.stamp build/native/.stamp
	$(VENV)/bin/pip install -q --force-reinstall --no-deps build/native/dist/*.whl
	touch $@

$(VENV311)/.native: $(VENV311)/.stamp build/native/.stamp
	$(VENV311)/bin/pip install -q --force-reinstall --no-deps build/native/dist/*.whl
	touch $@

demo: $(VENV)/.stamp $(VENV)/.native
	$(VENV)/bin/nephele film --out out/demo

test: test-main test-core311 test-extension test-slurm test-bench

test-main: $(VENV)/.stamp $(VENV)/.native
	$(VENV)/bin/python -m pytest --ignore=tests/extension --ignore=tests/farm/slurm $(PYTEST_ARGS)

# Core only (no bpy, no farm): the numpy 1.26 / Python 3.11 that Blender 4.2-5.0 ship. The slow cases
# (thick scattering slabs, big blobby grids) run once, in test-main, to keep CI within its budget.
test-core311: $(VENV311)/.stamp $(VENV311)/.native
	$(VENV311)/bin/python -m pytest -m "not bpy and not slow" --ignore=tests/farm --ignore=tests/addon --ignore=tests/extension $(PYTEST_ARGS)

# Build the linux-x64 zips (wheels cached in build/wheels), install each into its Blender-only
# Python through Blender's extension API and drive the whole sidebar workflow there.
test-extension: $(VENV)/.stamp $(VENV)/.native $(BPY52)/.stamp $(BPY50)/.stamp
	NEPHELE_REQUIRE_BLENDER_PYTHONS=1 NEPHELE_BLENDER_PYTHONS=$(CURDIR)/$(BPY52)/bin/python:$(CURDIR)/$(BPY50)/bin/python \
	  $(VENV)/bin/python -m pytest tests/extension $(PYTEST_ARGS)

# The farm on a real single-node Slurm cluster (slurmctld + slurmd + munged started by the tests;
# slurm-wlm and munge are installed with apt-get when missing, which needs root).
test-slurm: $(VENV)/.stamp
	$(VENV)/bin/python -m pytest tests/farm/slurm -m "not slow" $(PYTEST_ARGS)

# Every benchmark's --quick mode as a smoke test, so none can rot; a quick run prints its table and
# leaves docs/benchmarks.md alone (benchmarks/report.py).
test-bench: $(VENV)/.stamp $(VENV)/.native
	@mkdir -p build
	@for b in benchmarks/bench_*.py; do \
	  echo "$$b --quick"; \
	  $(VENV)/bin/python $$b --quick > build/bench-quick.log 2>&1 || { tail -40 build/bench-quick.log; exit 1; }; \
	done

bench: $(VENV)/.stamp $(VENV)/.native
	for b in benchmarks/bench_*.py; do $(VENV)/bin/python $$b || exit 1; done

extension: $(VENV)/.stamp build/native/.stamp
	$(VENV)/bin/nephele build-extension --out dist

clean:
	rm -rf $(VENV) $(VENV311) dist build out

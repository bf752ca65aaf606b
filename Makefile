# Two commands do everything on a fresh machine:
#   make demo   renders the default demo film (embedded data, no downloads)
#   make test   runs the whole test suite (Python 3.13 + bpy, and the core on Python 3.11 + numpy 1.26)
PY313 ?= $(shell command -v python3.13 || pyenv which python3.13 2>/dev/null || echo python3)
PY311 ?= $(shell command -v python3.11 || pyenv which python3.11 2>/dev/null || echo python3)
VENV := .venv
VENV311 := .venv311
PYTEST_ARGS ?=

.PHONY: demo test test-main test-core311 bench extension clean

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

demo: $(VENV)/.stamp
	$(VENV)/bin/nephele demo --out out/demo

test: test-main test-core311

test-main: $(VENV)/.stamp
	$(VENV)/bin/python -m pytest $(PYTEST_ARGS)

# Core only (no bpy, no farm): the numpy 1.26 / Python 3.11 that Blender 4.2-5.0 ship.
test-core311: $(VENV311)/.stamp
	$(VENV311)/bin/python -m pytest -m "not bpy" --ignore=tests/farm --ignore=tests/blender $(PYTEST_ARGS)

bench: $(VENV)/.stamp
	for b in benchmarks/bench_*.py; do $(VENV)/bin/python $$b || exit 1; done

extension: $(VENV)/.stamp
	$(VENV)/bin/nephele build-extension --out dist

clean:
	rm -rf $(VENV) $(VENV311) dist build out

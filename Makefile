# Two commands do everything on a fresh machine:
#   make demo   renders the demo film (embedded data, no downloads)
#   make test   the quick tier: core, add-on, farm and CLI on small grids and renders, at most
#               10 minutes on a fresh 2-core clone, its venv included
# and one for CI (.ci/run):
#   make test-full  everything: the slow hard cases, Python 3.11 + numpy 1.26, the zips in
#               Blender-only Pythons, real Slurm, the benchmarks' smoke runs (docs/testing.md)
# Every test target is strict (NEPHELE_STRICT=1): a test that would skip for something this
# machine should have fails instead, saying what is missing (tests/conftest.py).
PY313 ?= $(shell command -v python3.13 || pyenv which python3.13 2>/dev/null || echo python3)
PY311 ?= $(shell command -v python3.11 || pyenv which python3.11 2>/dev/null || echo python3)
VENV := .venv
VENV311 := .venv311
# Blender-only Pythons: nothing but the bpy wheel and its dependencies (see tests/extension).
BPY52 := build/venv-bpy52
BPY50 := build/venv-bpy50
PYTEST_ARGS ?=
# Test processes (pytest-xdist), one per core; a test file stays in one process (its module fixtures
# are built once). JOBS=0 runs in this process only.
JOBS ?= $(shell nproc 2>/dev/null || echo 2)
XDIST = -n $(JOBS) --dist loadfile
STRICT := NEPHELE_STRICT=1
# Each tier runs under tests/budget.py: its time against its budget in seconds (it fails past 1.5
# times that) and its ten slowest tests.
TIERS := build/tiers
BUDGET = $(VENV)/bin/python tests/budget.py

# $(call install,VENV,REQUIREMENTS): pip byte-compiles what it installs one file at a time (a minute
# of a fresh venv's two), so the files are compiled afterwards on every core (half that).  Python must
# not be left to compile them at import: under PYTHONDONTWRITEBYTECODE it would, in every process.
# (Warnings about the packages' own sources are theirs; pip does not show them either.)
define install
	$(1)/bin/pip install -q --no-compile -r $(2)
	$(1)/bin/python -W ignore::SyntaxWarning -m compileall -q -j 0 $$($(1)/bin/python -c 'import sysconfig; print(sysconfig.get_path("purelib"))')
endef

.PHONY: demo lint test test-full test-main test-core311 test-extension test-slurm test-bench bench extension clean

$(VENV)/.stamp: requirements.txt pyproject.toml
	$(PY313) -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip
	$(call install,$(VENV),requirements.txt)
	$(VENV)/bin/pip install -q --no-deps -e .
	touch $@

$(VENV311)/.stamp: requirements-core311.txt pyproject.toml
	$(PY311) -m venv $(VENV311)
	$(VENV311)/bin/pip install -q --upgrade pip
	$(call install,$(VENV311),requirements-core311.txt)
	$(VENV311)/bin/pip install -q --no-deps -e .
	touch $@

$(BPY52)/.stamp: requirements-blender.txt
	rm -rf $(BPY52)
	$(PY313) -m venv $(BPY52)
	$(call install,$(BPY52),requirements-blender.txt)
	touch $@

$(BPY50)/.stamp: requirements-blender311.txt
	rm -rf $(BPY50)
	$(PY311) -m venv $(BPY50)
	$(call install,$(BPY50),requirements-blender311.txt)
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

# Real GRIB products (pygrib's and cfgrib's sample files, fetched once from PyPI and checked by sha256;
# tests/data/fetch_grib_samples.py).
GRIB_SAMPLES := build/grib-samples/.stamp
$(GRIB_SAMPLES): tests/data/fetch_grib_samples.py $(VENV)/.stamp
	$(VENV)/bin/python tests/data/fetch_grib_samples.py
	touch $@

demo: $(VENV)/.stamp $(VENV)/.native
	$(VENV)/bin/nephele film --out out/demo

# The quick tier: the linter, then everything but the slow hard cases, the extension zips and Slurm.
# (Its environment is made two jobs at a time: the kernels compile while pip installs; in a fresh
# clone 109 s instead of 132.)
test:
	@$(MAKE) --no-print-directory -j 2 $(VENV)/.native $(GRIB_SAMPLES)
	@mkdir -p $(TIERS)
	$(VENV)/bin/ruff check .
	$(STRICT) $(BUDGET) quick 480 --junit $(TIERS)/quick.xml -- $(VENV)/bin/python -m pytest $(XDIST) -m "not slow" \
	  --ignore=tests/extension --ignore=tests/farm/slurm --junitxml=$(TIERS)/quick.xml $(PYTEST_ARGS)

# pyflakes, pycodestyle, isort and bugbear with the configuration in pyproject.toml.
lint: $(VENV)/.stamp
	$(VENV)/bin/ruff check .

# The full suite (CI): each tier once, then their times.
test-full:
	@mkdir -p $(TIERS) && rm -f $(TIERS)/times.tsv
	$(MAKE) lint test-main test-core311 test-extension test-slurm test-bench
	@$(VENV)/bin/python tests/budget.py --summary

# Everything on Python 3.13 + bpy, the slow hard cases too (the zips and Slurm have tiers of their own).
test-main: $(VENV)/.stamp $(VENV)/.native $(GRIB_SAMPLES)
	@mkdir -p $(TIERS)
	$(STRICT) $(BUDGET) main 900 --junit $(TIERS)/main.xml -- $(VENV)/bin/python -m pytest $(XDIST) \
	  --ignore=tests/extension --ignore=tests/farm/slurm --junitxml=$(TIERS)/main.xml $(PYTEST_ARGS)

# The core (no bpy, no farm) on the numpy 1.26 / Python 3.11 that Blender 4.2-5.0 ship. This tier has
# no bpy by design (NEPHELE_OPTIONAL); the slow hard cases run once, in test-main.
test-core311: $(VENV)/.stamp $(VENV311)/.stamp $(VENV311)/.native $(GRIB_SAMPLES)
	@mkdir -p $(TIERS)
	$(STRICT) NEPHELE_OPTIONAL=bpy $(BUDGET) core311 420 --junit $(TIERS)/core311.xml -- \
	  $(VENV311)/bin/python -m pytest $(XDIST) -m "not bpy and not slow" --ignore=tests/farm --ignore=tests/addon \
	  --ignore=tests/extension --junitxml=$(TIERS)/core311.xml $(PYTEST_ARGS)

# Build the linux-x64 zips (wheels cached in build/wheels), install each into its Blender-only
# Python through Blender's extension API and drive the whole sidebar workflow there.
test-extension: $(VENV)/.stamp $(VENV)/.native $(BPY52)/.stamp $(BPY50)/.stamp
	@mkdir -p $(TIERS)
	$(STRICT) NEPHELE_REQUIRE_BLENDER_PYTHONS=1 \
	  NEPHELE_BLENDER_PYTHONS=$(CURDIR)/$(BPY52)/bin/python:$(CURDIR)/$(BPY50)/bin/python \
	  $(BUDGET) extension 240 --junit $(TIERS)/extension.xml -- $(VENV)/bin/python -m pytest tests/extension \
	  --junitxml=$(TIERS)/extension.xml $(PYTEST_ARGS)

# The farm on a real single-node Slurm cluster (slurmctld + slurmd + munged started by the tests;
# slurm-wlm and munge are installed with apt-get when missing, which needs root), the slow
# wall-time hand-over included.
test-slurm: $(VENV)/.stamp
	@mkdir -p $(TIERS)
	$(STRICT) $(BUDGET) slurm 180 --junit $(TIERS)/slurm.xml -- $(VENV)/bin/python -m pytest tests/farm/slurm \
	  --junitxml=$(TIERS)/slurm.xml $(PYTEST_ARGS)

# Every benchmark's --quick mode as a smoke test, JOBS at a time, so none can rot; a quick run prints its table and
# leaves docs/benchmarks.md alone (benchmarks/report.py).  In reverse order: the slowest (volume, splats, scatter)
# start first instead of leaving one process alone at the end.
test-bench: $(VENV)/.stamp $(VENV)/.native
	@mkdir -p $(TIERS)
	$(BUDGET) bench 180 -- sh -c 'ls benchmarks/bench_*.py | sort -r | xargs -P $(or $(filter-out 0,$(JOBS)),1) -n 1 \
	  tests/bench_quick.sh $(VENV)/bin/python'

bench: $(VENV)/.stamp $(VENV)/.native
	for b in benchmarks/bench_*.py; do $(VENV)/bin/python $$b || exit 1; done

extension: $(VENV)/.stamp build/native/.stamp
	$(VENV)/bin/nephele build-extension --out dist

clean:
	rm -rf $(VENV) $(VENV311) dist build out

# The documentation site (docs/, Sphinx + PyData theme + numpydoc + MyST): offline, warnings are errors.
.PHONY: docs
docs: $(VENV)/.stamp
	$(VENV)/bin/python -m sphinx -W --keep-going -b html -q docs build/docs/html
	@echo "docs: build/docs/html/index.html"

# Long fuzz runs of every reader (NetCDF, GRIB, Zarr, GrADS, ETOPO, PQR, .vtu), outside CI: N mutated and
# truncated real files, J worker processes; findings (any error but DataError, > 10 CPU s, > 2 GiB, a
# crash) are saved under build/fuzz/ with the ops that made them.  The quick and full tiers run tests/fuzz.
N ?= 100000
J ?= 2
.PHONY: fuzz
fuzz: $(VENV)/.stamp
	nice -n 10 $(VENV)/bin/python tests/fuzz/run.py --cases $(N) --jobs $(J) --out build/fuzz

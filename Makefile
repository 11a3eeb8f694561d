# make demo   -- build .venv-demo (what the demo needs, no test tools) and run the demo on the
#                built-in mock rig
# make test   -- build .venv from nothing and run the linters and the whole test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# the demo's own environment: tmscal's dependencies and nothing else (ur_rtde is one of them
# where PyPI has a wheel of it; elsewhere the demo runs on the mock DENSO). The full one adds
# the test tools, the third-party clients and simulators the tests run against, matplotlib
# and ur_rtde. benchmarks/install_size.py reads these two lines and measures both.
DEMO_EXTRAS :=
TEST_EXTRAS := test,plot,ur
DEMO_VENV   := .venv-demo
DEMO_STAMP  := $(DEMO_VENV)/.installed

.PHONY: demo test lint bench clean venv

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[$(TEST_EXTRAS)]'
	touch $(STAMP)
	@echo 'environment ready in $(VENV); put it on your PATH with:  . $(BIN)/activate'

$(DEMO_STAMP): pyproject.toml
	$(PYTHON) -m venv $(DEMO_VENV)
	$(DEMO_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(DEMO_VENV)/bin/python -m pip install --quiet -e '.$(if $(DEMO_EXTRAS),[$(DEMO_EXTRAS)])'
	touch $(DEMO_STAMP)
	@echo 'demo environment ready in $(DEMO_VENV) (make test builds the full $(VENV))'

venv: $(STAMP)

demo: $(DEMO_STAMP)
	$(DEMO_VENV)/bin/tmscal demo

# ruff, the layers of docs/architecture.md ([tool.importlinter] in pyproject.toml), then the
# type checker ([tool.mypy]; a rerun reads its cache, .mypy_cache)
lint: $(STAMP)
	$(BIN)/ruff check tmscal tests benchmarks
	$(BIN)/lint-imports
	$(BIN)/mypy

# the suite in parallel (pytest-xdist: one worker per core, a test file whole on one worker;
# PYTEST_WORKERS=0 runs it in this process), one BLAS thread per process (OpenBLAS's busy-waiting
# threads starve the mock servers on a small machine); PYTEST_ARGS adds options, e.g.
# `make test PYTEST_ARGS="-m 'not slow'"` or PYTEST_ARGS=--durations=0
PYTEST_WORKERS ?= auto
PYTEST_ARGS    ?=
TEST_ENV := OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1

test: $(STAMP) lint
	$(TEST_ENV) $(BIN)/python -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile $(PYTEST_ARGS)

# every benchmark script (figures for the README; well over 5 minutes), then the check that
# docs/benchmarks.md's (and README's, docs') marked figures agree with what they printed (benchmarks/check_figures.py)
bench: $(STAMP)
	$(BIN)/python benchmarks/accuracy.py
	$(BIN)/python benchmarks/speed.py
	$(BIN)/python benchmarks/methods.py
	$(BIN)/python benchmarks/ml_bound.py --n 20
	$(BIN)/python benchmarks/ml_bound.py --n 250 --sessions 60
	$(BIN)/python benchmarks/ml_bound.py --n 7
	$(BIN)/python benchmarks/tracker.py
	$(BIN)/python benchmarks/acquisition.py --robot ur
	$(BIN)/python benchmarks/acquisition.py --robot denso
	$(BIN)/python benchmarks/time_to_calibrate.py
	$(BIN)/python benchmarks/selfcal.py
	$(BIN)/python benchmarks/selfcal_rig.py
	$(BIN)/python benchmarks/franka_demo.py
	$(BIN)/python benchmarks/kinematics.py
	$(BIN)/python benchmarks/kinematics.py --first-seed 4 --skip-sim --ladder 15,20,40
	$(BIN)/python benchmarks/kinematics.py --noise-scale 2 --skip-sim --ladder 40
	$(BIN)/python benchmarks/kinematics_ratio.py
	$(BIN)/python benchmarks/kinematics_cost.py
	$(BIN)/python benchmarks/ml_selection.py
	$(BIN)/python benchmarks/adequacy.py
	$(BIN)/python benchmarks/adaptive_coverage.py --runs 40 --table-rigs 5
	$(BIN)/python benchmarks/install_size.py
	$(BIN)/python benchmarks/arm_files.py
	$(BIN)/python benchmarks/check_figures.py

clean:
	rm -rf $(VENV) $(DEMO_VENV) build *.egg-info

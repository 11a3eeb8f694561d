# make demo   -- build .venv from nothing and run the demo on the built-in mock rig
# make test   -- build .venv from nothing and run the linters and the whole test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test lint bench clean venv

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,plot,ur]'
	touch $(STAMP)
	@echo 'environment ready in $(VENV); put it on your PATH with:  . $(BIN)/activate'

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/tmscal demo

# ruff, then the layers of docs/architecture.md ([tool.importlinter] in pyproject.toml)
lint: $(STAMP)
	$(BIN)/ruff check tmscal tests benchmarks
	$(BIN)/lint-imports

test: $(STAMP) lint
	$(BIN)/python -m pytest -q

# every benchmark script (figures for the README; ~5 minutes)
bench: $(STAMP)
	$(BIN)/python benchmarks/accuracy.py
	$(BIN)/python benchmarks/speed.py
	$(BIN)/python benchmarks/methods.py
	$(BIN)/python benchmarks/ml_bound.py --n 20
	$(BIN)/python benchmarks/ml_bound.py --n 250 --sessions 60
	$(BIN)/python benchmarks/tracker.py
	$(BIN)/python benchmarks/acquisition.py --robot ur
	$(BIN)/python benchmarks/acquisition.py --robot denso
	$(BIN)/python benchmarks/time_to_calibrate.py
	$(BIN)/python benchmarks/selfcal.py
	$(BIN)/python benchmarks/kinematics.py

clean:
	rm -rf $(VENV) build *.egg-info

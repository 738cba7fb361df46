# One venv in .venv (and .venv-serve for the serve-only suite); every target installs what it needs, so each
# works on a fresh machine.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
SERVE_VENV := .venv-serve

.PHONY: setup setup-serve test test-serve test-fast lint demo bench

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

# torch is pinned to the local CPU wheel (torch==2.13.0); a looser pin would pull the CUDA build.
setup: $(BIN)/python
	$(BIN)/pip install --quiet -e '.[dev]'

setup-serve: $(BIN)/python
	$(BIN)/pip install --quiet -e '.[serve]'

# The main job on the shipped default model: disparity of the bundled Cones pair, then its accuracy.
demo: setup-serve
	mkdir -p out
	$(BIN)/adsm predict ../shared/data/middlebury2003-cones/left.png ../shared/data/middlebury2003-cones/right.png \
		-o out/cones-disparity.png --max-disparity 64 --timings
	$(BIN)/adsm predict ../shared/data/middlebury2003-cones/left.png ../shared/data/middlebury2003-cones/right.png \
		-o out/cones-disparity-color.png --format color --max-disparity 64
	@echo "wrote out/cones-disparity.png (KITTI uint16) and out/cones-disparity-color.png"

# ruff, then the type checker on service/ (pyproject.toml [tool.mypy]), then the whole suite, then the
# serve-only suite.
test: setup
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/pytest -q
	$(MAKE) --no-print-directory test-serve

$(SERVE_VENV)/bin/python:
	$(PYTHON) -m venv $(SERVE_VENV)
	$(SERVE_VENV)/bin/pip install --quiet --upgrade pip

# The serve-only suite: the runtime as the service image installs it (no torch, scikit-image or SciPy),
# with the video extra and the test tools, in a venv of its own; every test not marked torch (train extra)
# or slow (the whole suite above runs those).
test-serve: $(SERVE_VENV)/bin/python
	$(SERVE_VENV)/bin/pip install --quiet -e '.[serve,video,test]'
	$(SERVE_VENV)/bin/pytest -q -m "not torch and not slow"

test-fast: setup
	$(BIN)/pytest -q -m "not slow"

lint: setup
	$(BIN)/ruff check .
	$(BIN)/mypy

bench: setup
	$(BIN)/python -m bench

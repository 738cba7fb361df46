# One venv in .venv; every target installs what it needs, so each works on a fresh machine.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin

.PHONY: setup setup-serve test test-fast lint demo bench

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

# ruff, then the type checker on service/ (pyproject.toml [tool.mypy]), then the whole suite.
test: setup
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/pytest -q

test-fast: setup
	$(BIN)/pytest -q -m "not slow"

lint: setup
	$(BIN)/ruff check .
	$(BIN)/mypy

bench: setup
	$(BIN)/python -m bench

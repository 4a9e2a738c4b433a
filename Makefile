# Two commands do everything on a fresh machine (see README):
#   make demo   set up, `dvc repro` the default small profile, then the main job on real videos
#   make test   set up, then the test suite (what CI runs)
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
REAL ?= ../shared/data/real/video
export PATH := $(abspath $(VENV))/bin:$(PATH)
export MUJOCO_GL ?= egl
export HF_HUB_OFFLINE := 1
export TRANSFORMERS_OFFLINE := 1
export TOKENIZERS_PARALLELISM := false

.PHONY: setup demo repro realvideo test clean

setup: $(VENV)/.installed

# System GL libraries for offscreen rendering (EGL through Mesa llvmpipe), then the venv.
$(VENV)/.installed: pyproject.toml scripts/setup_system.sh
	bash scripts/setup_system.sh
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	# xgrammar (constrained decoding) without its triton dependency: ~1 GB of GPU compiler, unused on CPU
	$(PY) -m pip install --quiet --no-deps xgrammar==0.2.8
	$(PY) -c "import pipeline, mujoco, dm_control.mjcf, torch, transformers, xgrammar; print('setup ok: mujoco', mujoco.__version__, 'torch', torch.__version__)"
	touch $@

repro: setup
	@test -d .dvc || dvc init -q
	dvc config core.analytics false
	dvc repro

realvideo: setup
	bash scripts/realvideo.sh

demo: repro realvideo
	@cat reports/table.md

# pytest and hypothesis are the `test` extra (pyproject.toml), not runtime dependencies
$(VENV)/.test-installed: $(VENV)/.installed
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

test: setup $(VENV)/.test-installed
	$(PY) -m pytest -q

clean:
	rm -rf data outputs .dvc/tmp

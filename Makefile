# boxpose: every entry point. `make setup` is idempotent and every other target runs it first.
SHELL := /bin/bash
.DEFAULT_GOAL := help

PYTHON_BOOTSTRAP ?= python3
VENV := .venv
PY := $(VENV)/bin/python
BOXPOSE := target/release/boxpose
RECIPE ?= clutter
DATASET ?= datasets/generated/$(RECIPE)
SHARDS ?= 1
JOBS ?= 2
# MuJoCo: mujoco-rs links against the libmujoco inside the pinned `mujoco` wheel (DESIGN.md).
MUJOCO_LINK_DIR := $(CURDIR)/build/mujoco
export MUJOCO_DYNAMIC_LINK_DIR := $(MUJOCO_LINK_DIR)
export LD_LIBRARY_PATH := $(MUJOCO_LINK_DIR):$(LD_LIBRARY_PATH)
export PATH := $(CURDIR)/$(VENV)/bin:$(PATH)

.PHONY: help setup rust schema scenes demo test bench clean

help: ## List the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-8s %s\n", $$1, $$2}'

$(VENV)/.stamp: requirements.txt
	@$(PYTHON_BOOTSTRAP) -c 'import sys; assert sys.version_info[:2] == (3, 11), "boxpose needs Python 3.11 (bpy 5.0.1); found " + sys.version' 
	test -x $(PY) || $(PYTHON_BOOTSTRAP) -m venv $(VENV)
	$(PY) -m pip install --quiet -r requirements.txt
	# boxpose_io (python/) and the stage packages (drake_scenes, blender_scripts) import from this tree.
	printf '%s\n' $(CURDIR)/python $(CURDIR) > $$($(PY) -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/boxpose.pth
	touch $@

$(MUJOCO_LINK_DIR)/.stamp: $(VENV)/.stamp
	mkdir -p $(MUJOCO_LINK_DIR)
	lib=$$($(PY) -c 'import mujoco, pathlib; print(next(pathlib.Path(mujoco.__file__).parent.glob("libmujoco.so.*")))') && \
	  ln -sf "$$lib" $(MUJOCO_LINK_DIR)/libmujoco.so && ln -sf "$$lib" $(MUJOCO_LINK_DIR)/$$(basename "$$lib")
	touch $@

rust: $(MUJOCO_LINK_DIR)/.stamp ## Build the Rust workspace (release) and install the `boxpose` Python module into .venv
	cargo build --release --workspace
	# maturin builds into its own target dir: it sets PYO3_BUILD_EXTENSION_MODULE, which would
	# otherwise invalidate the workspace's pyo3 build on every alternation.
	VIRTUAL_ENV=$(CURDIR)/$(VENV) CARGO_TARGET_DIR=target/maturin $(VENV)/bin/maturin develop --release --quiet -m rust/python/Cargo.toml

setup: $(VENV)/.stamp $(MUJOCO_LINK_DIR)/.stamp rust ## Create .venv with pinned deps, prepare MuJoCo linking, build Rust

schema: ## Regenerate python/boxpose_io/schema.json and the column reference in docs/dataset.md from the Rust schema
	cargo run --quiet -p boxpose-cli -- schema > python/boxpose_io/schema.json
	mkdir -p build && cargo run --quiet -p boxpose-cli -- schema --markdown > build/columns.md
	$(PY) scripts/splice_doc.py docs/dataset.md build/columns.md

test: setup ## Run every test: Rust unit/property tests, then the Python/Rust end-to-end tests
	cargo test --release --workspace
	$(PY) -m pytest -q tests

clean: ## Remove build outputs and generated datasets (keeps .venv)
	cargo clean
	rm -rf build datasets/generated results

# boxpose: every entry point. `make setup` is idempotent and every other target runs it first.
SHELL := /bin/bash
.DEFAULT_GOAL := help

PYTHON_BOOTSTRAP ?= python3
VENV := .venv
PY := $(VENV)/bin/python
BOXPOSE := target/release/boxpose
RECIPE ?= clutter
DATASET ?= datasets/generated/$(basename $(notdir $(RECIPE)))
SHARDS ?= 1
JOBS ?= 2
# MuJoCo: mujoco-rs links against the libmujoco inside the pinned `mujoco` wheel
# (docs/design.md, "Toolchain facts").
MUJOCO_LINK_DIR := $(CURDIR)/build/mujoco
export MUJOCO_DYNAMIC_LINK_DIR := $(MUJOCO_LINK_DIR)
export LD_LIBRARY_PATH := $(MUJOCO_LINK_DIR):$(LD_LIBRARY_PATH)
export PATH := $(CURDIR)/$(VENV)/bin:$(PATH)

.PHONY: help setup rust schema scenes train search demo test bench bench-geometry bench-settle bench-render bench-scenes bench-learn bench-backends bench-render-quality bench-render-accuracy bench-search bench-scale-out lint fuzz test-faults clean

help: ## List the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-15s %s\n", $$1, $$2}'

$(VENV)/.stamp: requirements.txt
	@$(PYTHON_BOOTSTRAP) -c 'import sys; assert sys.version_info[:2] == (3, 11), "boxpose needs Python 3.11 (bpy 5.0.1); found " + sys.version' 
	test -x $(PY) || $(PYTHON_BOOTSTRAP) -m venv $(VENV)
	$(PY) -m pip install --quiet -r requirements.txt
	# What earlier layouts installed: a .pth, then a `boxpose-stages` distribution. The packages
	# now come with the `boxpose` distribution (pyproject.toml), installed by `make rust`.
	rm -f $$($(PY) -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/boxpose.pth
	$(PY) -m pip uninstall --quiet --yes boxpose-stages 2>/dev/null || true
	touch $@

$(MUJOCO_LINK_DIR)/.stamp: $(VENV)/.stamp
	mkdir -p $(MUJOCO_LINK_DIR)
	lib=$$($(PY) -c 'import mujoco, pathlib; print(next(pathlib.Path(mujoco.__file__).parent.glob("libmujoco.so.*")))') && \
	  ln -sf "$$lib" $(MUJOCO_LINK_DIR)/libmujoco.so && ln -sf "$$lib" $(MUJOCO_LINK_DIR)/$$(basename "$$lib")
	touch $@

rust: $(MUJOCO_LINK_DIR)/.stamp ## Build the Rust workspace (release) and install the `boxpose` Python distribution into .venv
	# Libraries and binaries only: the tests, benchmarks and their dev-dependencies (criterion,
	# proptest) build with `make test`. rust/workspace-hack gives both builds the same features, so
	# `cargo test` adds to this build instead of recompiling it (tests/test_build_features.py).
	cargo build --release --workspace
	# The `boxpose` distribution (pyproject.toml): the compiled module into python/boxpose/ and
	# every package of python/ importable from this tree. maturin builds into its own target dir:
	# it sets PYO3_BUILD_EXTENSION_MODULE, which would otherwise invalidate the workspace's pyo3
	# build on every alternation.
	VIRTUAL_ENV=$(CURDIR)/$(VENV) CARGO_TARGET_DIR=target/maturin $(VENV)/bin/maturin develop --release --quiet

setup: $(VENV)/.stamp $(MUJOCO_LINK_DIR)/.stamp rust ## Create .venv with pinned deps, prepare MuJoCo linking, build Rust

schema: ## Regenerate python/boxpose_io/schema.json, the column reference in docs/dataset.md and docs/recipes.md from the Rust schema
	# Each file is written beside its target and renamed: a killed `make schema` leaves no half file.
	cargo run --release --quiet -p boxpose-cli -- schema > python/boxpose_io/schema.json.tmp
	mv python/boxpose_io/schema.json.tmp python/boxpose_io/schema.json
	mkdir -p build && cargo run --release --quiet -p boxpose-cli -- schema --markdown > build/columns.md
	$(PY) scripts/splice_doc.py docs/dataset.md build/columns.md
	cargo run --release --quiet -p boxpose-cli -- schema --recipes-markdown > docs/recipes.md.tmp
	mv docs/recipes.md.tmp docs/recipes.md

scenes: setup ## Generate a dataset: Drake scenes then Blender renders, shard by shard, resumable (RECIPE=clutter SHARDS=1)
	$(PY) scripts/make_scenes.py --recipe $(RECIPE) --dataset $(DATASET) --num-shards $(SHARDS) --boxpose $(BOXPOSE)

MODEL ?= models/keypoint-slim
SEGMENTER ?= models/segmenter-slim
# The training backend (docs/learning.md, "Backends"): flex (default, the `make setup` build), tch
# (libtorch 2.9 on the CPU, assembled from PyPI wheels by scripts/setup_libtorch_cpu.sh, ≈ 900 MB
# download, ≈ 490 MB on disk), wgpu (any Vulkan/Metal GPU), cuda (NVIDIA). Each but flex is a
# second build of the CLI, in target/BACKEND, made only here: `make test` never needs it.
BACKEND ?= flex
LIBTORCH_DIR := $(CURDIR)/build/libtorch-cpu
ifeq ($(BACKEND),flex)
TRAIN_BOXPOSE := $(BOXPOSE)
else
TRAIN_BOXPOSE := target/$(BACKEND)/release/boxpose
endif

target/tch/release/boxpose: $(MUJOCO_LINK_DIR)/.stamp FORCE
	scripts/setup_libtorch_cpu.sh $(LIBTORCH_DIR)
	LIBTORCH=$(LIBTORCH_DIR) RUSTFLAGS="-C link-arg=-Wl,-rpath,$(LIBTORCH_DIR)/lib" CARGO_TARGET_DIR=target/tch \
	  cargo build --release -p boxpose-cli --features boxpose-learn/tch

target/wgpu/release/boxpose target/cuda/release/boxpose: $(MUJOCO_LINK_DIR)/.stamp FORCE
	CARGO_TARGET_DIR=target/$(BACKEND) cargo build --release -p boxpose-cli --features boxpose-learn/$(BACKEND)

.PHONY: FORCE
FORCE:

# Stage 2 of the shipped models read the first 6 of train_large's 50 shards, stage 3 the first 10
# (their cards); a folder holding more of its shards trains on those too.
TRAIN_LARGE_SHARDS ?= 0,1,2,3,4,5
TRAIN_LARGE_STAGE3_SHARDS ?= 6,7,8,9
# Stages 2 and 3 read both sets (held-out scenes of each are never trained on).
TRAIN_SETS := --dataset datasets/generated/train --dataset datasets/generated/train_large
train: setup $(TRAIN_BOXPOSE) ## Train the shipped networks as their cards say (BACKEND=flex|tch|wgpu|cuda): render `train` and 6 shards of `train_large`, stage 1 from random weights on `train`, stage 2 from stage 1 on both, render 4 more shards, stage 3 from stage 2, keypoint-wide and segmenter-wide from stage 3 on `train_wide` too, segmenter-wide then on `train_pallet` and `train_bins`, keypoint-wide then on all four, keypoint-sensor from stage 3 on `train_sensor` and `train_bins_sensor` (all resumable), copy to models/
	$(PY) scripts/make_scenes.py --recipe train --dataset datasets/generated/train --boxpose $(BOXPOSE)
	$(PY) scripts/make_scenes.py --recipe train_large --dataset datasets/generated/train_large \
	  --num-shards 50 --shards $(TRAIN_LARGE_SHARDS) --no-inspect
	$(TRAIN_BOXPOSE) train --config configs/keypoint-slim.toml --out runs/keypoint-slim --backend $(BACKEND)
	$(TRAIN_BOXPOSE) train-segmenter --config configs/segmenter-slim.toml --out runs/segmenter-slim --backend $(BACKEND)
	$(TRAIN_BOXPOSE) train --config configs/keypoint-slim.toml --init runs/keypoint-slim/model \
	  $(TRAIN_SETS) \
	  --steps 12000 --learning-rate 5e-4 --validate-every 1000 --max-val-instances 300 \
	  --out runs/keypoint-slim-large --backend $(BACKEND)
	$(TRAIN_BOXPOSE) train-segmenter --config configs/segmenter-slim.toml --init runs/segmenter-slim/model \
	  $(TRAIN_SETS) \
	  --steps 4000 --learning-rate 5e-4 --validate-every 500 \
	  --out runs/segmenter-slim-large --backend $(BACKEND)
	$(PY) scripts/make_scenes.py --recipe train_large --dataset datasets/generated/train_large \
	  --num-shards 50 --shards $(TRAIN_LARGE_STAGE3_SHARDS) --no-inspect
	$(TRAIN_BOXPOSE) train --config configs/keypoint-slim.toml --init runs/keypoint-slim-large/model \
	  $(TRAIN_SETS) \
	  --steps 8000 --learning-rate 3e-4 --validate-every 1000 --max-val-instances 300 \
	  --out runs/keypoint-slim-stage3 --backend $(BACKEND)
	$(TRAIN_BOXPOSE) train-segmenter --config configs/segmenter-slim.toml --init runs/segmenter-slim-large/model \
	  $(TRAIN_SETS) \
	  --steps 2000 --learning-rate 3e-4 --validate-every 500 \
	  --out runs/segmenter-slim-stage3 --backend $(BACKEND)
	$(call publish_model,runs/keypoint-slim-stage3,$(MODEL))
	$(call publish_model,runs/segmenter-slim-stage3,$(SEGMENTER))
	# keypoint-wide: stage 3 fine-tuned with a crop-scaled depth axis on the wider world too
	$(PY) scripts/make_scenes.py --recipe train_wide --dataset datasets/generated/train_wide \
	  --num-shards 40 --no-inspect
	$(TRAIN_BOXPOSE) train --config configs/keypoint-wide.toml --init runs/keypoint-slim-stage3/model \
	  --out runs/keypoint-wide --backend $(BACKEND)
	# segmenter-wide: stage 3 fine-tuned on the bins (repeated) and the wider world, then on the
	# pallets of train_pallet too (MuJoCo scenes at the segmenter's 320×256)
	$(TRAIN_BOXPOSE) train-segmenter --config configs/segmenter-wide.toml --init runs/segmenter-slim-stage3/model \
	  --out runs/segmenter-wide --backend $(BACKEND)
	$(PY) scripts/make_scenes.py --recipe train_pallet --dataset datasets/generated/train_pallet \
	  --num-shards 8 --boxpose $(BOXPOSE) --no-inspect
	$(TRAIN_BOXPOSE) train-segmenter --config configs/segmenter-pallet.toml --init runs/segmenter-wide/model \
	  --out runs/segmenter-pallet --backend $(BACKEND)
	# ... and on the dense bins of train_bins (MuJoCo, 320×256)
	$(PY) scripts/make_scenes.py --recipe train_bins --dataset datasets/generated/train_bins \
	  --num-shards 8 --boxpose $(BOXPOSE) --no-inspect
	$(TRAIN_BOXPOSE) train-segmenter --config configs/segmenter-bins.toml --init runs/segmenter-pallet/model \
	  --out runs/segmenter-bins --backend $(BACKEND)
	$(call publish_model,runs/segmenter-bins,models/segmenter-wide)
	# keypoint-wide's second stage: the cheap bins and pallets beside its own data
	$(TRAIN_BOXPOSE) train --config configs/keypoint-cheap.toml --init runs/keypoint-wide/model \
	  --out runs/keypoint-cheap --backend $(BACKEND)
	$(call publish_model,runs/keypoint-cheap,models/keypoint-wide)
	# keypoint-sensor: stage 3 (keypoint-slim) fine-tuned with a quarter of its crops on the
	# simulated sensor's depth
	$(PY) scripts/make_scenes.py --recipe train_sensor --dataset datasets/generated/train_sensor \
	  --num-shards 4 --boxpose $(BOXPOSE) --no-inspect
	$(PY) scripts/make_scenes.py --recipe train_bins_sensor --dataset datasets/generated/train_bins_sensor \
	  --num-shards 4 --boxpose $(BOXPOSE) --no-inspect
	$(TRAIN_BOXPOSE) train --config configs/keypoint-sensor-mix.toml --init runs/keypoint-slim-stage3/model \
	  --out runs/keypoint-sensor --backend $(BACKEND)
	$(call publish_model,runs/keypoint-sensor,models/keypoint-sensor)

# Copies a trained run's model, history and config into a model folder as a whole: assembled
# beside it (keeping its card.md and plots), then swapped in by two renames, so that a killed copy
# never leaves a folder mixing two trainings.
define publish_model
	rm -rf $(2).new && mkdir -p $(2).new
	cp $(1)/model/* $(1)/history.csv $(1)/config.toml $(2).new/
	if [ -d $(2) ]; then find $(2) -maxdepth 1 \( -name '*.md' -o -name '*.png' \) -exec cp {} $(2).new/ \; ; fi
	rm -rf $(2).old && if [ -d $(2) ]; then mv $(2) $(2).old; fi && mv $(2).new $(2) && rm -rf $(2).old
endef

SPACE ?= single_box
SAMPLER ?= mc
SAMPLES ?= 2000
SEARCH_OUT ?= results/search/$(SPACE)-$(SAMPLER)
search: setup ## Counterexample search, resumable (SPACE=single_box|clutter SAMPLER=mc|ce SAMPLES=2000; more options: boxpose search --help)
	$(BOXPOSE) search $(SPACE) --sampler $(SAMPLER) --samples $(SAMPLES) --out $(SEARCH_OUT)

DEMO_DATASET := datasets/generated/demo
DEMO_RESULTS := results/demo
demo: setup ## The main job on the default recipe: a small photoreal clutter dataset, then every later stage on it
	$(PY) scripts/make_scenes.py --recipe clutter --dataset $(DEMO_DATASET) --num-scenes 2 --boxpose $(BOXPOSE)
	@echo; echo "== MuJoCo re-settles the Drake scenes from their initial poses (the search loop's fast path)"
	$(BOXPOSE) settle $(DEMO_DATASET)
	@echo; echo "== heatmap → pose on ground-truth heatmaps, then with 4 confident outlier peaks (the paper's failure)"
	$(BOXPOSE) eval-geometry $(DEMO_DATASET) --out $(DEMO_RESULTS)/eval_geometry_clean.parquet
	$(BOXPOSE) eval-geometry $(DEMO_DATASET) --outliers 4 --out $(DEMO_RESULTS)/eval_geometry_4_outliers.parquet
	@echo; echo "== re-render a 128×128 crop of scene 0 from Rust (embedded Blender)"
	# render refuses a folder holding an earlier render: this one is the demo's own, so a second
	# `make demo` starts it afresh
	rm -rf $(DEMO_RESULTS)/rerender
	$(BOXPOSE) render $(DEMO_DATASET) --scene 0 --crop 256,176,384,304 --out $(DEMO_RESULTS)/rerender
	@echo; echo "== the shipped networks ($(SEGMENTER), $(MODEL)) on these freshly rendered scenes: one frame, then all of them"
	$(BOXPOSE) predict $(DEMO_DATASET) --scene 0 --frame 0 --crops predicted --model $(MODEL) --segmenter $(SEGMENTER) --out $(DEMO_RESULTS)/predict
	$(BOXPOSE) eval $(DEMO_DATASET) --crops gt --model $(MODEL) --out $(DEMO_RESULTS)/eval_gt_crops
	$(BOXPOSE) eval $(DEMO_DATASET) --crops predicted --model $(MODEL) --segmenter $(SEGMENTER) --out $(DEMO_RESULTS)/eval_predicted_crops
	@echo; echo "== counterexample search on single_box (the paper's setting, docs/search.md): Monte Carlo, then cross-entropy importance sampling"
	$(BOXPOSE) search single_box --samples 200 --out $(DEMO_RESULTS)/search-mc
	$(BOXPOSE) search single_box --sampler ce --ce-tilt target.size_m --samples 150 --ce-samples-per-iteration 60 --ce-max-iterations 3 --out $(DEMO_RESULTS)/search-ce
	@echo; echo "dataset: $(DEMO_DATASET)  (docs/dataset.md shows how to open it with pandas or DuckDB)"
	@echo "results: $(DEMO_RESULTS)"

bench: bench-geometry bench-settle bench-render bench-scenes bench-render-quality bench-render-accuracy bench-learn bench-backends bench-search bench-scale-out ## Every benchmark; each prints ratios against a reference measured in the same run (docs/benchmarks.md)

bench-geometry: setup ## Geometry core (criterion), then fast exact search vs a batched NumPy brute force on the same inputs
	cargo bench -p boxpose-geometry --bench geometry
	$(PY) scripts/bench_geometry_numpy.py --scenes 200

bench-settle: setup ## Drake vs MuJoCo settle time on the same 5- and 20-box drops
	scripts/bench_settle.sh

bench-render: setup ## Cycles seconds per 640×480 frame by samples and denoising; 128×128 crop re-render from Rust, scene reused vs rebuilt
	$(PY) scripts/bench_render.py

bench-scenes: setup ## make scenes images/s per recipe with --jobs 1 and 2; then box instances per CPU-second of train_large as shipped, settled by MuJoCo, at 320×256, and as box regions
	$(PY) scripts/bench_scenes.py
	$(PY) scripts/bench_scenes.py --recipes train_large --scenes 24 --shards 2 --variants \
	  'settle.engine="mujoco"' \
	  'settle.engine="mujoco",camera.width=320,camera.height=256' \
	  'settle.engine="mujoco",camera.width=320,camera.height=256,camera.frames_per_scene=16' \
	  'settle.engine="mujoco",camera.region="box",camera.frames_per_scene=16'

bench-render-quality: setup ## PSNR/SSIM against a 1024-sample reference and CPU-seconds per image over samples × denoiser × bounces, Kubric's defaults as a row
	$(PY) scripts/bench_render_quality.py --recipes single_box --scenes 3
	$(PY) scripts/bench_render_quality.py --recipes clutter --scenes 1 --samples 1,4,16,64

bench-render-accuracy: setup ## The shipped networks' accuracy on the same fresh scenes rendered at 1–64 samples, paired box by box against the 64-sample renders
	$(PY) scripts/bench_render_accuracy.py

bench-search: setup ## Search: CPU-seconds per sample by stage (ground-truth and segmenter crops; clutter at two resolutions against whole frames, paired); samples for 20% relative error on a real event by every sampler (MC, CE, CE --ce-tilt auto, splitting) as ratios to MC; the analytic failure sets' ratios
	$(PY) scripts/bench_search.py

bench-scale-out: setup ## python -m boxpose_ray on a loopback Ray head with 1 and 2 CPUs against one process (search and scenes)
	scripts/bench_scale_out.sh

# PyTorch, apart from .venv: for the comparison benchmark and the test of boxpose_io.torch (with
# pyarrow, which boxpose_io imports). PyPI's torch wheel brings CUDA libraries (≈ 4 GB to
# download, ≈ 7 GB installed) that nothing here loads: it runs on the CPU.
TORCH_VENV := build/torch-venv
$(TORCH_VENV)/.stamp: requirements-torch.txt
	test -x $(TORCH_VENV)/bin/python || $(PYTHON_BOOTSTRAP) -m venv $(TORCH_VENV)
	$(TORCH_VENV)/bin/pip install --quiet -r requirements-torch.txt
	touch $@

bench-backends: setup ## Keypoint network training speed on every backend built here (flex; tch, wgpu, cuda once `make train BACKEND=…` built them), one run: the bare step, then `boxpose train` in its first epoch and in the steady state
	cargo bench --no-run --quiet --workspace --bench keypoint_step
	if [ -x target/tch/release/boxpose ]; then \
	  LIBTORCH=$(LIBTORCH_DIR) RUSTFLAGS="-C link-arg=-Wl,-rpath,$(LIBTORCH_DIR)/lib" CARGO_TARGET_DIR=target/tch \
	    cargo bench --no-run --quiet -p boxpose-learn --features tch --bench keypoint_step; fi
	scripts/bench_backends.sh
	FIRST=200 STEPS=200 BACKBONES=slim scripts/bench_backends.sh  # again past the first epoch: the steady state

bench-learn: setup $(TORCH_VENV)/.stamp ## Keypoint network training step and per-crop inference: burn next to PyTorch, same architecture
	$(TORCH_VENV)/bin/python scripts/bench_learn.py

# Property tests draw their cases from this seed, so a run is reproducible and CI cannot fail by
# chance; `make fuzz` explores fresh seeds. A failure's case is kept in the test's
# `*.proptest-regressions` file, which is replayed first on every run.
PROPTEST_SEED ?= 20261201

test: setup $(TORCH_VENV)/.stamp ## Run every test: Rust unit/property tests, then the Python/Rust end-to-end tests
	PROPTEST_RNG_SEED=$(PROPTEST_SEED) cargo test --release --workspace
	$(PY) -m pytest -q -m "not faults" tests

test-faults: setup ## Fault injection: kill -9 at every write/fsync/rename of a shard writer (needs strace; docs/reliability.md)
	$(PY) -m pytest -q -s -m faults tests

lint: $(VENV)/.stamp $(MUJOCO_LINK_DIR)/.stamp ## Style and lint gates that CI runs before the tests: rustfmt, clippy (-D warnings), ruff
	cargo fmt --all --check
	cargo clippy --release --workspace --all-targets -- -D warnings
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

fuzz: rust ## Property tests on fresh random seeds with many cases (FUZZ_CASES, default 2000)
	PROPTEST_CASES=$(or $(FUZZ_CASES),2000) PROPTEST_MAX_GLOBAL_REJECTS=1000000 \
		cargo test --release --workspace --tests

clean: ## Remove build outputs and generated datasets (keeps .venv)
	cargo clean
	rm -rf build datasets/generated results

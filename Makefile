# pushgrasp: the two commands a user needs are `make run` and `make test`.
CARGO ?= cargo
SHARED ?= ../shared

.PHONY: run test test-gpu gpu-bench bench soak lint fmt arrangements

# The main job: a scaled-down stage-1 training run (goal-conditioned grasping) on the CPU:
# a buffer, a learner and 2 actor processes over shared memory, about 45 s after the build;
# checkpoint, snapshot, learning curve and summary land in logs/<run-id>/.
run:
	$(CARGO) run --release -- train --config configs/stage1.toml

# Every test of the CPU path, built optimised (physics in an unoptimised build is too slow
# to test). The MCAP files are also read back by the independent Python reader, installed
# into target/ when Python is there (the tests say so and skip that check when it is not).
# `--tests` runs every unit and integration test; it leaves out doc tests, of which the
# workspace has none, and which would have rustdoc check all 18 crates again to find that
# out (two minutes on two cores).
MCAP_VENV := target/mcap-venv
test:
	test -x $(MCAP_VENV)/bin/python3 || { python3 -m venv $(MCAP_VENV) && $(MCAP_VENV)/bin/python3 -m pip install -q mcap mcap-protobuf-support; } || echo "the Python mcap reader is not installed: its cross-check is skipped"
	$(CARGO) test --release --workspace --tests

# The GPU path's tests (tests/wgpu.rs, and CubeCL's autotune in tests/tune.rs), in a build
# with the GPU backend (burn-wgpu, autotuned) of only what they need, on this machine's Vulkan
# device: Mesa's software one (lavapipe) where there is no GPU, installed first when it is
# missing (as root with apt-get). Their tune cache stays in target/, out of the user's.
test-gpu:
	tests/vulkan/install.sh
	PUSHGRASP_TUNE_CACHE=$(CURDIR)/target/tune $(CARGO) test --release --features wgpu --test wgpu --test tune

# Every GPU figure in one go on a GPU host, within about 8 minutes, into gpu-figures.json
# (`pushgrasp bench gpu`). PUSHGRASP_BIN names a wgpu build made beforehand (a GPU host's
# minutes are too few to build one); without it, one is built here. The tune cache it fills
# holds what the GPU's tuner took for every shape: `tools/tune_picks.py list target/tune`.
gpu-bench:
	@bin="$(PUSHGRASP_BIN)"; \
	if [ -z "$$bin" ]; then $(CARGO) build --release --features wgpu && bin=target/release/pushgrasp; fi; \
	PUSHGRASP_TUNE_CACHE=$${PUSHGRASP_TUNE_CACHE:-$(CURDIR)/target/tune} "$$bin" bench gpu --out gpu-figures.json

# The peers run beside ours when they can be installed (into target/): onnxruntime and numpy
# beside the nets (bench learner), cpprb beside the replay (bench buffer). PyTorch's training
# step runs beside ours where it is installed there by hand (README, "Learning"): its wheel
# brings about 5 GB of CUDA libraries.
BENCH_VENV := target/bench-venv
bench:
	test -x $(BENCH_VENV)/bin/python3 || python3 -m venv $(BENCH_VENV) || echo "no Python venv: the benchmarks run without their peers"
	$(BENCH_VENV)/bin/python3 -c "import cpprb, onnxruntime, onnx, numpy" 2>/dev/null || $(BENCH_VENV)/bin/python3 -m pip install -q cpprb onnxruntime onnx numpy || echo "the peers are not installed: the benchmarks run without them"
	$(CARGO) run --release -- bench sim
	$(CARGO) run --release -- bench learner
	$(CARGO) run --release -- bench learner --config configs/stage1.toml
	$(CARGO) run --release -- bench transport
	$(CARGO) run --release -- bench hosts
	$(CARGO) run --release -- bench buffer
	$(CARGO) run --release -- bench e2e
	$(CARGO) run --release -- bench logging

# Memory over a long run: a stage-3 run 20 minutes past a full replay, every process's
# resident memory sampled; its growth over the last 15 minutes beside a 5% bound.
soak:
	$(CARGO) run --release -- bench soak

# Besides fmt and clippy: no file of a crate imports one that imports it back (the check
# prints each circle with the names that tie it; under a second).
lint:
	$(CARGO) fmt --all -- --check
	python3 tools/import_circles.py
	$(CARGO) clippy --release --workspace --all-targets -- -D warnings

fmt:
	$(CARGO) fmt --all

# Regenerates configs/arrangements/ from the paper's ten challenging cases and goal slots, and
# configs/validation/ from the grasping-invisible coordination cases that are not among them
# (01 and 03 hold the objects of challenging cases 01 and 06; 07 sets two cubes 1.2 cm into
# the table). Those files name their goals.
CASES := 00:4 01:7 02:8 03:7 04:7 05:3 06:1 07:7 08:5 09:9
VALIDATION := 00 02 04 05 06
arrangements:
	@for case in $(CASES); do \
		n=$${case%%:*}; goal=$${case##*:}; \
		$(CARGO) run --release -q -- scene convert \
			$(SHARED)/reference/test-cases/Efficient_goal-oriented_push-grasping_synergy/test-10-obj-$$n.txt \
			--goal-slot $$goal --name challenging-$$n > configs/arrangements/challenging-$$n.toml || exit 1; \
	done
	@for n in $(VALIDATION); do \
		$(CARGO) run --release -q -- scene convert \
			$(SHARED)/reference/test-cases/grasping-invisible/preset/coordination-$$n.txt \
			> configs/validation/coordination-$$n.toml || exit 1; \
	done

# groupforward: `make demo` runs the end-to-end demo, `make test` runs every check CI runs.
# Both do their own idempotent setup (a project-local Python venv with pinned test tools).

CARGO ?= cargo
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed-$(shell sha256sum tests/python/requirements.txt | cut -c1-16)

.PHONY: all setup build demo test test-rust test-python lint bench sweep soak golden clean train-setup train-data train-test ros2-setup ros2 ros2-test

all: test

$(STAMP): tests/python/requirements.txt
	@test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check -r tests/python/requirements.txt
	@rm -f $(VENV)/.installed-* && touch $@

setup: $(STAMP)

demo: setup build
	./target/debug/groupforward demo

lint:
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets --quiet -- -D warnings

# One feature set for every build (all targets, dev-dependencies unified), so the binary the Python
# tests run and the test builds share their compiled dependencies instead of building them twice.
build:
	$(CARGO) build --workspace --all-targets

# --all-targets also runs each benchmark once, as a smoke test.
test-rust: setup build
	$(CARGO) test --workspace --all-targets

test-python: setup build
	PYTHONDONTWRITEBYTECODE=1 $(VENV)/bin/python -m pytest -q -p no:cacheprovider tests/python

test: lint test-rust test-python

# Regenerate the golden CDR vectors and type hashes with Python rosbags.
golden: setup
	$(VENV)/bin/python msgs/tests/golden/make_golden.py

# Criterion benches, then the side-by-side measurements the README shows (CSV, Markdown, SVG).
bench: setup
	$(CARGO) bench -p groupforward -p groupforward-sim
	$(CARGO) run --release -p groupforward-cli -- bench grouping --python $(VENV)/bin/python --out node/doc/bench/grouping
	$(CARGO) run --release -p groupforward-cli -- bench graph --out node/doc/bench/graph
	$(CARGO) run --release -p groupforward-cli -- bench refer --out node/doc/bench/refer

# What accuracy costs in time: the settings sweep the README's Pareto chart comes from (~20 min).
sweep: setup
	$(CARGO) run -p groupforward-cli -- bench sweep --rounds 2 --out node/doc/bench/sweep

# Native ROS 2 (the `ros2` feature, through r2r): ROS 2 Jazzy from PyPI wheels in $(ROS2_PREFIX)
# with the message packages the wheels lack built from msgs/ros (launch/ros2/setup.sh), then the
# node built against it: `launch/ros2/groupforward run --transport ros2` joins the ROS 2 graph.
# Not part of `make test` (the first run takes ~10 min on 2 cores). It shares target/debug with the
# default build (no second cold build): `make build` relinks the default binary afterwards.
ROS2_PREFIX := target/ros2
ros2-setup:
	launch/ros2/setup.sh $(ROS2_PREFIX)

ros2 ros2-test: SHELL := /bin/bash
ros2: ros2-setup
	source launch/ros2/env.sh $(ROS2_PREFIX) && $(CARGO) build -p groupforward-cli --features ros2
	mkdir -p $(ROS2_PREFIX)/bin && cp target/debug/groupforward $(ROS2_PREFIX)/bin/groupforward

# The ros2 transport's CDR against rcl's serializers, then an rclpy node (real ROS 2, rmw_fastrtps)
# plays a sim bag into the native node and checks its services and outputs (tests/ros2).
ros2-test: setup ros2
	source launch/ros2/env.sh $(ROS2_PREFIX) && $(CARGO) test -p groupforward --features ros2 --lib transport::ros2
	rm -rf $(ROS2_PREFIX)/bag && launch/ros2/groupforward sim record sim/scenes/two_chairs.toml --no-ground-truth --out $(ROS2_PREFIX)/bag
	source launch/ros2/env.sh $(ROS2_PREFIX) && python tests/ros2/ros2_end_to_end.py --node launch/ros2/groupforward --bag $(ROS2_PREFIX)/bag

# The reliability soak at full size (10^5 bad messages, a 5-minute two-camera flood; ~7 min).
# CI runs it at a reduced size (tests/tests/soak.rs).
soak: setup build
	$(CARGO) run -p groupforward-cli -- bench soak --out node/doc/bench/soak

# Training (never part of CI): PyTorch and friends into train/.venv, and sim datasets for it.
train-setup:
	@test -x train/.venv/bin/python || $(PYTHON) -m venv train/.venv
	train/.venv/bin/python -m pip install --quiet --disable-pip-version-check -r train/requirements.txt

train-data: build
	./target/debug/groupforward sim dataset --split train --samples 2000 --out train/data/train
	./target/debug/groupforward sim dataset --split val --samples 100 --out train/data/val
	./target/debug/groupforward sim dataset --split val --samples 300 --first-index 100 --out train/data/val_selection
	./target/debug/groupforward sim dataset --split val --samples 400 --first-index 400 --out train/data/val_test
	./target/debug/groupforward sim dataset --split layouts_train --samples 1000 --out train/data/layouts_train
	python3 train/merge_datasets.py train/data/train_layouts train/data/train train/data/layouts_train

# Checks of the training code's geometry (CPU, seconds); like training, not part of CI (torch is ~3 GB).
train-test: train-setup
	PYTHONDONTWRITEBYTECODE=1 train/.venv/bin/python -m pytest -q -p no:cacheprovider train/tests

clean:
	$(CARGO) clean
	rm -rf $(VENV)

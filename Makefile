# Foresight — the two commands of the README are `make demo` and `make test`.
# Both run `make setup` first, which installs what is missing (scripts/setup.sh) and is
# cheap when nothing is.

SHELL := /bin/bash
FORESIGHT_CACHE ?= $(HOME)/.cache/foresight
# Build outputs live outside the clone so repeated CI runs reuse them, one target folder per
# checkout path: cargo's fingerprints are path-independent, and artifacts that embed their
# checkout's path (env!("CARGO_MANIFEST_DIR")) must not be shared between two checkouts
# building at once. Override with CARGO_TARGET_DIR=... as usual.
CHECKOUT_KEY := $(shell printf '%s' '$(CURDIR)' | sha1sum | cut -c1-12)
CARGO_TARGET_DIR ?= $(FORESIGHT_CACHE)/target-$(CHECKOUT_KEY)
export CARGO_TARGET_DIR FORESIGHT_CACHE

# build/env.mk is written by scripts/setup.sh (LIBTORCH and the rpath for its libraries; the
# ONNX Runtime library perception loads by default).
-include build/env.mk
export LIBTORCH FORESIGHT_TORCH_RPATH FORESIGHT_TORCH_CUDA FORESIGHT_ORT_DYLIB
# torch-sys' own check reads torch's version through Python; setup.sh checks it instead.
export LIBTORCH_BYPASS_VERSION_CHECK := 1

CARGO ?= cargo
BIN := $(CARGO_TARGET_DIR)/release

.PHONY: setup setup-fresh-check build demo test test-deploy docs-check lint fmt learner-host bench bench-link bench-loop sweep sweep-dynamic clean help

help:
	@echo "make demo   - run the main job on the simulated arm (installs what it needs)"
	@echo "make test   - run every check and test (installs what it needs)"
	@echo "make bench  - criterion benchmarks (medians in README)"
	@echo "make learner-host - on a GPU box: learner serve + relay (LEARNER_HOST_ARGS)"
	@echo "make bench-link - policy/request latency across two network namespaces (root)"
	@echo "make test-deploy - the deploy build (panic = abort) brakes after a panic"
	@echo "make sweep  - the adversarial safety sweep, 10 000 episodes (ARGS to override)"
	@echo "make sweep-dynamic - the sweep with intruders during a motion, 3 000 episodes, every kind (ARGS)"
	@echo "make docs-check - README's figures re-run where deterministic (about 2 min)"
	@echo "make setup-fresh-check - set-up as a new user meets it: empty cache, fresh HOME, output must hold no ERROR/WARNING"

setup:
	@bash scripts/setup.sh

build: setup
	$(MAKE) --no-print-directory _build

_build:
	$(CARGO) build --release --workspace --bins

demo: setup
	$(MAKE) --no-print-directory _build
	@bash scripts/demo.sh "$(BIN)" $(ARGS)

test: setup
	$(MAKE) --no-print-directory _test

_test:
	$(CARGO) fmt --all --check
	$(CARGO) clippy --release --workspace --all-targets -- -D warnings
	$(CARGO) build --release --workspace --bins
	python3 scripts/docs_check.py --bin "$(BIN)"
	$(CARGO) test --release --workspace --no-fail-fast
	@bash scripts/ci-bench-loop.sh "$(BIN)"

# The deploy build (`panic = "abort"`) keeps the controlled stop after a panic (issue 25):
# rt-core built in the deploy profile (every rt-core dependency once more: minutes, so not
# part of `make test`), then the exit-path test on it against xarm-sim.
test-deploy: setup
	$(CARGO) build --profile deploy -p rt-core --bins
	$(CARGO) build --release -p xarm-sim --bins
	$(CARGO) test --release -p foresight-tests --test exit_paths -- --ignored deploy_build

# README's claims (issue 32 item 3): `make test` checks the results table against
# docs/results.toml, the links, paths, make targets and flags; this also re-runs the seeded,
# deterministic figures (the sweeps, the unseen-worlds benchmark) and fails when one changed.
docs-check: setup
	$(MAKE) --no-print-directory _build
	python3 scripts/docs_check.py --bin "$(BIN)" --rerun

# `cargo doc` with warnings as errors (broken intra-doc links, bad code blocks): in `lint`
# only. It checks every dependency once more in its own mode (minutes on a fresh cache), so
# `make test` leaves it out. `--release` shares the build scripts' runs (OpenCV's bindings,
# libtorch's) with the release build instead of running them again. error_messages.py: no
# error message prints a source it also returns (the chain printers show it once).
lint: setup
	$(CARGO) fmt --all --check
	$(CARGO) clippy --release --workspace --all-targets -- -D warnings
	RUSTDOCFLAGS="-D warnings" $(CARGO) doc --release --no-deps --workspace
	python3 scripts/error_messages.py

fmt:
	$(CARGO) fmt --all

bench: setup
	$(CARGO) bench -p twin -p policy -p xarm

# The GPU box of a two-host setup (docs/components.md, "Two hosts"): `learner serve` plus the learner
# side of the relay. LEARNER_HOST_ARGS says where to listen (and any learner flags).
# LINK_KEYS is the folder of `zenoh-relay keygen` (issue 25); made here on first use, then
# copy $(LINK_KEYS)/robot-pc to the robot PC (`foresight --learner-host --link-keys …`).
LEARNER_HOST_ARGS ?= --listen tcp/0.0.0.0:7447
LINK_KEYS ?= link-keys
learner-host: setup
	$(MAKE) --no-print-directory _build
	@[ -d "$(LINK_KEYS)/learner-host" ] || $(BIN)/zenoh-relay keygen --out "$(LINK_KEYS)"
	$(BIN)/zenoh-relay learner-host --link-keys "$(LINK_KEYS)/learner-host" $(LEARNER_HOST_ARGS)

# Host-to-host link latency (issue 16): two network namespaces joined by a veth pair (root).
bench-link: setup
	$(MAKE) --no-print-directory _build
	$(CARGO) bench -p foresight-tests --bench link_latency

# The adversarial sweep's long run (issue 14): the real twin worker and cycle through
# randomised, adversarial scenes; exits non-zero on any unsafe command. The `sweep` binary
# is a crate of its own (rt-core/sweep), not part of the production rt-core binary. Built with
# the workspace's other binaries (`cargo run -p sweep` resolved features for that package alone
# and rebuilt most dependencies, minutes on 2 cores).
SWEEP_ARGS ?= --episodes 10000 --seed 1 --out runs/sweep
sweep: setup
	$(MAKE) --no-print-directory _build
	$(BIN)/sweep $(or $(ARGS),$(SWEEP_ARGS))

# The dynamic sweep (issue 33): an intruder during each motion (enters and stops on the path,
# crosses it, stops then leaves, appears at once; 0.1-1.6 m/s), 60 Hz frames with tracked
# velocities; exits non-zero on any avoidable contact while the arm moves. Grown by issue 42
# (moving when the arm starts, near misses, parking on the path, taking the goal, appearing
# next to the arm; `--kinds classic` is the sweep before it): 3 000 intrusions, a table per kind.
# The planner fallback on, as the product runs (README, "What runs by default").
SWEEP_DYNAMIC_ARGS ?= --dynamic --episodes 3000 --seed 1 --planner-fallback --out runs/sweep-dynamic
sweep-dynamic: setup
	$(MAKE) --no-print-directory _build
	$(BIN)/sweep $(or $(ARGS),$(SWEEP_DYNAMIC_ARGS))

# Set-up as a new user meets it (issue 41 item 6): a clone of this checkout, an empty cache and a
# fresh HOME (so pip's cache is empty too: ~1.3 GB downloaded); fails if set-up fails or prints
# ERROR or WARNING. Not part of `make test` for its download.
setup-fresh-check:
	@bash scripts/setup-fresh-check.sh

clean:
	$(CARGO) clean

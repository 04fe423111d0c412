# pedrl: `make help` lists the targets. Every target installs what it needs first (`setup`).
.DEFAULT_GOAL := help
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
TORCH_PIN := torch==2.13.0
STAMP := $(VENV)/.pedrl-installed

.PHONY: help setup run test test-all lint bench clean

help: ## list the targets
	@grep -hE '^[a-zA-Z_-]+:.*?## ' $(MAKEFILE_LIST) | awk 'BEGIN {FS = ":.*?## "}; {printf "  \033[36m%-10s\033[0m %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	@test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q $(TORCH_PIN)
	$(PY) -m pip install -q -e '.[dev,analysis,launchers,pettingzoo,jupedsim,onnx]'
	@touch $(STAMP)

setup: $(STAMP) ## create .venv with torch==2.13.0 (CPU) and pedrl[dev,analysis,launchers,pettingzoo,jupedsim,onnx]; does nothing when done

RUN_DIR ?= outputs/main/$(shell date +%Y-%m-%d_%H-%M-%S)

run: setup ## the main job: IT-VQQL on the factored table in the paper's room (experiment=main_factored), then its evaluation beside the greedy walker
	$(VENV)/bin/pedrl-train experiment=main_factored hydra.run.dir=$(RUN_DIR) $(ARGS)
	$(VENV)/bin/pedrl-eval checkpoint=$(RUN_DIR)/checkpoints/last.safetensors "agents=[20,100]" trials=50 \
		hydra.run.dir=$(RUN_DIR)/eval

# the tests run in a random order (pytest-randomly); rerun one order with `make test SEED=<the seed printed>`
# drawn once (:=), so that the seed printed is the seed pytest runs
ifndef SEED
SEED := $(shell python3 -c 'import random; print(random.randrange(2**32))')
endif

# one test process per core (pytest-xdist; JOBS=1: one process, the tests in one order); numba's two largest kernels
# are compiled first, in two processes at once (tests/warm_kernels.py), so that the test processes load them from
# numba's cache instead of each compiling its own
JOBS ?= $(shell nproc 2>/dev/null || echo 1)

test: setup ## the fast test suite (not slow), one process per core, in a random order whose seed it prints
	@echo "test order: --randomly-seed=$(SEED) (rerun this order: make test SEED=$(SEED) JOBS=$(JOBS))"
	$(PY) -m tests.warm_kernels
	OMP_NUM_THREADS=1 $(PY) -m pytest -q -p randomly --randomly-seed=$(SEED) -n $(JOBS) -m "not slow" $(ARGS)

test-all: setup ## every test, slow ones included, in a random order whose seed it prints
	@echo "test order: --randomly-seed=$(SEED) (rerun this order: make test-all SEED=$(SEED) JOBS=$(JOBS))"
	$(PY) -m tests.warm_kernels
	OMP_NUM_THREADS=1 $(PY) -m pytest -q -p randomly --randomly-seed=$(SEED) -n $(JOBS) $(ARGS)

lint: setup ## ruff check and format check
	$(VENV)/bin/ruff check pedrl tests
	$(VENV)/bin/ruff format --check pedrl tests

bench: setup ## benchmarks: writes outputs/bench/bench.json
	$(PY) -m pip install -q -e '.[dev,bench]'
	$(PY) -m pedrl.bench $(ARGS)

clean: ## remove caches (keeps .venv and outputs/)
	rm -rf .pytest_cache .ruff_cache build *.egg-info

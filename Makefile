# The command contract of docs/DESIGN.md: setup | test | demo | paper | bench.
SHELL := /bin/bash
VENV := .venv
ENV := source scripts/env.sh &&
JOBS ?= 2

.PHONY: setup test lint demo paper bench clean

setup:
	@bash scripts/setup.sh

# Two pytest-xdist workers: the hardware loop test (about 7 min of real-time arm motion against
# the emulator) runs first, beside the rest. Each worker's node processes get their own ROS
# domain (katana_common.testing); in-process graphs are isolated by discovery OFF.
TEST_WORKERS ?= 2

test: setup
	@$(ENV) ruff check .
	@$(ENV) ROS_AUTOMATIC_DISCOVERY_RANGE=OFF python -m pytest -n $(TEST_WORKERS) --dist worksteal

lint: setup
	@$(ENV) ruff check .

EXPERIMENTS ?= 200

demo: setup
	@$(ENV) katana-demo --experiments $(EXPERIMENTS)

paper: setup
	@$(ENV) katana-curiosity paper --jobs $(JOBS) --out runs/paper

# The robot experiment (issue 9): seeds x experiments x q1 and random on the fast sim, each run
# its own graph and ROS domain, against the measured truth shipped in docs/.
ROBOT_SEEDS ?= 4
ROBOT_EXPERIMENTS ?= 60
ROBOT_DOMAIN ?= 40

.PHONY: robot-paper
robot-paper: setup
	@$(ENV) katana-robot paper --seeds $(ROBOT_SEEDS) --experiments $(ROBOT_EXPERIMENTS) \
		--methods q1,random --jobs $(JOBS) --domain-base $(ROBOT_DOMAIN) \
		--truth docs/robot_truth.json --out runs/robot-paper

bench: setup
	@$(ENV) python bench/run.py

clean:
	rm -rf build install log runs .pytest_cache

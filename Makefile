# The command contract of DESIGN.md: setup | test | demo | paper | bench.
SHELL := /bin/bash
VENV := .venv
ENV := source scripts/env.sh &&
JOBS ?= 2

.PHONY: setup test lint demo paper bench clean

setup:
	@bash scripts/setup.sh

test: setup
	@$(ENV) ruff check .
	@$(ENV) ROS_AUTOMATIC_DISCOVERY_RANGE=OFF python -m pytest

lint: setup
	@$(ENV) ruff check .

EXPERIMENTS ?= 200

demo: setup
	@$(ENV) katana-demo --experiments $(EXPERIMENTS)

paper: setup
	@$(ENV) katana-curiosity paper --jobs $(JOBS) --out runs/paper

bench: setup
	@$(ENV) python bench/run.py

clean:
	rm -rf build install log runs .pytest_cache

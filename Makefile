# Two commands: `make demo` and `make test`. Each creates .venv when missing
# and installs everything first (torch's CPU wheel comes from local disk).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEMO_DIR ?= demo_out

.PHONY: demo test install bench clean

$(BIN)/python:
	$(PY) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m pipeline demo --out $(DEMO_DIR)

test: $(STAMP)
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -n 2 -q

# `make bench` prints the pipeline's speed and memory figures (every figure of issue 25, with the oaconvolve
# yardstick, in one run: about 20 minutes); `make bench BENCH="bench/bench_audio.py --walk-only"` runs another.
# The study benches (fusion_study, env_learning_curve, ...) take a built split: see their docstrings.
BENCH ?= bench/bench_pipeline.py

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e ".[compare]"
	$(BIN)/python $(BENCH)

clean:
	rm -rf $(DEMO_DIR) .pytest_cache

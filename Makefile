# Two commands for a fresh clone (Python >= 3.11 on PATH as python3):
#   make compare   the main job: head-to-head comparison on the default scenarios
#   make test      install what the tests need and run them
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
STAMP   = $(VENV)/.installed

.PHONY: test compare bench bench-check bench-ratios bench-compare reproduce lint clean mutants

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,stonesoup,dask]'
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -n 2 -q
	$(BIN)/python -m pytest -q benchmarks/bench --benchmark-disable

compare: $(STAMP)
	$(BIN)/mttbench compare

bench: $(STAMP)
	$(BIN)/python -m pytest benchmarks/bench --benchmark-only

# time every benchmark and gate each on its ratio to a reference workload timed in the
# same run (benchmarks/bench/ratios.toml): the gate means the same on any machine
bench-check: $(STAMP)
	$(BIN)/python -m pytest benchmarks/bench --benchmark-only --benchmark-timer=time.process_time

# re-record the stored ratios (run three times: each keeps the median of its last 3 runs)
bench-ratios: $(STAMP)
	$(BIN)/python -m pytest benchmarks/bench --benchmark-only \
	    --benchmark-timer=time.process_time --record-ratios

# pytest-benchmark's own wall-clock comparison with the stored baseline (same machine only)
bench-compare: $(STAMP)
	$(BIN)/python -m pytest benchmarks/bench --benchmark-only \
	    --benchmark-storage=.benchmarks/baseline --benchmark-compare=0001 \
	    --benchmark-compare-fail=min:150%

reproduce: $(STAMP)
	$(BIN)/mttbench reproduce paper

lint: $(STAMP)
	$(BIN)/ruff check .

# the mutation sample (tests/mutation/mutants.toml): does the suite catch each one-line
# change? Runs on a throwaway installed copy, never on the checkout (about 4 minutes)
mutants: $(STAMP)
	$(BIN)/python tests/mutation/run_mutants.py

clean:
	rm -rf $(VENV) build *.egg-info

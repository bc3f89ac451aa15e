# Two commands for a fresh clone (Python >= 3.11 on PATH as python3):
#   make compare   the main job: head-to-head comparison on the default scenarios
#   make test      install what the tests need and run them
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
STAMP   = $(VENV)/.installed

.PHONY: test compare bench bench-check reproduce lint clean mutants

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -n 2 -q
	$(BIN)/python -m pytest -q benchmarks/bench --benchmark-disable

compare: $(STAMP)
	$(BIN)/mttbench compare

bench: $(STAMP)
	$(BIN)/python -m pytest benchmarks/bench --benchmark-only

bench-check: $(STAMP)
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

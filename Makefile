# Two commands for a fresh clone (Python >= 3.11 on PATH as python3):
#   make compare   the main job: head-to-head comparison on the default scenarios
#   make test      install what the tests need and run them
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
STAMP   = $(VENV)/.installed

.PHONY: test compare bench lint clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -n 2 -q

compare: $(STAMP)
	$(BIN)/mttbench compare

bench: $(STAMP)
	$(BIN)/python -m pytest benchmarks/bench --benchmark-only

lint: $(STAMP)
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) build *.egg-info

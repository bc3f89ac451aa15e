# Two commands for a fresh clone (Python >= 3.11 on PATH as python3):
#   make compare   the main job: head-to-head comparison on the default scenarios
#   make test      install what the tests need and run them
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
STAMP   = $(VENV)/.installed
# the numba kernels' disk cache, warm for the kernel sources as they are now
READY   = $(VENV)/.kernels-warm
KERNEL_SOURCES = $(wildcard trackers/*kernels.py trackers/*/*kernels.py) \
                 trackers/numba_exact.py trackers/compiled.py

.PHONY: test compare bench bench-check bench-check-full bench-ratios bench-noise bench-compare reproduce lint clean mutants

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,stonesoup,dask]'
	touch $(STAMP)

# compile the numba kernels into their on-disk cache here, in two processes, so that no
# sweep's workers compile them side by side inside their first timed runs (about 105 s on
# 2 cores, 165 s in one; docs/suite_time.md): after the install, and again after a pull or
# an edit that changed a kernel module (one that others call drops every cached kernel on
# import: trackers/compiled.py). Beside them, on the core their shorter group leaves idle,
# pytest collects the tests once with bytecode writing on, so that its rewritten test
# modules are cached (each test process would rewrite them all)
$(READY): $(STAMP) $(KERNEL_SOURCES)
	$(BIN)/python -c 'from mttbench.trackers import compiled; compiled.warm_up_in_processes()' & \
	  warm=$$!; \
	  env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest --collect-only -q -p no:cacheprovider \
	    tests benchmarks/bench >/dev/null 2>&1 || echo "note: collecting the tests failed"; \
	  wait $$warm
	touch $(READY)

# the tests and every benchmark once, untimed, in one session on two processes (the
# benchmarks alone on one core left the other idle; docs/suite_time.md)
test: $(READY)
	$(BIN)/python -m pytest -n 2 -q tests benchmarks/bench --benchmark-disable

compare: $(READY)
	$(BIN)/mttbench compare

bench: $(READY)
	$(BIN)/python -m pytest benchmarks/bench --benchmark-only

# the regression gate (docs/bench_gates.md): each benchmark's fastest round over a reference
# workload timed around and between its rounds (CPU time), against its stored ratio and
# tolerance in benchmarks/bench/ratios.toml; a benchmark above its tolerance is re-run
# twice and fails when every attempt is, one without a stored ratio fails at once.
# bench-check: the quick subset for every push (marker quick, benchmarks/bench/conftest.py
# QUICK: all but the scaling series; ~2 minutes on 2 loaded cores); bench-check-full: all
# (~7 minutes). BENCH_ARGS: more pytest arguments, e.g. BENCH_ARGS="-k gpf"
BENCH_GATE = $(BIN)/python benchmarks/bench/gate.py
bench-check: $(READY)
	$(BENCH_GATE) check -- -m quick --benchmark-columns=min,median,rounds $(BENCH_ARGS)

bench-check-full: $(READY)
	$(BENCH_GATE) check -- --benchmark-columns=min,median,rounds $(BENCH_ARGS)

# re-record the stored ratios after a deliberate change moved them: 5 runs on the changed
# tree, each benchmark's median, spread and tolerance (about 35 minutes for all; select
# with BENCH_ARGS="-k ..."); MOVED_BY names the change (default: HEAD, +uncommitted)
bench-ratios: $(READY)
	$(BENCH_GATE) record $(if $(MOVED_BY),--moved-by "$(MOVED_BY)") -- $(BENCH_ARGS)

# the gate's noise: 5 gated runs on an unchanged tree, each benchmark's measured / stored
# and failures; INJECT=1.3 slows every timed call 1.3 times (the gate must then fail)
bench-noise: $(READY)
	$(BENCH_GATE) repeat --inject $(or $(INJECT),1.0) -- $(BENCH_ARGS)

# pytest-benchmark's own wall-clock comparison with the stored baseline (same machine only)
bench-compare: $(READY)
	$(BIN)/python -m pytest benchmarks/bench --benchmark-only \
	    --benchmark-storage=.benchmarks/baseline --benchmark-compare=0001 \
	    --benchmark-compare-fail=min:150%

reproduce: $(READY)
	$(BIN)/mttbench reproduce paper

lint: $(STAMP)
	$(BIN)/ruff check .

# the mutation sample (tests/mutation/mutants.toml): does the suite catch each one-line
# change? Runs on a throwaway installed copy, never on the checkout (about 4 minutes)
mutants: $(STAMP)
	$(BIN)/python tests/mutation/run_mutants.py

clean:
	rm -rf $(VENV) build *.egg-info

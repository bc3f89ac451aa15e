"""Runtime benchmarks (pytest-benchmark): collection of ``bench_*.py``, warm states,
accuracy bounds and the machine-independent regression gate.

Files here are named ``bench_*.py`` so the correctness run (``pytest`` over ``tests/``)
never picks them up; this conftest collects them when ``benchmarks/bench`` is given
explicitly. Commands (see the README, "Runtime benchmarks", and docs/bench_gates.md)::

    pytest -q benchmarks/bench --benchmark-disable      # CI: once, untimed, accuracy only
    make bench-check        # the regression gate on the quick subset (marker quick)
    make bench-check-full   # ... on every benchmark
    make bench-ratios       # re-record the stored ratios (gate.py record)

**Warm states** (:func:`warm_up`): a tracker is timed from a state in which it holds
the targets, reached through the harness's step loop (:func:`~mttbench.benchmarks.
harness.play`) with every cell looked at (the ``all`` policy) or, for a tracker that
cannot find the targets from its prior, started from the truth. A benchmark that
repeats one step from a copy of that state runs the step once untimed before each
round (:meth:`Warm.repeat_step`), so that a round times the step, not the refill of
caches that other processes emptied.

**Accuracy** (fixture ``accuracy``): the OSPA (``c = 2, p = 2``, positions) and the
counts of the step a benchmark times go into ``extra_info`` and the test fails when
the OSPA is not below the benchmark's stated bound; this runs under
``--benchmark-disable`` too, so ``make test`` catches a tracker that stopped tracking.
With targets present, the ``null`` tracker scores ``c = 2``.

**Regression gate** (:func:`pytest_runtest_call`, arithmetic in :mod:`gate`): whenever
benchmarks are timed by the gate's clock (``--benchmark-timer=time.process_time``, CPU
time, which other processes do not inflate the way they do wall time), a fixed numpy
reference workload (:func:`reference_workload`, about 3 ms) is timed by the same clock
15 times right before and 15 times right after each benchmark, and ``ratio =
min(rounds) / min(reference runs)``. The test fails when the ratio is above ``tol``
times the ratio stored for it in ``ratios.toml``, or when none is stored (the
recording mode, ``--record-ratios``, never fails). BLAS runs on one thread (set here
before numpy loads). A run by another clock is not gated (the summary says so).
``--gate-log PATH`` writes every benchmark's rounds, reference runs and verdict as
JSON lines (``gate.py`` reads them: ``check`` re-runs what exceeded its tolerance,
``record`` stores the ratios, ``repeat`` measures the gate's noise);
``--inject-slowdown F`` slows every timed call F times (:func:`slowed`), the gate's
own check; ``--ratios-file`` gates against another file.
"""

from __future__ import annotations

import copy
import fnmatch
import json
import math
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

# BLAS on one thread (gate.BLAS_THREADS), set before numpy loads: with more, the CPU time
# of a BLAS call includes its helper threads' busy-waiting, which the machine's load
# decides. Only when numpy is not loaded yet (it reads them once); otherwise the gate
# says so and fails rather than compare against ratios recorded on one thread.
_BLAS_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
if "numpy" not in sys.modules:
    for _var in _BLAS_VARS:
        os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from mttbench.benchmarks.engine.loop import play  # noqa: E402
from mttbench.benchmarks.engine.metrics import step_metrics  # noqa: E402
from mttbench.benchmarks.engine.policies import Policy, Raster  # noqa: E402
from mttbench.scenarios.model import Looks  # noqa: E402
from mttbench.scenarios.simulator import Run  # noqa: E402
from mttbench.scenarios.spec import Scenario  # noqa: E402
from mttbench.trackers.base import Estimate, Tracker  # noqa: E402
from mttbench.trackers.jmpd import JMPDTracker  # noqa: E402

from . import gate  # noqa: E402

#: the BLAS threads of this process (numpy read the variable when it loaded)
_BLAS_THREADS = os.environ.get("OPENBLAS_NUM_THREADS", "")
_BLAS_PROBLEM = "" if _BLAS_THREADS == gate.BLAS_THREADS else (
    f"OPENBLAS_NUM_THREADS is {_BLAS_THREADS or 'unset'} for this run, the stored ratios "
    f"are by {gate.BLAS_THREADS} thread (numpy was loaded before the benchmarks' conftest "
    "could set it, or it was set otherwise): run the benchmarks on their own or set it")

#: OSPA cut-off: what the ``null`` tracker scores at every step with targets present
NULL_OSPA = 2.0


def pytest_collect_file(file_path, parent):
    """Collect ``bench_*.py`` as test modules (unless pytest's own collector already does:
    a file named on the command line, or one matching ``python_files``)."""
    if file_path.suffix != ".py" or not file_path.name.startswith("bench_"):
        return None
    if parent.session.isinitpath(file_path):
        return None
    patterns = parent.config.getini("python_files")
    if any(fnmatch.fnmatch(file_path.name, p) for p in patterns):
        return None
    return pytest.Module.from_parent(parent, path=file_path)


def pytest_addoption(parser):
    parser.addoption("--record-ratios", action="store_true", default=False,
                     help="recording mode: time and list the step/reference ratios without "
                          "gating (python benchmarks/bench/gate.py record runs it and "
                          "stores them in benchmarks/bench/ratios.toml)")
    parser.addoption("--gate-log", default=None, metavar="PATH",
                     help="append one JSON line per timed benchmark (rounds, reference "
                          "runs, ratio, verdict) to PATH")
    parser.addoption("--ratios-file", default=str(gate.RATIOS_FILE), metavar="PATH",
                     help="the stored ratios to gate on (default benchmarks/bench/ratios.toml)")
    parser.addoption("--inject-slowdown", type=float, default=1.0, metavar="FACTOR",
                     help="slow every timed call FACTOR times by its own clock (a busy "
                          "loop after the call): the gate's own check (docs/bench_gates.md)")


# ------------------------------------------------------------------ accuracy
def step_accuracy(truth: np.ndarray, estimate: Estimate) -> dict[str, float]:
    """OSPA (``c = 2, p = 2``, on positions), count error and both counts of one step:
    ``truth (n, 4)`` true states, ``estimate`` the tracker's output."""
    states = np.asarray(estimate.states, dtype=float).reshape(-1, 4)
    m = step_metrics(truth[:, [0, 2]], states[:, [0, 2]], float(estimate.count))
    return {"ospa": float(m["ospa"]), "count_error": float(m["count_error"]),
            "true_count": int(len(truth)), "est_count": float(estimate.count)}


#: (test, ospa, est_count, true_count, bound) of every checked step, for the summary
_ACCURACY: list[tuple[str, float, float, int, float | None]] = []


@pytest.fixture
def accuracy(request, benchmark):
    """``accuracy(truth, estimate, bound, prefix="")``: the step's :func:`step_accuracy`
    into ``benchmark.extra_info`` (keys prefixed with ``prefix``) and an assertion that
    its OSPA is below ``bound`` (None: no bound, for a baseline tracker). Returns the
    accuracy dict."""
    def check(truth: np.ndarray, estimate: Estimate, bound: float | None,
              prefix: str = "") -> dict[str, float]:
        acc = step_accuracy(truth, estimate)
        benchmark.extra_info.update({prefix + k: v for k, v in acc.items()})
        benchmark.extra_info[prefix + "ospa_bound"] = bound
        _ACCURACY.append((request.node.name + (f" ({prefix.rstrip('_')})" if prefix else ""),
                          acc["ospa"], acc["est_count"], acc["true_count"], bound))
        if bound is not None:
            assert bound < NULL_OSPA, f"bound {bound} does not beat the null tracker"
            assert acc["ospa"] < bound, (
                f"{request.node.name}: OSPA {acc['ospa']:.3f} at the timed step is not below "
                f"its bound {bound} (estimated {acc['est_count']:g} of "
                f"{acc['true_count']} targets): the tracker lost the targets")
        return acc
    return check


# ------------------------------------------------------------------ warm states
def start_from_truth(tracker: Tracker, scenario: Scenario, truth: np.ndarray,
                     rng: np.random.Generator) -> None:
    """Put a freshly reset tracker on the targets ``truth (n, 4)`` of step 0.

    JMPD (``jmpd``, ``jmpd-ip``): every particle holds exactly the ``n`` targets, each at
    ``F^-1 x`` (one step back, so the first predict brings it to step 0) plus
    ``N(0, diag(0.3^2, 0.03^2, 0.3^2, 0.03^2))`` (about a cell's spread in position),
    positions clipped into the workspace; weights stay equal. Other trackers: TypeError.
    """
    if not isinstance(tracker, JMPDTracker):
        raise TypeError(f"no start from the truth for {type(tracker).__name__}")
    n, slots = len(truth), tracker.mask.shape[1]  # t_max as reset resolved it
    if n > slots:
        raise ValueError(f"{n} targets do not fit t_max = {slots}")
    back = truth @ np.linalg.inv(tracker.prior.F).T  # (n, 4)
    states, mask = tracker.states, tracker.mask  # (N, t_max, 4), (N, t_max) views
    spread = np.array([0.3, 0.03, 0.3, 0.03])
    states[:, :n, :] = back[None] + rng.standard_normal((len(states), n, 4)) * spread
    width, height = scenario.model.grid.extent
    states[:, :n, 0] = np.clip(states[:, :n, 0], 0.0, np.nextafter(width, 0.0))
    states[:, :n, 2] = np.clip(states[:, :n, 2], 0.0, np.nextafter(height, 0.0))
    mask[:] = False
    mask[:, :n] = True


@dataclass
class Warm:
    """A tracker after the warm-up steps ``0..step-1``, and what the timed step sees."""

    tracker: Tracker  # the state after the warm-up (copy it before timing: never mutate)
    scenario: Scenario
    world: Run  # the simulated run: truth and the sensor world
    step: int  # the timed step
    looks: Looks  # the looks of ``step`` under ``timed_policy``
    truth: np.ndarray  # (n, 4) true states at ``step``
    warm_ospa: float  # mean OSPA (c = 2, p = 2) over the warm-up steps
    last: dict[str, float]  # step_accuracy of the last warm-up step
    timed_policy: Policy = field(repr=False)

    def looks_at(self, k: int) -> Looks:
        """The looks of step ``k`` (any ``k >= step``) under the timed policy."""
        return _looks_at(self.world, self.timed_policy, k)

    def repeat_step(self):
        """A repeated benchmark of the timed step: ``setup`` runs the step once on a copy
        of :attr:`tracker` (untimed: the code and the state's data are then in the
        caches, as in the harness's loop where steps follow each other) and makes the
        round's own copy; ``step`` runs ``predict``, ``update(looks)``, ``estimate`` on
        that copy; and the step's estimate, computed once outside the timing on another
        copy (the same state and random numbers, so each timed round must give it
        again). Returns ``(setup, step, estimate)``.

        Without the untimed step, a round of a sub-millisecond step timed mostly the
        refill of caches that whatever ran before it (other processes on a loaded
        machine) had emptied: kfnn on ``default`` took 0.13-0.16 ms cold against 0.07
        warm, and its minimum over 50 rounds moved by 1.29x between repeats against
        1.11x warm (docs/bench_gates.md)."""
        state: dict = {}

        def setup():
            state["tr"] = copy.deepcopy(self.tracker)
            step()  # untimed: warms the caches
            state["tr"] = copy.deepcopy(self.tracker)

        def step():
            tr = state["tr"]
            tr.predict()
            tr.update(self.looks)
            return tr.estimate()

        setup()
        est = step()
        return setup, step, est

    def advance(self, n_calls: int, with_estimate: bool = True):
        """The step function of an advancing benchmark: each of its ``n_calls`` calls is
        the next step of this world for :attr:`tracker` (no copy), with its own looks
        (precomputed, so the policy is never timed): ``predict``, ``update`` and, if
        ``with_estimate``, ``estimate``. Returns the step function and the list of
        ``(step, estimate)`` it fills."""
        tracker = self.tracker
        looks = [self.looks_at(k) for k in range(self.step, self.step + n_calls)]
        done: list = []

        def step():
            k = self.step + len(done)
            tracker.predict()
            tracker.update(looks[k - self.step])
            est = tracker.estimate() if with_estimate else None
            done.append((k, est))
            return est

        return step, done


def _looks_at(world: Run, policy: Policy, k: int) -> Looks:
    """Step ``k``'s looks at the cells ``policy`` selects (given the true cells if it
    uses the truth, never a prediction)."""
    truth_cells = None
    if policy.uses_truth:
        s = world.states[k]
        truth_cells = world.scenario.grid.cell_of(s[:, 0], s[:, 2])
    return world.look(k, policy.select(k, truth_cells=truth_cells))


#: a configuration whose declared state (``Tracker.resource_terms``) is larger is skipped:
#: ``mttbench run`` would refuse it on this size of machine (e.g. the bootstrap JMPD with
#: its model-sized ``t_max`` on the 1,000-target scaling point)
MAX_STATE_BYTES = 2 * 2**30


def warm_up(scenario: Scenario, tracker: Tracker, n_steps: int, seed: int = 0, *,
            policy: Policy | None = None, from_truth: bool = False,
            timed_policy: Policy | None = None) -> Warm:
    """Play ``n_steps`` steps of world ``seed`` through the harness's step loop
    (:func:`~mttbench.benchmarks.engine.loop.play`) so that a timed step starts from a
    realistic state; skips the benchmark (with the tracker's reason) when the tracker
    cannot run the scenario.

    ``policy``: the warm-up's cell selection (default the harness's raster at the
    scenario's budget; the benchmarks pass :class:`~mttbench.benchmarks.engine.policies.
    AllCells`, every cell once per step). ``from_truth``: after the harness's reset,
    :func:`start_from_truth` (seeded from ``seed``). ``timed_policy``: the looks of the
    timed step(s) (default a raster at the scenario's look budget; it must not need the
    tracker's prediction).
    """
    reason = tracker.unsupported_reason(scenario.model)
    if reason:
        pytest.skip(f"{tracker.name} cannot run {scenario.name}: {reason}")
    terms = type(tracker).resource_terms(tracker.get_params(), scenario.model,
                                         getattr(scenario.model.sensor, "looks_per_step", 0),
                                         len(scenario.model.birth_death.initial_states)
                                         + scenario.model.birth_death.n_random_initial)
    if terms.state_bytes > MAX_STATE_BYTES:
        pytest.skip(f"{tracker.name} on {scenario.name}: its state alone needs about "
                    f"{terms.state_bytes / 2**30:.1f} GiB (more than a benchmark gets)")
    playback = play(scenario, tracker, seed, policy=policy, n_steps=n_steps)
    world = playback.world
    if from_truth:
        start_from_truth(tracker, scenario, world.states[0],
                         np.random.default_rng(np.random.SeedSequence([seed, 7])))
    ospa, acc = [], {}
    for rec in playback:
        acc = step_accuracy(rec.truth, rec.estimate)
        ospa.append(acc["ospa"])
    timed_policy = Raster() if timed_policy is None else timed_policy
    if timed_policy.uses_prediction:
        raise ValueError("the timed policy must not need the tracker's prediction")
    timed_policy.reset(scenario.model, scenario.model.sensor.looks_per_step,
                       np.random.default_rng(np.random.SeedSequence([seed, 11])))
    return Warm(tracker, scenario, world, n_steps, _looks_at(world, timed_policy, n_steps),
                world.states[n_steps].copy(), float(np.mean(ospa)), acc, timed_policy)


@pytest.fixture(name="warm_up")
def warm_up_fixture():
    """:func:`warm_up`, for benchmark modules (which cannot import this conftest)."""
    return warm_up


# ------------------------------------------------------------------ JMPD paired ratio
_PAIRED: list[tuple[str, float, float]] = []  # (benchmark, paired ratio, draw median s)


@pytest.fixture
def record_ratio(request):
    """``record_ratio(ratio, noise_s)``: list a paired step / noise-draw ratio in the
    terminal summary (``bench_jmpd.test_jmpd_step``)."""
    def record(ratio: float, noise_s: float) -> None:
        _PAIRED.append((request.node.name, ratio, noise_s))
    return record


# ------------------------------------------------------------------ speed goals
_GOALS: list[tuple[str, str, float, str, bool]] = []  # (benchmark, what, ratio, goal, met)


@pytest.fixture
def goal_ratio(request):
    """``goal_ratio(what, ratio, goal, met)``: list a paired speed-goal ratio in the
    terminal summary (``bench_goals.py``; the goal as text, e.g. ``">= 10"``)."""
    def record(what: str, ratio: float, goal: str, met: bool) -> None:
        _GOALS.append((request.node.name, what, ratio, goal, met))
    return record


# ------------------------------------------------------------------ regression gate
#: the benchmarks of ``make bench-check`` (marker ``quick``): (node id pattern, why). Every
#: benchmark of these files but :data:`NOT_QUICK`; the rest (the scaling series: 222
#: benchmarks, ~5 minutes, mostly trackers' steps at 300-1000 targets) runs in ``make
#: bench-check-full``.
QUICK: list[tuple[str, str]] = [
    ("bench_harness.py::*", "the step loop's own overhead"),
    ("bench_trackers.py::*", "every registered tracker's step with its defaults on small "
                             "and large: gpf, kfnn, jmpd, jmpd-ap, jmpd-ip, truth-aided, null"),
    ("bench_gpf.py::*", "the GPF's combination enumeration, its per-target scaling"),
    ("bench_jmpd.py::*", "the JMPD's speed goal at N = 1e4 and 1e5, the noise draw, grid "
                         "scaling"),
    ("bench_jmpd_ap.py::*", "jmpd-ap's speed goal and grid scaling"),
    ("bench_stonesoup.py::*", "the Stone Soup peers, next to kfnn and gpf"),
    ("bench_goals.py::*", "the speed goals between trackers (paired ratios)"),
]
#: benchmarks of those files left out of the quick set, and why
NOT_QUICK: dict[str, str] = {
    "bench_jmpd.py::test_jmpd_step[large-t30-100000]": "about 4 s a step, 25 s in all, and "
    "2.3 GB; its code is that of large-t30-10000",
}

#: reference runs right before and right after each benchmark. One before every round
#: as well made the ratios no steadier (median spread over 5 runs 0.056, against 0.044
#: without) and slowed the short advancing steps it cooled the caches of
#: (docs/bench_gates.md)
REFERENCE_REPEATS = 15

_REF_N = 200_000


class _Reference:
    """The inputs of :func:`reference_workload`, built once (fixed seeds)."""

    def __init__(self) -> None:
        rng = np.random.default_rng(np.random.SeedSequence(20240611))
        self.a = rng.standard_normal(_REF_N)
        self.idx = rng.integers(0, _REF_N, _REF_N)
        self.keys = rng.integers(0, 1000, 50_000)
        self.small = rng.standard_normal((4, 4)) * 0.5
        self.buf, self.res = np.empty(_REF_N), np.empty(_REF_N)
        self.gen = np.random.default_rng(np.random.SeedSequence(20240612))
        self.items = list(range(2000))


_REF: _Reference | None = None


def reference_workload() -> None:
    """A fixed mix of what the trackers spend their time on, about 4 ms of CPU on the
    development machine: ``2e5`` standard normals into a buffer (the particle filters'
    draws), a multiply-add and a random gather over ``2e5`` doubles, a bincount of
    ``5e4`` keys, 600 small (4x4) numpy products (per-call overhead, which dominates the
    sub-millisecond steps) and a pure-Python pass over 2000 items. Left out: ``exp``
    and sorting, whose speed follows the CPU's SIMD level much more than the steps'
    do (numpy restricted to ``X86_V2`` on the development machine: ``exp`` and ``sort``
    1.7-3.6 times slower, the steps not)."""
    global _REF
    if _REF is None:
        _REF = _Reference()
    r = _REF
    r.gen.standard_normal(out=r.buf)
    np.multiply(r.a, r.buf, out=r.res)
    np.add(r.res, 1.0, out=r.res)
    np.take(r.a, r.idx, out=r.buf)
    np.bincount(r.keys, minlength=1000)
    s = r.small
    for _ in range(600):
        s = np.tanh(s @ r.small)
    d: dict[int, int] = {}
    for i in r.items:
        d[i % 97] = d.get(i % 97, 0) + i


def time_reference(timer=time.perf_counter, repeats: int = REFERENCE_REPEATS) -> list[float]:
    """``repeats`` runs of :func:`reference_workload` by ``timer``, seconds (after one
    untimed run: inputs built, caches warm)."""
    reference_workload()
    out = []
    for _ in range(repeats):
        t0 = timer()
        reference_workload()
        out.append(timer() - t0)
    return out


def slowed(target, factor: float, timer):
    """``target`` made ``factor`` times slower by ``timer`` (the injected slowdown of
    ``--inject-slowdown``): after each call, a busy loop until ``factor`` times the
    call's own time has passed by ``timer`` since it began. By the CPU clock the extra
    is exact whatever else runs; a step of a few microseconds is slowed somewhat more
    (the loop's own clock reads, about 0.7 us each)."""
    def run(*args, **kwargs):
        t0 = timer()
        result = target(*args, **kwargs)
        t1 = timer()
        end = t1 + (factor - 1.0) * (t1 - t0)
        while timer() < end:
            pass
        return result
    return run


def _timer_name(timer) -> str:
    return f"{getattr(timer, '__module__', '')}.{getattr(timer, '__name__', repr(timer))}"


def _ratio_key(item) -> str:
    return f"{item.path.name}::{item.name}"


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _machine() -> dict[str, Any]:
    return {"cpu": _cpu_name(), "cores": os.cpu_count() or 0,
            "python": platform.python_version(), "numpy": np.__version__}


@dataclass
class _Row:
    """One timed benchmark of this run, as the summary and ``--gate-log`` show it."""

    key: str
    ratio: float
    entry: gate.Entry | None
    verdict: gate.Verdict | None  # None: not gated (another clock)
    step_min: float
    ref_min: float
    log: dict = field(repr=False, default_factory=dict)


_ROWS: list[_Row] = []
_NOT_GATED: list[str] = []  # why this run is not gated (another clock), once


_GATE_LOG: list[str | None] = [None]  # --gate-log


def pytest_configure(config):
    config.addinivalue_line("markers", "quick: in make bench-check's subset "
                                       "(conftest.QUICK lists them and why)")
    _GATE_LOG[0] = config.getoption("--gate-log")


def pytest_collection_modifyitems(config, items):
    for item in items:
        key = _ratio_key(item)
        if key not in NOT_QUICK and any(fnmatch.fnmatch(key, p) for p, _ in QUICK):
            item.add_marker(pytest.mark.quick)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item):
    """The regression gate (module docstring): the reference timed right before and right
    after a timed benchmark (its ``pedantic`` wrapped for ``--inject-slowdown``); the
    test fails when its ratio is above the stored ratio's tolerance or nothing is
    stored. Inactive under ``--benchmark-disable``."""
    bench = getattr(item, "funcargs", {}).get("benchmark")
    if bench is None or bench.disabled:
        return (yield)
    config = item.config
    timer = bench._timer  # the benchmark's own clock (--benchmark-timer)
    factor = float(config.getoption("--inject-slowdown"))
    pedantic = bench.pedantic

    def gated_pedantic(target, *args, **kwargs):
        return pedantic(slowed(target, factor, timer), *args, **kwargs)

    if factor != 1.0:
        bench.pedantic = gated_pedantic
    load0 = os.getloadavg()[0]
    before = time_reference(timer)
    result = yield
    stats = getattr(bench, "stats", None)
    if stats is None:
        return result
    after = time_reference(timer)
    steps = list(stats.stats.data)
    refs = before + after
    ratio = gate.ratio(steps, refs)
    bench.extra_info["reference_s"] = min(refs)
    bench.extra_info["reference_ratio"] = ratio
    key = _ratio_key(item)
    recording = config.getoption("--record-ratios")
    _, entries = gate.load(Path(config.getoption("--ratios-file")))
    entry = entries.get(key)
    if _timer_name(timer) != gate.GATE_TIMER:
        verdict = None
        if not _NOT_GATED:
            _NOT_GATED.append(f"timed with {_timer_name(timer)}; the gate's clock is "
                              f"{gate.GATE_TIMER} (--benchmark-timer=that)")
    elif _BLAS_PROBLEM and not recording:
        verdict = gate.Verdict(False, math.nan, f"{key}: {_BLAS_PROBLEM}")
    else:
        verdict = gate.decide(key, ratio, entry, recording=recording)
    row = _Row(key, ratio, entry, verdict, min(steps), min(refs))
    row.log = {"key": key, "nodeid": item.nodeid, "ratio": ratio,
               "ok": verdict is None or verdict.ok,
               "gated": verdict is not None and not recording,
               "stored": None if entry is None else entry.ratio,
               "tol": None if entry is None else entry.tol, "inject": factor,
               "timer": _timer_name(timer), "blas_threads": _BLAS_THREADS,
               "steps": steps, "refs_before": before,
               "refs_after": after, "load": [load0, os.getloadavg()[0]],
               "machine": _machine()}
    _ROWS.append(row)
    if _GATE_LOG[0]:
        with open(_GATE_LOG[0], "a") as f:
            f.write(json.dumps(row.log) + "\n")
    if verdict is not None and not verdict.ok:
        pytest.fail(verdict.message, pytrace=False)
    return result


def pytest_runtest_logreport(report):
    """``--gate-log``: a test that failed otherwise than by the gate (an accuracy bound,
    an error), so that ``gate.py check`` does not take it for noise."""
    if not report.failed or _GATE_LOG[0] is None:
        return
    if any(r.log.get("nodeid") == report.nodeid and not r.log["ok"] for r in _ROWS):
        return
    with open(_GATE_LOG[0], "a") as f:
        f.write(json.dumps({"nodeid": report.nodeid, "when": report.when,
                            "other_failure": True}) + "\n")


def pytest_terminal_summary(terminalreporter):
    tr = terminalreporter
    if _ACCURACY:
        tr.section("accuracy at the timed step (OSPA c = 2; null scores 2 with targets)")
        for name, ospa, est, true, bound in _ACCURACY:
            b = "-" if bound is None else f"< {bound:g}"
            tr.write_line(f"{name:52s} OSPA {ospa:6.3f} {b:>7s}   count {est:6.2f} of {true}")
    if _PAIRED:
        tr.section("JMPD step (predict + update + estimate) / its noise draw (paired median)")
        for name, ratio, noise_s in _PAIRED:
            tr.write_line(f"{name:52s} {ratio:6.2f}x   (draw {noise_s * 1e3:7.1f} ms)")
    if _GOALS:
        tr.section("speed goals: paired ratios of the fastest steps (CPU time, one run)")
        for name, what, ratio, goal, met in _GOALS:
            tr.write_line(f"{name:40s} {what:36s} {ratio:8.2f}  goal {goal:7s} "
                          f"{'met' if met else 'NOT met'}")
    if not _ROWS:
        return
    recording = tr.config.getoption("--record-ratios")
    factor = float(tr.config.getoption("--inject-slowdown"))
    tr.section("step / reference workload (gate: measured <= tol x stored)")
    if _NOT_GATED:
        tr.write_line(f"NOT GATED: {_NOT_GATED[0]}")
    elif recording:
        tr.write_line("recording mode: not gated (python benchmarks/bench/gate.py record "
                      "stores the ratios)")
    if factor != 1.0:
        tr.write_line(f"every timed call slowed {factor:g} times (--inject-slowdown)")
    for row in _ROWS:
        if row.entry is None:
            s = "(none stored)"
        else:
            s = (f"stored {row.entry.ratio:10.4g}  x{row.ratio / row.entry.ratio:5.3f} "
                 f"(tol {row.entry.tol:5.3f})")
        mark = "" if row.verdict is None or row.verdict.ok else "  FAILED"
        tr.write_line(f"{row.key:64s} {row.ratio:10.4g}  {s}   ref {row.ref_min * 1e3:.2f} "
                      f"ms{mark}")
    failed = [r for r in _ROWS if r.verdict is not None and not r.verdict.ok]
    gated = [r for r in _ROWS if r.verdict is not None and not recording]
    if gated:
        tr.write_line(f"gate: {len(gated) - len(failed)} of {len(gated)} benchmarks within "
                      f"their tolerance, {len(failed)} failed")
        faster = [r for r in gated if r.entry is not None
                  and r.ratio < r.entry.ratio / r.entry.tol]
        if faster:
            tr.write_line(f"{len(faster)} ran faster than stored / tolerance (re-record them, "
                          f"or their gate stays looser than measured): "
                          f"{', '.join(r.key for r in faster)}")

"""Runtime benchmarks (pytest-benchmark): collection of ``bench_*.py``, warm states,
accuracy bounds and the machine-independent regression gate.

Files here are named ``bench_*.py`` so the correctness run (``pytest`` over ``tests/``)
never picks them up; this conftest collects them when ``benchmarks/bench`` is given
explicitly. Commands (see the README, "Runtime benchmarks")::

    pytest -q benchmarks/bench --benchmark-disable                 # CI: once, untimed
    pytest benchmarks/bench --benchmark-only \
        --benchmark-timer=time.process_time                        # time and gate
    pytest benchmarks/bench --benchmark-only \
        --benchmark-timer=time.process_time --record-ratios        # re-record the ratios

**Warm states** (:func:`warm_up`): a tracker is timed from a state in which it holds
the targets, reached through the harness's step loop (:func:`~mttbench.benchmarks.
harness.play`) with every cell looked at (the ``all`` policy) or, for a tracker that
cannot find the targets from its prior, started from the truth.

**Accuracy** (fixture ``accuracy``): the OSPA (``c = 2, p = 2``, positions) and the
counts of the step a benchmark times go into ``extra_info`` and the test fails when
the OSPA is not below the benchmark's stated bound; this runs under
``--benchmark-disable`` too, so ``make test`` catches a tracker that stopped tracking.
With targets present, the ``null`` tracker scores ``c = 2``.

**Regression gate** (:func:`pytest_runtest_call`): whenever benchmarks are timed (not
under ``--benchmark-disable``), a fixed numpy reference workload
(:func:`reference_workload`, about 4 ms) is timed, by the benchmarks' own clock, right
before and right after each benchmark, and the benchmark's fastest round is divided by
the fastest reference run: ``ratio = min(step) / min(reference)``. Both are measured on
the same machine in the same minute, so the ratio carries over between machines far
better than a time does. The test fails when its ratio exceeds ``tolerance`` times the
ratio stored in ``ratios.toml``, which states the tolerance, the clock (``timer``) and
the runs behind each stored value; a run by another clock is not gated (the summary
says so). The stored ratios are CPU time (``--benchmark-timer=time.process_time``):
wall time on a shared machine includes whatever else runs, and the ratios of three wall
runs under a load of 5 on 2 cores spread up to 6.8x, those of CPU time up to 1.7x.
``--record-ratios`` writes this run's ratios instead of gating: each benchmark keeps
its last three runs (by the same clock) and the stored ratio is their median.
"""

from __future__ import annotations

import copy
import fnmatch
import json
import os
import platform
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.metrics import step_metrics
from mttbench.benchmarks.engine.policies import Policy, Raster
from mttbench.scenarios.model import Looks
from mttbench.scenarios.simulator import Run
from mttbench.scenarios.spec import Scenario
from mttbench.trackers.base import Estimate, Tracker
from mttbench.trackers.jmpd import JMPDTracker

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
                     help="write this run's step/reference ratios to benchmarks/bench/"
                          "ratios.toml (keeps each benchmark's last 3 runs, stores their "
                          "median) instead of gating on them")


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
    n = len(truth)
    if n > int(tracker.t_max):
        raise ValueError(f"{n} targets do not fit t_max = {tracker.t_max}")
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
        """A repeated benchmark of the timed step: ``setup`` copies :attr:`tracker`,
        ``step`` runs ``predict``, ``update(looks)``, ``estimate`` on the copy; and the
        step's estimate, computed once outside the timing on another copy (the same state
        and random numbers, so each timed round must give it again). Returns
        ``(setup, step, estimate)``."""
        state: dict = {}

        def setup():
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


# ------------------------------------------------------------------ regression gate
RATIOS_FILE = Path(__file__).with_name("ratios.toml")
#: the clock the stored ratios are measured with (pytest-benchmark's --benchmark-timer):
#: CPU time of the process, which other processes on the machine do not inflate
GATE_TIMER = "time.process_time"
RECORD_KEEP = 3  # runs kept per benchmark by --record-ratios; the stored ratio is their median
REFERENCE_REPEATS = 10  # reference runs before and after each benchmark (minimum taken)

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


def time_reference(timer=time.perf_counter, repeats: int = REFERENCE_REPEATS) -> float:
    """Fastest of ``repeats`` runs of :func:`reference_workload` by ``timer``, seconds."""
    reference_workload()  # inputs built, caches warm
    best = np.inf
    for _ in range(repeats):
        t0 = timer()
        reference_workload()
        best = min(best, timer() - t0)
    return float(best)


def _timer_name(timer) -> str:
    return f"{getattr(timer, '__module__', '')}.{getattr(timer, '__name__', repr(timer))}"


def _ratio_key(item) -> str:
    return f"{item.path.name}::{item.name}"


def _stored_ratios() -> dict[str, Any]:
    if not RATIOS_FILE.exists():
        return {"tolerance": 2.0, "timer": GATE_TIMER, "ratios": {}}
    with RATIOS_FILE.open("rb") as f:
        return tomllib.load(f)


#: (key, ratio, stored ratio or None, reference s) of every timed benchmark this run
_GATED: list[tuple[str, float, float | None, float]] = []
#: the timer of this run's benchmarks, when it is not the one the ratios were recorded with
_OTHER_TIMER: list[str] = []
_RUN_TIMER: list[str] = []  # the clock of this run's timed benchmarks


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item):
    """The regression gate (module docstring): times the reference workload around a
    timed benchmark and fails the test when ``min(step) / min(reference)`` exceeds
    ``tolerance`` times its stored ratio. Inactive under ``--benchmark-disable``."""
    bench = getattr(item, "funcargs", {}).get("benchmark")
    timed = bench is not None and not bench.disabled
    timer = bench._timer if timed else None  # the benchmark's own clock (--benchmark-timer)
    before = time_reference(timer) if timed else np.inf
    result = yield
    stats = getattr(bench, "stats", None) if timed else None
    if stats is None:
        return result
    ref = min(before, time_reference(timer))
    ratio = float(stats.stats.min) / ref
    bench.extra_info["reference_s"] = ref
    bench.extra_info["reference_ratio"] = ratio
    key = _ratio_key(item)
    stored = _stored_ratios()
    recording = item.config.getoption("--record-ratios")
    _RUN_TIMER[:] = [_timer_name(timer)]
    if _timer_name(timer) != stored.get("timer", GATE_TIMER) and not recording:
        # ratios by another clock do not compare (wall time includes other processes)
        if not _OTHER_TIMER:
            _OTHER_TIMER.append(_timer_name(timer))
        _GATED.append((key, ratio, None, ref))
        return result
    entry = stored.get("ratios", {}).get(key)
    _GATED.append((key, ratio, None if entry is None else float(entry["ratio"]), ref))
    if entry is None or recording:
        return result
    tol = float(stored["tolerance"])
    if ratio > tol * float(entry["ratio"]):
        pytest.fail(f"{key}: step / reference = {ratio:.4g}, {ratio / entry['ratio']:.2f} "
                    f"times the stored {entry['ratio']:.4g} (tolerance {tol:g}x; fastest "
                    f"round {stats.stats.min * 1e3:.3g} ms, reference {ref * 1e3:.3g} ms). "
                    "Rerun on a quiet machine; if it persists, it is a regression.",
                    pytrace=False)
    return result


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def pytest_sessionfinish(session):
    """``--record-ratios``: merge this run's ratios into ``ratios.toml``."""
    if not session.config.getoption("--record-ratios", default=False) or not _GATED:
        return
    stored = _stored_ratios()
    timer = _RUN_TIMER[0]
    # runs by another clock are not comparable: recording by a new clock starts afresh
    ratios = stored.get("ratios", {}) if stored.get("timer", GATE_TIMER) == timer else {}
    for key, ratio, _, _ in _GATED:
        runs = [*ratios.get(key, {}).get("runs", []), round(ratio, 6)][-RECORD_KEEP:]
        ratios[key] = {"ratio": round(float(np.median(runs)), 6), "runs": runs}
    refs = [ref for *_, ref in _GATED]
    recorded = {"cpu": _cpu_name(), "cores": os.cpu_count() or 0,
                "python": platform.python_version(), "numpy": np.__version__,
                "reference_ms": round(float(np.median(refs)) * 1e3, 3)}
    lines = [
        "# Runtime benchmark gate (benchmarks/bench/conftest.py): for each benchmark, its",
        "# fastest round divided by the fastest run of a fixed numpy reference workload",
        "# timed around it in the same run. A timed run fails a benchmark whose ratio is",
        "# above `tolerance` times `ratio`; `ratio` is the median of `runs`, the last runs",
        "# recorded with `pytest benchmarks/bench --benchmark-only --record-ratios`",
        "# `--benchmark-timer=<timer>`; runs by another timer are not gated.",
        f"tolerance = {float(stored.get('tolerance', 2.0))}", f"timer = {json.dumps(timer)}", "",
        "# the machine of the last recording (the reference workload's median time)",
        "[recorded]", *(f"{k} = {json.dumps(v)}" for k, v in recorded.items()), "",
        "[ratios]"]
    for key, entry in sorted(ratios.items()):
        runs = ", ".join(f"{r:.6g}" for r in entry["runs"])
        lines.append(f"{json.dumps(key)} = {{ ratio = {entry['ratio']:.6g}, runs = [{runs}] }}")
    RATIOS_FILE.write_text("\n".join(lines) + "\n")


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
    if _GATED:
        tr.section("step / reference workload (gate: measured <= tolerance x stored)")
        if _OTHER_TIMER:
            tr.write_line(f"gate not applied: this run timed with {_OTHER_TIMER[0]}, the stored "
                          f"ratios are by {_stored_ratios().get('timer', GATE_TIMER)} (pass "
                          "--benchmark-timer=that)")
        for key, ratio, stored, ref in _GATED:
            s = ("(none stored)" if stored is None
                 else f"stored {stored:10.4g}  x{ratio / stored:.2f}")
            tr.write_line(f"{key:60s} {ratio:10.4g}  {s}   ref {ref * 1e3:.2f} ms")

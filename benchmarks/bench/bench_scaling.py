"""Scaling series: step time against the number of targets at a fixed
density, and against the grid's side at fixed targets and looks, for the simulator and
every registered tracker (defaults; plus ``jmpd`` and ``jmpd-ip`` with ``t_max = 30`` on
the grid series, whose 25 targets exceed the default ``t_max = 5``).

Series ``targets``: ``n`` targets (10, 30, 100, 300, 1,000) placed at random on a square
grid of about ``250 n`` cells with ``2.5 n`` looks per step (1% of the cells), survival
0.99 and Poisson births of ``0.01 n`` per step: the density of the ``scale`` preset, which
is the series' last point (500x500, 1,000 targets, 2,500 looks). Series ``grid``: the
``large`` preset's world (25 targets at random, ~0.1 cell/step) and 250 looks per step on
grids of side 50, 100, 200, 500, 1,000 and 2,000.

Looks: the ``oracle`` policy (the targets' cells first, then distinct random cells), so
that every tracker holds its targets and a step carries the work of tracking them (a
raster over a large grid would leave the trackers almost nothing to do). Warm state:
``WARM_STEPS`` untimed steps through the harness (:func:`~mttbench.benchmarks.engine.loop.
play`), the JMPDs started from the truth (``conftest.start_from_truth``); each benchmark
then works on its own deep copy of that state.

Timed, per tracker (``extra_info`` holds the series, the size and the step's OSPA, which
is recorded, not bounded: these benchmarks time cost, bench_trackers.py checks accuracy):

* ``test_tracker_step``: each round is the next step of the world (no copy), what the
  harness times: ``predict(); update(looks); estimate()``.
* ``test_selection``: after one ``predict``, ``P_c(t)`` and the ``renyi`` policy's choice
  of the scenario's looks, ``policy.select(k, counts=tracker.cell_count_distribution())``
  (the harness's selection time).

and ``test_simulator_step``: one step of the world, the truth advanced one step
(:func:`~mttbench.scenarios.simulator.iter_truth`) and the oracle's looks answered
(``Run.look``).

The goals (docs/scaling.md): each step on the 2000x2000 grid within 1.5 times its step
on 50x50; the ``scale`` point (1,000 targets) GPF <= 100 ms and KF-NN <= 10 ms per step.
``docs/scaling_plot.py`` reads the JSON of a timed run and draws both series.

Untimed (``--benchmark-disable``, CI): only the sizes in :data:`CI_TARGETS` and
:data:`CI_SIDES` run (one step each); the others are timed only. Run::

    pytest benchmarks/bench/bench_scaling.py --benchmark-only \\
        --benchmark-json=scaling.json
"""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest

from mttbench import scenarios, trackers
from mttbench.benchmarks.engine.policies import Oracle, make_policy
from mttbench.scenarios.model import Grid
from mttbench.scenarios.simulator import iter_truth, simulate
from mttbench.scenarios.spec import Scenario
from mttbench.trackers.jmpd import JMPDTracker

TARGETS = [10, 30, 100, 300, 1000]
SIDES = [50, 100, 200, 500, 1000, 2000]
#: the sizes CI runs untimed (one step each); the others are timed only
CI_TARGETS = {30}
CI_SIDES = {50, 500}
#: cells per target and looks per target of the targets series (the scale preset's)
CELLS_PER_TARGET, LOOKS_PER_TARGET = 250, 2.5
WARM_STEPS = 5
#: (rounds, warm-up rounds) of a timed benchmark; fewer for steps of a second or more.
#: The world's 20 steps after the warm-up bound an advancing benchmark's to 19
ROUNDS, ROUNDS_SLOW = (15, 2), (3, 1)
#: a tracker's step at or above this (measured on the first warm-up step) counts as slow
SLOW_S = 0.5
#: configurations besides every registered tracker's defaults, per series
EXTRA = {"targets": [], "grid": ["jmpd:t_max=30", "jmpd-ip:t_max=30"]}


def targets_scenario(n: int) -> Scenario:
    """``n`` targets at the ``scale`` preset's density (module docstring)."""
    base = scenarios.get("scale")
    side = int(round(math.sqrt(CELLS_PER_TARGET * n)))
    bd = dataclasses.replace(base.model.birth_death, n_random_initial=n,
                             birth_rate=0.01 * n)
    sensor = dataclasses.replace(base.model.sensor,
                                 looks_per_step=int(round(LOOKS_PER_TARGET * n)))
    model = dataclasses.replace(base.model, grid=Grid(side, side, 1.0), birth_death=bd,
                                sensor=sensor)
    return dataclasses.replace(base, name=f"scaling-targets-{n}", model=model,
                               n_steps=WARM_STEPS + 20)


def grid_scenario(side: int) -> Scenario:
    """The ``large`` preset's targets and looks on a ``side x side`` grid."""
    base = scenarios.get("large")
    model = dataclasses.replace(base.model, grid=Grid(side, side, 1.0))
    return dataclasses.replace(base, name=f"scaling-grid-{side}", model=model,
                               n_steps=WARM_STEPS + 20)


SERIES = {"targets": (TARGETS, CI_TARGETS, targets_scenario),
          "grid": (SIDES, CI_SIDES, grid_scenario)}


def _cases(with_trackers: bool = True):
    out = []
    for series, (sizes, _, _) in SERIES.items():
        specs = [*trackers.available(), *EXTRA[series]] if with_trackers else [None]
        for spec in specs:
            for size in sizes:
                ident = f"{series}-{size}" if spec is None else (
                    f"{series}-{spec.replace(':', '-').replace('=', '')}-{size}")
                params = (series, size) if spec is None else (series, spec, size)
                out.append(pytest.param(*params, id=ident))
    return out


def _skip_timed_only(benchmark, series: str, size: int) -> None:
    if benchmark.disabled and size not in SERIES[series][1]:
        pytest.skip("timed only: CI runs the sizes in CI_TARGETS and CI_SIDES untimed")


_WARM: dict[tuple[str, str, int], object] = {}


def _warm(warm_up, series: str, spec_text: str, size: int):
    """The warm state of ``(series, tracker, size)`` (module docstring), built once."""
    key = (series, spec_text, size)
    if key not in _WARM:
        from mttbench.benchmarks.engine.specs import TrackerSpec

        spec = TrackerSpec.parse(spec_text)
        tracker = spec.make()
        sc = SERIES[series][2](size)
        _WARM[key] = warm_up(sc, tracker, WARM_STEPS, policy=Oracle(),
                             from_truth=isinstance(tracker, JMPDTracker),
                             timed_policy=Oracle())
    return _WARM[key]


def _copy(warm):
    return dataclasses.replace(warm, tracker=copy.deepcopy(warm.tracker))


def _info(benchmark, series: str, size: int, warm) -> None:
    sc = warm.scenario
    benchmark.extra_info.update(series=series, size=size, side=sc.grid.nx,
                                n_cells=sc.grid.n_cells, n_targets=len(warm.truth),
                                n_looks=sc.model.sensor.looks_per_step,
                                warm_steps=warm.step, policy="oracle")


@pytest.mark.parametrize(("series", "spec", "size"), _cases())
def test_tracker_step(benchmark, warm_up, accuracy, series, spec, size):
    """The harness's tracker step, advancing through the world (module docstring)."""
    _skip_timed_only(benchmark, series, size)
    warm = _copy(_warm(warm_up, series, spec, size))
    _info(benchmark, series, size, warm)
    probe, done = warm.advance(1)
    t = benchmark._timer()
    probe()  # the first timed-world step, untimed: it also tells a slow tracker apart
    slow = benchmark._timer() - t >= SLOW_S
    warm = dataclasses.replace(warm, step=warm.step + 1)
    rounds, warmup = ROUNDS_SLOW if slow else ROUNDS
    step, done = warm.advance(1 if benchmark.disabled else rounds + warmup)
    benchmark.pedantic(step, rounds=1 if benchmark.disabled else rounds,
                       warmup_rounds=0 if benchmark.disabled else warmup)
    k, est = done[-1]
    accuracy(warm.world.states[k], est, None)


@pytest.mark.parametrize(("series", "spec", "size"), _cases())
def test_selection(benchmark, warm_up, series, spec, size):
    """``P_c(t)`` and the renyi policy's looks, after one ``predict`` (module docstring)."""
    _skip_timed_only(benchmark, series, size)
    warm = _copy(_warm(warm_up, series, spec, size))
    _info(benchmark, series, size, warm)
    tracker, sc = warm.tracker, warm.scenario
    tracker.predict()
    if tracker.uses_truth:
        tracker.observe_truth(warm.truth.copy(), warm.world.ids[warm.step].copy())
    policy = make_policy("renyi")
    policy.reset(sc.model, sc.model.sensor.looks_per_step, np.random.default_rng(5))

    def select():
        return policy.select(warm.step, counts=tracker.cell_count_distribution())

    rounds, warmup = ROUNDS
    cells = benchmark.pedantic(select, rounds=1 if benchmark.disabled else rounds,
                               warmup_rounds=0 if benchmark.disabled else warmup)
    assert len(cells) == sc.model.sensor.looks_per_step
    assert cells.min() >= 0 and cells.max() < sc.grid.n_cells


@pytest.mark.parametrize(("series", "size"), _cases(with_trackers=False))
def test_simulator_step(benchmark, series, size):
    """One step of the world: the truth one step on, the oracle's looks answered."""
    _skip_timed_only(benchmark, series, size)
    sc = SERIES[series][2](size)
    world = simulate(sc, 0)
    truth = iter_truth(sc, 0)
    oracle = Oracle()
    oracle.reset(sc.model, sc.model.sensor.looks_per_step, np.random.default_rng(3))
    n_rounds = 1 if benchmark.disabled else sum(ROUNDS)
    cells = []
    for k in range(n_rounds):
        s = world.states[k]
        cells.append(oracle.select(k, truth_cells=sc.grid.cell_of(s[:, 0], s[:, 2])))
    done: list[int] = []

    def step():
        k = len(done)
        next(truth)
        looks = world.look(k, cells[k])
        done.append(k)
        return looks

    benchmark.extra_info.update(series=series, size=size, side=sc.grid.nx,
                                n_cells=sc.grid.n_cells, n_targets=len(world.states[0]),
                                n_looks=sc.model.sensor.looks_per_step)
    looks = benchmark.pedantic(step, rounds=1 if benchmark.disabled else ROUNDS[0],
                               warmup_rounds=0 if benchmark.disabled else ROUNDS[1])
    assert len(looks) == sc.model.sensor.looks_per_step

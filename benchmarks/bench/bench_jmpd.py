"""Runtime of one JMPD bootstrap step next to drawing its process noise alone.

One step = ``predict`` (deaths, ``x <- F x + L e``, boundary, births, cells) plus
``update`` (grid likelihood, normalisation, resampling when the ESS is low) with
the scenario's looks per step. The baseline draws the same ``N * t_max * 4``
standard normals with the same kind of Generator into a preallocated buffer, the
floor of any bootstrap step. Goal: step / baseline <= 1.5 at N = 1e5.

Also one resampling step with and without a resample-move sweep.

The step runs the numba kernels (``mttbench.trackers.jmpd.kernels``) when numba is
installed (``extra_info["compiled_kernels"]``); ``MTTBENCH_NO_NUMBA=1`` times the
numpy forms, which give the same numbers.

Run: ``pytest benchmarks/bench/bench_jmpd.py --benchmark-only``; the paired ratios
(``extra_info["paired_ratio"]``, see ``test_jmpd_bootstrap_step``) are listed at the
end of the terminal output and kept in the saved JSON.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from mttbench import scenarios
from mttbench.scenarios.simulator import simulate
from mttbench.trackers.jmpd import JMPDTracker

T_MAX = 5
SIZES = [10_000, 100_000]
SCENARIOS = ["default", "large"]


@pytest.fixture(scope="module", params=SCENARIOS)
def world(request):
    sc = scenarios.get(request.param)
    run = simulate(sc, 0)
    m = sc.model.sensor.looks_per_step
    looks = run.look(0, (np.arange(m) * 7919) % sc.grid.n_cells)
    return sc, looks


@pytest.mark.parametrize("n", SIZES)
def test_jmpd_bootstrap_step(benchmark, world, n, record_ratio):
    """The step, timed by pytest-benchmark; before every round (untimed, in the
    setup) the same noise draw as ``test_draw_process_noise_only`` is timed too, so
    ``extra_info["paired_ratio"]`` (median over rounds of step / draw just before it)
    is free of the drift between two benchmarks run seconds apart (the draw alone has
    wandered by 30% between runs on the reference machine)."""
    sc, looks = world
    tr = JMPDTracker(n_particles=n, t_max=T_MAX)
    tr.reset(sc.model, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    noise = np.empty((8, T_MAX, n))[4:]
    noise_times: list[float] = []

    def time_noise():
        t0 = time.perf_counter()
        rng.standard_normal(out=noise)
        noise_times.append(time.perf_counter() - t0)

    def step():
        tr.predict()
        tr.update(looks)

    benchmark.extra_info.update(scenario=sc.name, n_particles=n, t_max=T_MAX,
                                compiled_kernels=tr.uses_compiled_kernels)
    benchmark.pedantic(step, setup=time_noise, rounds=15, warmup_rounds=2)
    benchmark.extra_info["resamples"] = tr.n_resamples
    if benchmark.stats is not None:  # None under --benchmark-disable
        steps = np.asarray(benchmark.stats.stats.data)
        draws = np.asarray(noise_times[-len(steps):])
        benchmark.extra_info["paired_ratio"] = float(np.median(steps / draws))
        benchmark.extra_info["noise_median_s"] = float(np.median(draws))
        record_ratio(benchmark.extra_info["paired_ratio"], float(np.median(draws)))


@pytest.mark.parametrize("n", SIZES)
def test_draw_process_noise_only(benchmark, n):
    rng = np.random.default_rng(0)
    out = np.empty((8, T_MAX, n))[4:]  # the tracker's noise rows, same layout
    benchmark.extra_info.update(n_particles=n, t_max=T_MAX)
    benchmark.pedantic(lambda: rng.standard_normal(out=out), rounds=15, warmup_rounds=2)


@pytest.mark.parametrize("move_steps", [0, 1])
def test_jmpd_resample_move_step(benchmark, world, move_steps):
    """One step resampling every time (threshold 1), with and without one MH sweep
    of the opt-in resample-move (its cost: one more noise draw, matrix product and
    likelihood per sweep)."""
    sc, looks = world
    n = 10_000
    tr = JMPDTracker(n_particles=n, t_max=T_MAX, resample_threshold=1.0, move_steps=move_steps)
    tr.reset(sc.model, np.random.default_rng(0))

    def step():
        tr.predict()
        tr.update(looks)

    benchmark.extra_info.update(scenario=sc.name, n_particles=n, t_max=T_MAX,
                                move_steps=move_steps)
    benchmark.pedantic(step, rounds=15, warmup_rounds=2)
    benchmark.extra_info["move_acceptance"] = tr.move_acceptance

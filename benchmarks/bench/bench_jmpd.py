"""Runtime of one JMPD bootstrap step next to drawing its process noise alone.

One step = ``predict`` (deaths, ``x <- F x + L e``, boundary, births, cells) plus
``update`` (grid likelihood, normalisation, resampling when the ESS is low) with
the scenario's looks per step. The baseline draws the same ``N * t_max * 4``
standard normals with the same kind of Generator into a preallocated buffer, the
floor of any bootstrap step. Goal: step / baseline <= 1.5 at N = 1e5.

Also one resampling step with and without a resample-move sweep.

Run: ``pytest benchmarks/bench/bench_jmpd.py --benchmark-only``.
"""

from __future__ import annotations

import numpy as np
import pytest

import scenarios
from scenarios.simulator import simulate
from trackers.jmpd import JMPDTracker

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
def test_jmpd_bootstrap_step(benchmark, world, n):
    sc, looks = world
    tr = JMPDTracker(n_particles=n, t_max=T_MAX)
    tr.reset(sc.model, np.random.default_rng(0))

    def step():
        tr.predict()
        tr.update(looks)

    benchmark.extra_info.update(scenario=sc.name, n_particles=n, t_max=T_MAX)
    benchmark.pedantic(step, rounds=15, warmup_rounds=2)
    benchmark.extra_info["resamples"] = tr.n_resamples


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

"""Runtime of one GPF step (predict + update + estimate), and its scaling with the target count.

* ``paper`` and ``large`` presets: the filter is first run 20 steps on the scenario's own
  raster looks (so it holds a realistic particle set), then one step is timed; each round
  restarts from a copy of that state (``pedantic`` setup), so every round times the same
  work.
* Scaling: ``n`` targets on a 100x100 grid, 8 cells apart, each held by a confident
  particle, and every target's cell plus its 8 neighbours looked at (9 looks per target).
  The enumeration is local to clusters of particles that share a looked cell, so the cost
  per target should stay about constant from 5 to 50 targets (``extra_info`` has
  ``per_target_us``).

Run: ``pytest benchmarks/bench/bench_gpf.py --benchmark-only``.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from mttbench import scenarios
from mttbench.scenarios.model import Grid, Looks
from mttbench.trackers.gpf import GaussianParticleFilter

WARM_STEPS = 20


@pytest.mark.parametrize("name", ["paper", "large"])
def test_gpf_step(benchmark, name, warm_up):
    warm = warm_up(scenarios.get(name), GaussianParticleFilter(), WARM_STEPS)
    base, looks = warm.tracker, warm.looks
    state = {}

    def setup():
        state["tr"] = copy.deepcopy(base)

    def step():
        tr = state["tr"]
        tr.predict()
        tr.update(looks)
        tr.estimate()

    benchmark.extra_info.update(scenario=name, n_particles=len(base.particles[0]),
                                n_looks=len(looks))
    benchmark.pedantic(step, setup=setup, rounds=20, warmup_rounds=2)


def _separated_world(n_targets: int):
    grid = Grid(100, 100)
    sc = scenarios.get("default")
    model = dataclasses.replace(sc.model, grid=grid)
    side = int(np.ceil(np.sqrt(n_targets)))
    idx = np.arange(n_targets)
    ix, iy = 4 + 8 * (idx % side), 4 + 8 * (idx // side)
    means = np.zeros((n_targets, 4))
    means[:, 0], means[:, 2] = ix + 0.5, iy + 0.5
    means[:, 1], means[:, 3] = 0.05, -0.05
    covs = np.repeat(np.diag([0.09, 0.0025, 0.09, 0.0025])[None], n_targets, axis=0)
    offsets = np.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    cells = ((iy[:, None] + offsets[None, :, 1]) * grid.nx
             + ix[:, None] + offsets[None, :, 0]).ravel().astype(np.int64)
    returns = np.zeros(len(cells), dtype=bool)
    returns[4::9] = True  # a detection in every target's own cell
    return model, means, covs, Looks(cells, returns)


@pytest.mark.parametrize("n_targets", [5, 20, 50])
def test_gpf_step_separated_targets(benchmark, n_targets):
    model, means, covs, looks = _separated_world(n_targets)
    state = {}

    def setup():
        tr = GaussianParticleFilter()
        tr.reset(model, np.random.default_rng(0))
        tr.set_particles(np.full(n_targets, 0.9), means, covs)
        state["tr"] = tr

    def step():
        tr = state["tr"]
        tr.predict()
        tr.update(looks)
        tr.estimate()

    benchmark.extra_info.update(n_targets=n_targets, n_looks=len(looks))
    benchmark.pedantic(step, setup=setup, rounds=20, warmup_rounds=2)
    if benchmark.stats is not None:
        benchmark.extra_info["per_target_us"] = benchmark.stats.stats.median / n_targets * 1e6

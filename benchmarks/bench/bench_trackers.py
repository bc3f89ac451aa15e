"""Runtime of one step of every registered tracker, on a small and a large preset.

``small`` is the ``default`` preset (12x12 cells, 3 targets, 24 looks) and ``large`` the
``large`` preset (50x50 cells, 25 targets, 250 looks). Each tracker runs with its own
default parameters (what a user gets).

For each tracker x size, a module-scoped fixture simulates seed 0, resets the tracker
and runs ``WARM_STEPS`` steps of raster looks (untimed), so the timed step starts from
a realistic state (tracks or particles on the targets), not from the prior. Each timed
round then starts from a deep copy of that state (``benchmark.pedantic`` setup, untimed,
the equivalent of a reset to it), and times exactly one step::

    tracker.predict(); tracker.update(looks of step WARM_STEPS); tracker.estimate()

Accuracy of that step goes into ``benchmark.extra_info`` (OSPA, count error, true and
estimated counts, and the mean OSPA over the warm-up), so a speed-up that breaks the
tracker shows in the saved JSON next to its timing.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from mttbench import scenarios, trackers
from mttbench.benchmarks.metrics import step_metrics

WARM_STEPS = 10
SIZES = {"small": "default", "large": "large"}
#: rounds per benchmark: more for the cheap small steps, whose minimum then settles
ROUNDS = {"small": 50, "large": 10}


_CACHE: dict[tuple[str, str], object] = {}


@pytest.fixture
def warm(request, warm_up):
    """The warmed-up tracker for ``(tracker, size)`` (built once per session)."""
    key = (request.node.callspec.params["name"], request.node.callspec.params["size"])
    if key not in _CACHE:
        name, size = key
        _CACHE[key] = warm_up(scenarios.get(SIZES[size]), trackers.make(name), WARM_STEPS)
    return _CACHE[key]


@pytest.mark.parametrize("size", list(SIZES))
@pytest.mark.parametrize("name", trackers.available())
def test_tracker_step(benchmark, warm, name, size):
    state: dict = {}

    def setup():
        state["tr"] = copy.deepcopy(warm.tracker)

    def step():
        tr = state["tr"]
        tr.predict()
        tr.update(warm.looks)
        return tr.estimate()

    # accuracy of the timed step, computed once outside the timing (a deterministic copy)
    probe = copy.deepcopy(warm.tracker)
    probe.predict()
    probe.update(warm.looks)
    est = probe.estimate()
    states = np.asarray(est.states, dtype=float).reshape(-1, 4)
    m = step_metrics(warm.truth[:, [0, 2]], states[:, [0, 2]], float(est.count))
    benchmark.extra_info.update(
        tracker=name, scenario=SIZES[size], size=size, step=WARM_STEPS,
        n_looks=len(warm.looks.cells), ospa=m["ospa"], count_error=m["count_error"],
        true_count=int(len(warm.truth)), est_count=float(est.count),
        warm_mean_ospa=warm.warm_ospa)
    result = benchmark.pedantic(step, setup=setup, rounds=ROUNDS[size], warmup_rounds=1)
    # the timed step gives the same estimate as the probe (same state, same random numbers)
    assert float(result.count) == float(est.count)

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
from dataclasses import dataclass

import numpy as np
import pytest

from mttbench import scenarios, trackers
from mttbench.benchmarks.harness import play
from mttbench.benchmarks.metrics import step_metrics
from mttbench.scenarios.model import Looks
from mttbench.trackers.base import Tracker

WARM_STEPS = 10
SIZES = {"small": "default", "large": "large"}
#: rounds per benchmark: more for the cheap small steps, whose minimum then settles
ROUNDS = {"small": 50, "large": 10}


@dataclass
class Warm:
    tracker: Tracker  # state after WARM_STEPS steps (never timed, never mutated)
    looks: Looks  # the timed step's looks
    truth: np.ndarray  # (n, 4) true states of the timed step
    warm_ospa: float


def _warm(name: str, size: str) -> Warm:
    """Play ``WARM_STEPS`` raster steps of seed 0 through the harness's step loop."""
    sc = scenarios.get(SIZES[size])
    tr = trackers.make(name)
    reason = tr.unsupported_reason(sc.model)
    if reason:
        pytest.skip(f"{name} cannot run {sc.name}: {reason}")
    playback = play(sc, tr, 0, n_steps=WARM_STEPS)
    ospa = []
    for rec in playback:
        states = np.asarray(rec.estimate.states, dtype=float).reshape(-1, 4)
        ospa.append(step_metrics(rec.truth[:, [0, 2]], states[:, [0, 2]],
                                 float(rec.estimate.count))["ospa"])
    k = WARM_STEPS
    looks = playback.world.look(k, playback.policy.select(k))
    return Warm(tr, looks, playback.world.states[k].copy(), float(np.mean(ospa)))


_CACHE: dict[tuple[str, str], Warm] = {}


@pytest.fixture
def warm(request) -> Warm:
    """The warmed-up tracker for ``(tracker, size)`` (built once per session)."""
    key = (request.node.callspec.params["name"], request.node.callspec.params["size"])
    if key not in _CACHE:
        _CACHE[key] = _warm(*key)
    return _CACHE[key]


@pytest.mark.parametrize("size", list(SIZES))
@pytest.mark.parametrize("name", trackers.available())
def test_tracker_step(benchmark, warm, name, size):
    state: dict[str, Tracker] = {}

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

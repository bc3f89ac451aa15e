"""Runtime of one step of every registered tracker, on a small and a large preset,
from a state in which the tracker holds the targets (asserted).

``small`` is the ``default`` preset (12x12 cells, 3 targets, 24 looks) and ``large`` the
``large`` preset (50x50 cells, 25 targets, 250 looks). Each tracker runs with its own
default parameters (what a user gets). A tracker that declares a size unsupported is
skipped with its reason: the default JMPDs (``t_max = 5``) on ``large``; there the JMPDs
run with ``t_max = 30`` instead (``EXTRA``).

Warm state: the harness plays ``WARM_STEPS`` untimed steps of world 0 with every cell
looked at (the ``all`` policy), so the tracker has found and confirmed the targets.
The JMPDs start from the truth (``conftest.start_from_truth``) before those steps:
from their prior they hold 1-2 of the 3 ``default`` targets even after 10-30 steps of
every cell looked at (OSPA 1.2-1.7; the bootstrap's limit, docs/jmpd.md). On ``large``
the JMPDs lose targets steadily even so (OSPA from 0.1 to about 1 over 10 steps), so
they warm up for ``WARM_STEPS_JMPD_LARGE`` steps only.

Timed: one step at the scenario's budget (raster looks of step ``WARM_STEPS``)::

    tracker.predict(); tracker.update(looks); tracker.estimate()

Every round starts from a deep copy of the warm state (``benchmark.pedantic`` setup,
untimed, which first runs the step once on another copy so that the round finds the
step's code and data in the caches: conftest ``Warm.repeat_step``), so every round times
the same step. That step's OSPA and counts go into
``extra_info`` and the test fails when the OSPA is not below ``OSPA_BOUND`` (a
baseline tracker, ``null``, has no bound: it scores 2), timed or not.
"""

from __future__ import annotations

import pytest

from mttbench import scenarios, trackers
from mttbench.benchmarks.engine.policies import AllCells
from mttbench.benchmarks.engine.specs import TrackerSpec

#: untimed warm-up steps, every cell looked at: started from the prior, or from the
#: truth for the trackers in FROM_TRUTH (module docstring)
WARM_STEPS = 20
WARM_STEPS_FROM_TRUTH = {"small": 10, "large": 1}
SIZES = {"small": "default", "large": "large"}
#: rounds per benchmark (each after an untimed step: conftest Warm.repeat_step); the
#: gate's ratio takes the fastest, which settles with more rounds (docs/bench_gates.md)
ROUNDS = {"small": 50, "large": 30}
#: configurations timed on one size only, besides every registered tracker's defaults
EXTRA = {"large": ["jmpd:t_max=30", "jmpd-ip:t_max=30"]}
#: trackers (by registered name) started from the truth (module docstring)
FROM_TRUTH = {"jmpd", "jmpd-ip"}
#: OSPA (c = 2) the timed step must stay below: half of null's 2. Measured with this
#: protocol, world 0 (the benchmark's) and the worst of worlds 0-9: small gpf 0.35/0.55,
#: jmpd 0.32/0.53, jmpd-ip 0.20/0.42, kfnn 0.38/0.61; large gpf 0.60/0.60, kfnn
#: 0.57/0.72, jmpd:t_max=30 0.18/0.96, jmpd-ip:t_max=30 0.35/0.73
OSPA_BOUND = 1.0
#: per tracker where one spurious track is the model's answer: KF-NN confirms a false alarm
#: at its birth when every cell is looked at (the prior odds of 3 targets in 144 cells
#: times p_d / p_f give P(target) = 0.96 > 1 - alpha) and deletes it a few steps later; one
#: extra estimate costs ~1.1 here (world 0: OSPA 1.07, 4 states for 3), still far below 2
OSPA_BOUNDS = {"kfnn": 1.5}

#: the optional-extra peers (Stone Soup) are timed in bench_stonesoup.py: their defaults are
#: tuned for raster looks, and the every-cell warm-up here leaves ss-gnn with duplicates
CASES = [(spec, size) for size in SIZES for spec in trackers.available()
         if not hasattr(trackers.get_class(spec), "missing_extra")] + [
    (spec, size) for size, specs in EXTRA.items() for spec in specs]

_CACHE: dict[tuple[str, str], object] = {}


def _id(spec: str) -> str:
    return spec.replace(":", "-").replace("=", "").replace(",", "-")


def warm_state(warm_up, spec_text: str, size: str):
    """The warm tracker of ``(spec, size)`` (module docstring), built once per session."""
    key = (spec_text, size)
    if key not in _CACHE:
        spec = TrackerSpec.parse(spec_text)
        from_truth = spec.name in FROM_TRUTH
        steps = WARM_STEPS_FROM_TRUTH[size] if from_truth else WARM_STEPS
        _CACHE[key] = warm_up(scenarios.get(SIZES[size]), spec.make(), steps,
                              policy=AllCells(), from_truth=from_truth)
    return _CACHE[key]


@pytest.mark.parametrize(("spec", "size"), CASES,
                         ids=[f"{_id(spec)}-{size}" for spec, size in CASES])
def test_tracker_step(benchmark, warm_up, accuracy, spec, size):
    warm = warm_state(warm_up, spec, size)
    setup, step, est = warm.repeat_step()
    bound = (None if warm.tracker.baseline
             else OSPA_BOUNDS.get(TrackerSpec.parse(spec).name, OSPA_BOUND))
    benchmark.extra_info.update(
        tracker=spec, scenario=SIZES[size], size=size, step=warm.step,
        n_looks=len(warm.looks.cells), warm_steps=warm.step, warm_policy="all",
        warm_from_truth=TrackerSpec.parse(spec).name in FROM_TRUTH,
        warm_mean_ospa=warm.warm_ospa)
    accuracy(warm.truth, est, bound)
    result = benchmark.pedantic(step, setup=setup, rounds=ROUNDS[size], warmup_rounds=1)
    # the timed step gives the same estimate as the probe (same state, same random numbers)
    assert float(result.count) == float(est.count)

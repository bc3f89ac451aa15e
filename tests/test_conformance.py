"""Conformance suite: every registered tracker must pass every check (STYLE.md pattern 8).

Each check is its own test item, named ``<tracker>-check_<what>``, so
``pytest -k "gpf-check_zero_targets"`` selects one. A tracker that legitimately
cannot pass a check lists it in a class attribute
``conformance_exceptions = {"check_name": "reason"}``; the check is then skipped
with that reason, visibly.

The checks drive trackers directly (not through the harness) with a raster sweep
of the scenario's looks, so a harness bug cannot hide a tracker bug.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from mttbench import scenarios, trackers
from mttbench.scenarios.model import Looks, RayleighGridSensor
from mttbench.scenarios.simulator import simulate, tracker_seed
from mttbench.trackers.base import Estimate, Tracker

ROW_SUM_TOL = 1e-9


def _raster(k: int, n_cells: int, m: int) -> np.ndarray:
    m = min(m, n_cells)
    return (k * m + np.arange(m)) % n_cells


def drive(tracker: Tracker, scenario, seed: int, n_steps: int | None = None,
          looks_per_step: int | None = None, skip_steps: frozenset = frozenset(),
          check_counts_every: int = 0) -> list[Estimate]:
    """Run ``tracker`` on ``scenario`` and return its estimates; asserts P_c validity."""
    run = simulate(scenario, seed)
    model = scenario.model
    tracker.reset(model, np.random.default_rng(tracker_seed(scenario.name, seed, tracker.name)))
    n_steps = scenario.n_steps if n_steps is None else n_steps
    out = []
    for k in range(n_steps):
        tracker.predict()
        if isinstance(model.sensor, RayleighGridSensor):
            if check_counts_every and k % check_counts_every == 0:
                _assert_count_distribution(tracker.cell_count_distribution(), model.grid.n_cells)
            m = model.sensor.looks_per_step if looks_per_step is None else looks_per_step
            looks = Looks.empty() if k in skip_steps else run.look(k, _raster(k, model.grid.n_cells,
                                                                             m))
        else:
            looks = run.measure(k)
        tracker.update(looks)
        out.append(tracker.estimate())
    return out


def _assert_count_distribution(P: np.ndarray, n_cells: int) -> None:
    assert isinstance(P, np.ndarray)
    assert P.ndim == 2 and P.shape[0] == n_cells and P.shape[1] >= 2, P.shape
    assert np.all(np.isfinite(P))
    assert np.all(P >= 0)
    np.testing.assert_allclose(P.sum(axis=1), 1.0, atol=ROW_SUM_TOL)


def _assert_estimate_valid(est: Estimate) -> None:
    assert isinstance(est, Estimate)
    assert np.isfinite(est.count) and est.count >= 0, est.count
    assert isinstance(est.states, np.ndarray)
    assert est.states.dtype == np.float64
    assert est.states.ndim == 2 and est.states.shape[1] == 4, est.states.shape
    assert np.all(np.isfinite(est.states))
    if est.covariances is not None:
        assert est.covariances.shape == (est.states.shape[0], 4, 4)
        assert np.all(np.isfinite(est.covariances))


# ------------------------------------------------------------------------- checks
def check_runs_200_steps(name: str) -> None:
    sc = dataclasses.replace(scenarios.get("default"), n_steps=200)
    for est in drive(trackers.make(name), sc, seed=0, check_counts_every=25):
        _assert_estimate_valid(est)


def check_deterministic(name: str) -> None:
    sc = dataclasses.replace(scenarios.get("births"), n_steps=40)
    a = drive(trackers.make(name), sc, seed=3)
    b = drive(trackers.make(name), sc, seed=3)
    for ea, eb in zip(a, b, strict=True):
        assert ea.count == eb.count
        np.testing.assert_array_equal(ea.states, eb.states)


def check_zero_targets(name: str) -> None:
    """No targets ever, every cell looked at: no crash, and the count settles below 1."""
    base = scenarios.get("default")
    model = dataclasses.replace(
        base.model,
        birth_death=dataclasses.replace(base.model.birth_death, initial_states=(),
                                        n_random_initial=0, birth_rate=0.0),
    )
    sc = dataclasses.replace(base, n_steps=60, model=model)
    ests = drive(trackers.make(name), sc, seed=1, looks_per_step=sc.grid.n_cells,
                 check_counts_every=20)
    for est in ests:
        _assert_estimate_valid(est)
    assert np.mean([e.count for e in ests[-20:]]) < 1.0


def check_step_without_looks(name: str) -> None:
    sc = dataclasses.replace(scenarios.get("default"), n_steps=30)
    ests = drive(trackers.make(name), sc, seed=2, skip_steps=frozenset({0, 1, 10, 11, 12}),
                 check_counts_every=1)
    for est in ests:
        _assert_estimate_valid(est)


def check_count_distribution_on_large(name: str) -> None:
    sc = dataclasses.replace(scenarios.get("large"), n_steps=5)
    drive(trackers.make(name), sc, seed=0, check_counts_every=1)


def check_superposition_or_reason(name: str) -> None:
    sc = dataclasses.replace(scenarios.get("superposition"), n_steps=30)
    tracker = trackers.make(name)
    reason = tracker.unsupported_reason(sc.model)
    if reason is not None:
        assert isinstance(reason, str) and len(reason) > 10
        return
    for est in drive(tracker, sc, seed=0):
        _assert_estimate_valid(est)


def check_params(name: str) -> None:
    """Constructor stores parameters unchanged; they rebuild an equal tracker; JSON-able."""
    cls = trackers.get_class(name)
    tracker = trackers.make(name)
    params = tracker.get_params()
    assert params == cls.param_defaults()
    json.dumps(params)
    assert trackers.make(name, **params).get_params() == params
    with pytest.raises(TypeError, match="no parameter"):
        trackers.make(name, definitely_not_a_parameter=1)
    assert cls.summary


CHECKS = [check_runs_200_steps, check_deterministic, check_zero_targets,
          check_step_without_looks, check_count_distribution_on_large,
          check_superposition_or_reason, check_params]

CASES = [(name, check) for name in trackers.available() for check in CHECKS]


@pytest.mark.parametrize(("name", "check"), CASES,
                         ids=[f"{n}-{c.__name__}" for n, c in CASES])
def test_conformance(name, check):
    exceptions = getattr(trackers.get_class(name), "conformance_exceptions", {})
    if check.__name__ in exceptions:
        pytest.skip(f"{name} declares: {exceptions[check.__name__]}")
    check(name)

"""Cell-selection policies: registry, oracle, renyi, and renyi closed loop on every tracker."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mttbench import scenarios, trackers
from mttbench.benchmarks.engine.information import expected_gain, greedy_looks
from mttbench.benchmarks.engine.policies import available_policies, make_policy
from mttbench.scenarios.simulator import simulate, tracker_seed
from mttbench.trackers.cells import as_cell_counts

DEFAULT = scenarios.get("default")
MODEL = DEFAULT.model


def test_registry_lists_information_and_oracle_policies():
    names = available_policies()
    assert {"all", "random", "raster", "renyi", "oracle"} <= set(names)
    assert make_policy("oracle").uses_truth
    assert not make_policy("renyi").uses_truth
    assert make_policy("renyi").uses_prediction
    for name in names:
        if name != "oracle":
            assert not make_policy(name).uses_truth, name
    assert make_policy("renyi", alpha=0.7, repeats=False).get_params() == {
        "alpha": 0.7, "repeats": False}
    with pytest.raises(TypeError):
        make_policy("renyi", beta=1.0)


# ------------------------------------------------------------------------- oracle
def _oracle(n_looks, seed=0):
    pol = make_policy("oracle")
    pol.reset(MODEL, n_looks, np.random.default_rng(seed))
    return pol


def test_oracle_looks_at_every_target_cell_then_distinct_random_cells():
    pol = _oracle(24)
    truth = np.array([5, 5, 17, -1, 143])  # duplicates and an outside target
    cells = pol.select(0, truth_cells=truth)
    assert cells.dtype == np.int64 and cells.shape == (24,)
    assert len(np.unique(cells)) == 24
    assert {5, 17, 143} <= set(cells.tolist())
    assert cells.min() >= 0 and cells.max() < MODEL.grid.n_cells
    # the filling cells are random: two steps differ
    assert pol.select(1, truth_cells=truth).tolist() != cells.tolist()


def test_oracle_with_more_target_cells_than_looks_takes_a_subset_of_them():
    pol = _oracle(3)
    truth = np.arange(10, 20)
    cells = pol.select(0, truth_cells=truth)
    assert len(np.unique(cells)) == 3 and set(cells.tolist()) <= set(truth.tolist())


def test_oracle_with_no_targets_and_without_truth():
    pol = _oracle(4)
    assert len(np.unique(pol.select(0, truth_cells=np.zeros(0, dtype=np.int64)))) == 4
    with pytest.raises(ValueError):
        pol.select(0)


def test_oracle_finds_the_targets_of_a_run():
    run = simulate(DEFAULT, 0)
    pol = _oracle(24)
    for k in (0, 50):
        counts = run.cell_counts(k)
        cells = pol.select(k, truth_cells=np.nonzero(counts)[0])
        assert set(np.nonzero(counts)[0].tolist()) <= set(cells.tolist())


# -------------------------------------------------------------------------- renyi
def test_renyi_policy_matches_the_kernel_and_is_reproducible():
    rng = np.random.default_rng(3)
    P = rng.dirichlet(np.full(3, 0.4), size=MODEL.grid.n_cells)
    pd = MODEL.sensor.detection_probability(np.arange(3))
    out = []
    for _ in range(2):
        pol = make_policy("renyi")  # default: alpha = 0.5, distinct cells
        pol.reset(MODEL, 24, np.random.default_rng(11))
        out.append(pol.select(0, counts=P))
    assert out[0].tolist() == out[1].tolist()
    best = np.argsort(-expected_gain(P, pd, 0.5))[:24]
    assert set(out[0].tolist()) == set(best.tolist())
    pol = make_policy("renyi", repeats=True)
    pol.reset(MODEL, 24, np.random.default_rng(11))
    want = greedy_looks(P, pd, 24, 0.5, repeats=True, rng=np.random.default_rng(11))
    assert pol.select(0, counts=P).tolist() == want.tolist()


def test_renyi_needs_the_prediction_and_a_grid_sensor():
    pol = make_policy("renyi")
    pol.reset(MODEL, 24, np.random.default_rng(0))
    with pytest.raises(ValueError):
        pol.select(0)
    with pytest.raises(TypeError):
        pol.reset(scenarios.get("superposition").model, 24, np.random.default_rng(0))


def test_renyi_looks_at_uncertain_cells():
    """Two cells with an even chance of a target, the rest certainly empty: without
    repeats both are looked at once (plus two zero-gain cells); with repeats the four
    looks split two and two between them (equal marginal gains)."""
    P = np.zeros((MODEL.grid.n_cells, 2))
    P[:, 0] = 1.0
    P[[40, 77]] = [0.5, 0.5]
    for repeats, want in ((False, None), (True, [40, 40, 77, 77])):
        pol = make_policy("renyi", repeats=repeats)
        pol.reset(MODEL, 4, np.random.default_rng(0))
        cells = pol.select(0, counts=P)
        if want is None:
            assert len(np.unique(cells)) == 4 and {40, 77} <= set(cells.tolist())
        else:
            assert cells.tolist() == want


# -------------------------------------------------------------------- closed loop
CLOSED_LOOP_STEPS = 200


@pytest.mark.parametrize("repeats", [False, True])
@pytest.mark.parametrize("name", trackers.available())
def test_every_tracker_runs_closed_loop_with_renyi(name, repeats):
    """predict -> P_c -> renyi looks -> look (common random numbers) -> update -> estimate."""
    sc = dataclasses.replace(DEFAULT, n_steps=CLOSED_LOOP_STEPS)
    tracker = trackers.make(name)
    reason = tracker.unsupported_reason(sc.model)
    if reason is not None:
        pytest.skip(reason)
    run = simulate(sc, 0)
    tracker.reset(sc.model, np.random.default_rng(tracker_seed(sc.name, 0, name)))
    pol = make_policy("renyi", repeats=repeats)
    pol.reset(sc.model, 24, np.random.default_rng(1))
    n_cells = sc.model.grid.n_cells
    for k in range(CLOSED_LOOP_STEPS):
        tracker.predict()
        P = tracker.cell_count_distribution()
        dense = as_cell_counts(P).dense()
        assert dense.shape[0] == n_cells and np.all(np.isfinite(dense))
        cells = pol.select(k, counts=P)
        assert cells.dtype == np.int64 and cells.shape == (24,)
        assert cells.min() >= 0 and cells.max() < n_cells
        tracker.update(run.look(k, cells))
        est = tracker.estimate()
        assert np.isfinite(est.count) and est.count >= 0
        assert np.all(np.isfinite(est.states))


def test_raster_advances_its_look_budget_every_step_and_wraps():
    """Raster on the 12x12 ``default`` grid (144 cells) with M = 50: step ``k`` looks at
    cells ``50 k, ..., 50 k + 49`` mod 144, so step 2 wraps (100..143, then 0..5) and
    step 3 starts at 6; every cell is looked at once in each 144 consecutive looks."""
    pol = make_policy("raster")
    pol.reset(MODEL, 50, np.random.default_rng(0))
    n = MODEL.grid.n_cells
    assert n == 144
    looks = [pol.select(k) for k in range(4)]
    for k, cells in enumerate(looks):
        np.testing.assert_array_equal(cells, (50 * k + np.arange(50)) % n)
    assert looks[3][0] == 6
    first = np.concatenate(looks)[:144]
    assert sorted(first.tolist()) == list(range(144))

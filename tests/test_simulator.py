"""The simulator: sensor statistics, determinism, order-independence of looks, dynamics."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats

from mttbench import scenarios
from mttbench.scenarios.model import Dynamics, Grid, RayleighGridSensor
from mttbench.scenarios.simulator import simulate, simulate_truth


def _static_scenario(states, p_d=0.5, snr=1.0, n_steps=400, nx=4, ny=1):
    """Targets that never move (Q = 0, zero velocity) on a small grid."""
    base = scenarios.get("default")
    model = dataclasses.replace(
        base.model,
        grid=Grid(nx, ny, 1.0),
        dynamics=Dynamics(tau=1.0, q_matrix=tuple(tuple(0.0 for _ in range(4)) for _ in range(4))),
        birth_death=dataclasses.replace(base.model.birth_death, initial_states=tuple(states),
                                        n_random_initial=0, birth_rate=0.0),
        sensor=RayleighGridSensor(p_d=p_d, snr=snr, looks_per_step=nx * ny),
    )
    return dataclasses.replace(base, name="static-test", n_steps=n_steps, model=model)


def test_positive_fraction_matches_pd_of_count():
    """Cells holding T = 0, 1, 2 targets return 1 with frequency p_d(T).

    A low snr (1.0) makes p_f = 0.25 so the T = 0 case is testable. Each cell is looked
    at 3 times per step (repeats are independent looks), 400 steps -> 1200 Bernoulli
    draws per cell and seed; the check is a two-sided binomial test at level 1e-4 per
    cell, so a correct simulator fails it with probability < 1e-3 overall.
    """
    sc = _static_scenario([(1.5, 0, 0.5, 0), (2.5, 0, 0.5, 0), (2.6, 0, 0.4, 0)])
    sensor = sc.model.sensor
    totals = np.zeros(4)
    positives = np.zeros(4)
    for seed in range(2):
        run = simulate(sc, seed)
        cells = np.repeat(np.arange(4), 3)
        for k in range(sc.n_steps):
            looks = run.look(k, cells)
            positives += np.bincount(looks.cells[looks.returns], minlength=4)
            totals += np.bincount(looks.cells, minlength=4)
    counts = simulate(sc, 0).cell_counts(0)
    np.testing.assert_array_equal(counts, [0, 1, 2, 0])
    for c in range(4):
        p = float(sensor.detection_probability(counts[c]))
        pval = stats.binomtest(int(positives[c]), int(totals[c]), p).pvalue
        assert pval > 1e-4, (c, counts[c], positives[c] / totals[c], p)


def test_detection_probability_formula():
    s = RayleighGridSensor(p_d=0.5, snr=10.0)
    assert s.p_f == pytest.approx(0.5**11)
    assert s.p_f == pytest.approx(4.8828125e-4)
    np.testing.assert_allclose(s.detection_probability([0, 1, 2]),
                               [0.5**11, 0.5, 0.5 ** (11 / 21)])
    # log-likelihood ratio is exactly zero for empty cells and matches the definition
    llr = s.log_likelihood_ratio(np.array([True, False, True]), np.array([0, 2, 1]))
    assert llr[0] == 0.0
    assert llr[1] == pytest.approx(np.log(1 - 0.5 ** (11 / 21)) - np.log(1 - 0.5**11))
    assert llr[2] == pytest.approx(np.log(0.5) - np.log(0.5**11))


@pytest.mark.parametrize("name", ["default", "births", "paper"])
def test_same_seed_same_world(name):
    sc = scenarios.get(name)
    a, b = simulate(sc, 7), simulate(sc, 7)
    for k in range(sc.n_steps):
        np.testing.assert_array_equal(a.ids[k], b.ids[k])
        np.testing.assert_array_equal(a.states[k], b.states[k])
    cells = np.arange(sc.grid.n_cells)
    np.testing.assert_array_equal(a.look(3, cells).returns, b.look(3, cells).returns)
    c = simulate(sc, 8)
    assert not np.array_equal(a.states[-1], c.states[-1])


def test_look_order_and_subset_do_not_change_returns():
    """A look's answer depends only on (step, cell, repeat index), not on the other looks."""
    sc = _static_scenario([(0.5, 0, 0.5, 0), (1.5, 0, 0.5, 0)], snr=0.5, nx=6, ny=3)
    run = simulate(sc, 11)
    rng = np.random.default_rng(0)
    cells = rng.integers(0, sc.grid.n_cells, size=60)  # many repeats
    reference = run.look(5, cells).returns
    perm = rng.permutation(cells.size)
    # permuting the looks permutes the answers only where the repeat rank is kept:
    # compare per cell the sequence of answers in repeat order
    shuffled = run.look(5, cells[perm]).returns
    for c in np.unique(cells):
        ref_seq = reference[cells == c]
        shuf_seq = shuffled[cells[perm] == c]
        np.testing.assert_array_equal(np.sort(ref_seq), np.sort(shuf_seq))
    # a fresh run object (no cached rows) looking at one cell alone agrees with the full call
    fresh = simulate(sc, 11)
    first_cell = int(cells[0])
    alone = fresh.look(5, np.array([first_cell])).returns
    assert alone[0] == reference[0]


def test_repeated_looks_are_independent():
    """Repeats at one cell are distinct draws: with p_f = 0.5**1.1 about half disagree."""
    sc = _static_scenario([], p_d=0.5, snr=0.1, nx=1, ny=1, n_steps=500)
    run = simulate(sc, 3)
    pairs = np.array([run.look(k, np.array([0, 0])).returns for k in range(sc.n_steps)])
    p = sc.model.sensor.p_f
    disagree = np.mean(pairs[:, 0] != pairs[:, 1])
    expected = 2 * p * (1 - p)
    # binomial sd over 500 steps is ~0.022; 5 sd band
    assert abs(disagree - expected) < 5 * np.sqrt(expected * (1 - expected) / 500)


def test_reflect_keeps_targets_inside_and_die_removes_them():
    sc = scenarios.get("paper")  # jumps of several cells per step: many bounces
    _, states = simulate_truth(sc, 0)
    w, h = sc.grid.extent
    for s in states:
        assert np.all((s[:, 0] >= 0) & (s[:, 0] < w) & (s[:, 2] >= 0) & (s[:, 2] < h))
        assert len(s) == 3
    births = scenarios.get("births")
    ids, states = simulate_truth(births, 1)
    counts = [len(i) for i in ids]
    assert len(set(counts)) > 1  # the count changes
    for i in ids:
        assert len(np.unique(i)) == len(i)


def test_dynamics_moments_without_boundary():
    """With no boundary hit, one step of the truth has mean F x and covariance Q."""
    sc = scenarios.get("default")
    dyn = sc.model.dynamics
    x0 = np.array([6.0, 0.1, 6.0, -0.1])
    model = dataclasses.replace(
        sc.model,
        dynamics=Dynamics(tau=1.0, wna_intensity=0.01),
        birth_death=dataclasses.replace(sc.model.birth_death, initial_states=(tuple(x0),) * 4000),
    )
    big = dataclasses.replace(sc, n_steps=2, model=model)
    _, states = simulate_truth(big, 0)
    step = states[1]
    F, Q = model.dynamics.F, model.dynamics.Q
    # 4 standard errors per component
    assert np.all(np.abs(step.mean(axis=0) - F @ x0) < 4 * np.sqrt(np.diag(Q) / 4000))
    # sample covariance: standard error of entry ij is sqrt((Q_ii Q_jj + Q_ij^2) / n); 5 SE
    se = np.sqrt((np.outer(np.diag(Q), np.diag(Q)) + Q**2) / len(step))
    assert np.all(np.abs(np.cov(step.T) - Q) < 5 * se)
    assert dyn.F.shape == (4, 4)


def test_superposition_measurement_is_mean_plus_noise():
    sc = scenarios.get("superposition")
    run = simulate(sc, 0)
    H, R = sc.model.sensor.H, sc.model.sensor.R
    resid = np.array([run.measure(k).z - (run.states[k] @ H.T).mean(axis=0)
                      for k in range(sc.n_steps)])
    # 100 draws of N(0, 0.25 I): sample covariance within a loose chi-square band
    assert np.allclose(resid.mean(axis=0), 0, atol=4 * 0.5 / np.sqrt(100))
    var = resid.var(axis=0, ddof=1)
    lo, hi = stats.chi2.ppf([1e-4, 1 - 1e-4], 99) / 99
    assert np.all((var / R[0, 0] > lo) & (var / R[0, 0] < hi))
    np.testing.assert_array_equal(run.measure(4).z, simulate(sc, 0).measure(4).z)


def test_look_rejects_bad_cells():
    run = simulate(scenarios.get("default"), 0)
    with pytest.raises(ValueError, match="cell indices"):
        run.look(0, np.array([144]))
    with pytest.raises(ValueError, match="step"):
        run.look(100, np.array([0]))
    with pytest.raises(ValueError, match="seed"):
        simulate(scenarios.get("default"), -1)

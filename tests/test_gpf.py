"""The GPF tracker as a whole: merging, pruning, extraction, births, P_c, long-run health."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from scipy import stats

from mttbench import scenarios, trackers
from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.scenarios.simulator import simulate
from mttbench.trackers.cells import gaussian_cell_mass
from mttbench.trackers.gpf import DEFAULT_DEATH_FLOOR, EmptyPriorGPF, merge_particles
from mttbench.trackers.gpf.grid import fold_into_workspace, sorted_runs
from mttbench.trackers.gpf.tracker import group_heads, merge_groups

#: round-off only (a few products and sums of O(1) numbers)
EXACT = 1e-12


def _cov(s=0.3, v=0.05):
    return np.diag([s * s, v * v, s * s, v * v])


def test_merge_rules_keep_weights_probabilities():
    w = np.array([0.7, 0.6, 0.9])
    m = np.array([[3.0, 0.1, 3.0, 0.0], [3.05, 0.1, 2.98, 0.0], [9.0, 0.0, 9.0, 0.0]])
    P = np.stack([_cov()] * 3)
    wc, mc, Pc = merge_particles(w, m, P, 4.0, "capped_sum")
    assert sorted(wc) == pytest.approx([0.9, 1.0])
    # the merged Gaussian is the weighted moment match of the pair
    i = int(np.argmin(np.abs(mc[:, 0] - 3.0)))
    mean = (0.7 * m[0] + 0.6 * m[1]) / 1.3
    cov = (0.7 * (P[0] + np.outer(m[0] - mean, m[0] - mean))
           + 0.6 * (P[1] + np.outer(m[1] - mean, m[1] - mean))) / 1.3
    np.testing.assert_allclose(mc[i], mean, atol=1e-12)
    np.testing.assert_allclose(Pc[i], cov, atol=1e-12)
    # nothing merges at threshold 0
    assert len(merge_particles(w, m, P, 0.0)[0]) == 3
    with pytest.raises(ValueError, match="rule"):
        merge_particles(w, m, P, 4.0, "union")


def test_bounded_sum_merge_keeps_the_count():
    """A particle joins a group (nearest first) only while the group's weight sum stays <= 1."""
    m = np.array([[3.0, 0.1, 3.0, 0.0], [3.05, 0.1, 3.0, 0.0], [3.1, 0.1, 3.0, 0.0]])
    P = np.stack([_cov()] * 3)
    w = np.array([0.6, 0.5, 0.3])
    wb, mb, Pb = merge_particles(w, m, P, 4.0, "bounded_sum")
    # from 0.6: the nearest (0.5) would overflow, the next (0.3) fits -> {0.6, 0.3}, {0.5}
    np.testing.assert_allclose(wb, [0.9, 0.5], atol=1e-15)
    np.testing.assert_allclose(mb[0], (0.6 * m[0] + 0.3 * m[2]) / 0.9, atol=1e-12)
    np.testing.assert_allclose(mb[1], m[1], atol=0)
    assert merge_particles(w, m, P, 4.0, "capped_sum")[0] == pytest.approx([1.0])
    # two certain, broad, overlapping particles are two targets: never merged
    broad = np.stack([np.diag([12.0, 0.01, 12.0, 0.01])] * 2)
    w2, _, _ = merge_particles(np.ones(2), m[:2] + [[0, 0, 0, 0], [4, 0, 0, 0]], broad, 4.0,
                               "bounded_sum")
    np.testing.assert_allclose(w2, [1.0, 1.0])
    # random sets: the count is kept exactly and every weight stays a probability
    rng = np.random.default_rng(3)
    for _ in range(50):
        k = int(rng.integers(2, 12))
        wr = rng.uniform(0.0, 1.0, k)
        A = rng.normal(size=(k, 4, 4))
        Pr = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(4)
        wm, _, Pm = merge_particles(wr, rng.uniform(0.0, 3.0, (k, 4)), Pr, 4.0, "bounded_sum")
        assert wm.sum() == pytest.approx(wr.sum(), abs=1e-12)
        assert np.all(wm <= 1.0) and len(wm) <= k
        assert np.linalg.eigvalsh(Pm).min() > 0


def test_prune_cap_and_extraction_rules():
    sc = scenarios.get("default")
    rng = np.random.default_rng(0)
    w = np.array([0.9, 0.55, 0.4, 0.3, 0.0005])
    m = np.stack([[1.0 + 2 * i, 0.0, 1.0 + 2 * i, 0.0] for i in range(5)])
    P = np.stack([_cov()] * 5)
    for extraction, expected in (("round_sum", [0, 1]), ("threshold", [0, 1])):
        t = EmptyPriorGPF(max_particles=3, extraction=extraction)
        t.reset(sc.model, rng)
        t.set_particles(w, m, P)
        t.update(Looks(np.array([143]), np.array([False])))  # far away: only merge/prune act
        wp, mp, _ = t.particles
        np.testing.assert_allclose(np.sort(wp)[::-1], [0.9, 0.55, 0.4])  # floor, then cap
        est = t.estimate()
        assert est.count == pytest.approx(1.85)
        np.testing.assert_allclose(est.states, m[expected])
    t = EmptyPriorGPF(extraction="threshold", extraction_threshold=0.35)
    t.reset(sc.model, rng)
    t.set_particles(w, m, P)
    assert len(t.estimate().states) == 3


def _cell_masses_diagonal(grid, mean_xy, sd_xy):
    """Mass of ``N(mean, diag(sd^2))`` in every cell, ``(n_cells,)`` row-major in y: a
    product of one-dimensional normal CDF differences (exact for a diagonal covariance)."""
    cells = np.arange(grid.n_cells)
    x0, x1, y0, y1 = grid.cell_bounds(cells)
    fx, fy = stats.norm(mean_xy[0], sd_xy[0]), stats.norm(mean_xy[1], sd_xy[1])
    return (fx.cdf(x1) - fx.cdf(x0)) * (fy.cdf(y1) - fy.cdf(y0))


def test_cell_count_distribution_equals_enumeration_of_particles_and_field():
    """The whole per-cell count distribution P_c(t), not only its mean, on a 3 x 2 grid.

    Independent reference: enumerate every joint outcome of the two particles (each absent,
    in one of the six cells or outside the workspace, with probabilities ``1 - w``,
    ``w m_c``, ``w (1 - sum m)``; ``m_c`` from scipy's normal CDF) and of cell c's
    undetected-field variable (present with ``u_c``); P_c(t) sums the outcomes with t in
    c. Both particles overlap in several cells, so P_c(2) > 0 and P_c(3) > 0 there:
    merging a cell's Bernoulli variables into one keeps the mean and loses those. Exact up
    to round-off (1e-12)."""
    grid = Grid(3, 2, 1.0)
    model = TrackingModel(grid, Dynamics(wna_intensity=1e-3),
                          BirthDeath(initial_states=((1.5, 0.0, 1.0, 0.0),)),
                          RayleighGridSensor())
    t = trackers.make("gpf", n_counts=4)
    t.reset(model, np.random.default_rng(0))
    w = np.array([0.8, 0.6])
    m = np.array([[1.2, 0.0, 0.9, 0.0], [1.6, 0.0, 1.1, 0.0]])
    sd = np.array([[0.5, 0.4], [0.6, 0.7]])
    P = np.stack([np.diag([sx * sx, 0.01, sy * sy, 0.01]) for sx, sy in sd])
    t.set_particles(w, m, P)
    got = t.cell_count_distribution().dense()
    # the field at reset: initial_count_mean / n_cells = 1/6 in every cell
    u = np.full(grid.n_cells, 1.0 / 6.0)
    mass = np.stack([_cell_masses_diagonal(grid, m[i, [0, 2]], sd[i]) for i in range(2)])
    options = [np.concatenate([[1.0 - w[i], w[i] * (1.0 - mass[i].sum())], w[i] * mass[i]])
               for i in range(2)]  # option 0 absent, 1 outside, 2 + c in cell c
    want = np.zeros((grid.n_cells, 4))
    for a, b in itertools.product(range(grid.n_cells + 2), repeat=2):
        p_ab = options[0][a] * options[1][b]
        for c in range(grid.n_cells):
            in_c = (a == 2 + c) + (b == 2 + c)
            want[c, in_c] += p_ab * (1.0 - u[c])
            want[c, in_c + 1] += p_ab * u[c]
    assert want[:, 2:].max() > 0.05  # overlaps matter: P_c(2) is not small
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def _predict_one_step(boundary: str, w, m, P, **params):
    """A GPF without births on a 5 x 4 workspace (survival 1, no death floor), one predict;
    returns the particles and the model."""
    model = TrackingModel(Grid(5, 4, 1.0), Dynamics(wna_intensity=2e-3),
                          BirthDeath(boundary=boundary), RayleighGridSensor())
    t = EmptyPriorGPF(death_probability=0.0, **params)
    t.reset(model, np.random.default_rng(0))
    t.set_particles(w, m, P)
    t.predict()
    return t.particles, model


#: one mean crossing each wall (+x, -x, +y, -y) in the predict, one staying inside
_CROSSING_MEANS = np.array([[4.8, 0.5, 2.0, 0.1], [0.2, -0.45, 1.5, 0.0],
                            [2.5, 0.05, 3.9, 0.3], [1.0, 0.0, 0.1, -0.35],
                            [2.5, 0.1, 2.0, -0.1]])


def test_predict_reflect_folds_each_gaussian_into_the_workspace():
    """Boundary "reflect": each predicted Gaussian ``N(F m, F P F^T + Q)`` is folded into
    the workspace (:func:`fold_into_workspace`, checked against folded samples in
    tests/test_gpf_mass.py): the means that crossed a wall come back inside, and the
    weights keep survival 1 (no mass is lost at a reflecting wall). Exact up to
    round-off. (Under "die": tests/test_gpf_mass.py, the default predict under "die".)"""
    rng = np.random.default_rng(2)
    A = rng.normal(0.0, 0.1, (5, 4, 4))
    P = A @ np.swapaxes(A, -1, -2) + 0.01 * np.eye(4)
    w = np.array([0.9, 0.8, 0.7, 0.6, 0.5])
    (w1, m1, P1), model = _predict_one_step("reflect", w, _CROSSING_MEANS, P)
    F, Q = model.dynamics.F, model.dynamics.Q
    width, height = model.grid.extent
    mean = _CROSSING_MEANS @ F.T
    cov = F @ P @ F.T + Q
    want_m, want_P = fold_into_workspace(mean, cov, model.grid)
    np.testing.assert_allclose(m1, want_m, atol=EXACT)
    np.testing.assert_allclose(P1, want_P, atol=EXACT)
    assert np.all((m1[:, [0, 2]] >= 0.0) & (m1[:, [0, 2]] < [width, height]))
    crossed = np.any((mean[:, [0, 2]] < 0.0) | (mean[:, [0, 2]] >= [width, height]), axis=1)
    np.testing.assert_array_equal(crossed, [True, True, True, True, False])
    np.testing.assert_allclose(w1, w, atol=0)


def test_without_births_an_empty_filter_stays_empty():
    sc = dataclasses.replace(scenarios.get("default"), n_steps=5)
    run = simulate(sc, 0)
    t = EmptyPriorGPF()
    t.reset(sc.model, np.random.default_rng(0))
    for k in range(5):
        t.predict()
        np.testing.assert_allclose(t.cell_count_distribution().dense()[:, 0], 1.0)
        t.update(run.look(k, np.arange(sc.grid.n_cells)))
        assert t.estimate().count == 0.0


@pytest.mark.parametrize("name", ["default", "births"])
def test_births_recover_the_targets_from_the_field(name):
    """All cells looked at each step: the filter starts with no particles and must find them.

    Count within 0.5 of the truth on average over the last 20 of 60 steps, and the
    distance from a true target to the nearest estimate (cut at 2 cells, so a missed
    target costs 2) below one cell on average (loose on purpose: the claim is recovery).
    """
    sc = dataclasses.replace(scenarios.get(name), n_steps=60)
    run = simulate(sc, 4)
    t = trackers.make("gpf")
    t.reset(sc.model, np.random.default_rng(1))
    errs, dists = [], []
    for k in range(sc.n_steps):
        t.predict()
        t.update(run.look(k, np.arange(sc.grid.n_cells)))
        est = t.estimate()
        if k >= 40:
            errs.append(abs(est.count - len(run.states[k])))
            for p in run.positions(k):
                d = np.linalg.norm(est.states[:, [0, 2]] - p, axis=1)
                dists.append(min(d.min(), 2.0) if len(d) else 2.0)  # cut at 2 cells
    assert np.mean(errs) < 0.5
    assert np.mean(dists) < 1.0


@pytest.mark.slow
@pytest.mark.parametrize("name", ["default", "births"])
def test_2000_steps_stay_finite_and_positive_definite(name):
    sc = dataclasses.replace(scenarios.get(name), n_steps=2000)
    run = simulate(sc, 0)
    t = trackers.make("gpf")
    t.reset(sc.model, np.random.default_rng(0))
    n_cells, m = sc.grid.n_cells, 8  # a cheap raster: 8 looks per step, each cell every 18
    for k in range(sc.n_steps):
        t.predict()
        t.update(run.look(k, (k * m + np.arange(m)) % n_cells))
        w, mean, P = t.particles
        assert np.all(np.isfinite(w)) and np.all((w >= 0) & (w <= 1))
        assert np.all(np.isfinite(mean)) and np.all(np.isfinite(P))
        if len(P):
            np.testing.assert_allclose(P, np.swapaxes(P, -1, -2), atol=1e-12)
            assert np.linalg.eigvalsh(P).min() > 0, k
        assert np.isfinite(t.estimate().count)


def test_superposition_keeps_the_prior_count():
    """Superposition: z is a mean, so the count must come from the prior weights and merging
    must not lose it. The merge there is ``bounded_sum``, which keeps 2 for 2 targets
    (``capped_sum`` would merge the two broad starting particles into one of weight 1)."""
    sc = dataclasses.replace(scenarios.get("superposition"), n_steps=20)
    run = simulate(sc, 0)
    t = trackers.make("gpf")
    t.reset(sc.model, np.random.default_rng(0))
    w0, m0, P0 = t.particles
    assert len(w0) == 2 and merge_particles(w0, m0, P0, 4.0, "capped_sum")[0] == \
        pytest.approx([1.0])  # what capped_sum would do to the starting particles
    counts = []
    for k in range(sc.n_steps):
        t.predict()
        t.update(run.measure(k))
        counts.append(t.estimate().count)
    np.testing.assert_allclose(counts, 2.0, atol=1e-9)


def _still_particle_model(name: str = "default"):
    """``name``'s model with almost no process noise, so a particle's cell mass stays ~1."""
    sc = scenarios.get(name)
    return dataclasses.replace(sc.model, dynamics=Dynamics(tau=1.0, wna_intensity=1e-10))


@pytest.mark.parametrize("floor", [0.003, 0.01, 0.03])
def test_death_floor_lets_a_saturated_weight_fall_after_negative_looks(floor):
    """A weight that rounds to exactly 1.0 must come down when its cell keeps returning 0.

    Six detections in one step from ``w = 0.5`` take the log-odds to ``6 log l(1) = 41.6``,
    and ``w`` rounds to 1.0; without a floor ``w L / (w L + 1 - w)`` then stays 1.0 for any
    ``L``. With the floor ``f`` the predict gives ``w <= 1 - f`` (log-odds at most
    ``log((1 - f) / f)``) and each look at the particle's cell without a return adds
    ``log(m l(1) + 1 - m)`` with ``m`` its mass in the cell (here ``>= 0.999``) and
    ``l(1) = (1 - p_d) / (1 - p_f)``; later predicts only lower it. So ``w < 0.5`` after at
    most ``ceil(log((1 - f) / f) / -log(1 - 0.999 (1 - l(1))))`` looks (7 at ``f = 0.01``).
    """
    model = _still_particle_model()
    sensor = model.sensor
    t = EmptyPriorGPF(death_probability=floor)
    t.reset(model, np.random.default_rng(0))
    cell = model.grid.cell_of(5.5, 6.5)
    t.set_particles([0.5], [[5.5, 0.0, 6.5, 0.0]], _cov(0.05, 1e-4)[None])
    t.update(Looks(np.full(6, cell), np.ones(6, dtype=bool)))
    assert t.particles[0][0] == 1.0  # saturated in floating point
    l1 = (1.0 - sensor.p_d) / (1.0 - sensor.p_f)
    n_max = math.ceil(math.log((1 - floor) / floor) / -math.log(1.0 - 0.999 * (1.0 - l1)))
    weights = []
    for _ in range(n_max):
        t.predict()
        w, m, P = t.particles
        assert w[0] <= 1.0 - floor
        assert gaussian_cell_mass(model.grid, m[:, [0, 2]], P[:, [0, 2]][:, :, [0, 2]])[
            0, cell] >= 0.999
        t.update(Looks(np.array([cell]), np.zeros(1, dtype=bool)))
        weights.append(t.particles[0][0])
    assert weights[-1] < 0.5, weights
    assert np.all(np.diff(weights) < 0)


def test_death_floor_default_only_on_the_grid_with_births():
    """``death_probability=None``: the floor on the grid with births on a model with
    arrivals; the model's ``p_s`` on a model without arrivals (the count bound holds lost
    targets), without births (the exact reductions) and on the superposition sensor (whose
    count lives in the prior weights); an explicit value always applies, as ``min(p_s, 1 -
    floor)``; and ``0`` reproduces the model, under which a saturated weight never falls."""
    grid = _still_particle_model()  # no arrivals, p_s = 1
    arrivals = dataclasses.replace(
        grid, birth_death=dataclasses.replace(grid.birth_death, birth_rate=0.01))
    births = scenarios.get("births").model  # p_s = 0.98 is below 1 - floor
    sup = scenarios.get("superposition").model
    gpf = trackers.get_class("gpf")
    cases = [(gpf, {}, arrivals, 1.0 - DEFAULT_DEATH_FLOOR), (gpf, {}, grid, 1.0),
             (EmptyPriorGPF, {}, grid, 1.0),
             (gpf, {}, sup, 1.0), (gpf, {}, births, 0.98),
             (EmptyPriorGPF, {"death_probability": 0.05}, grid, 0.95),
             (gpf, {"death_probability": 0.05}, sup, 0.95)]
    for cls, kwargs, model, survival in cases:
        t = cls(**kwargs)
        t.reset(model, np.random.default_rng(0))
        t.set_particles([1.0], [[5.5, 0.0, 6.5, 0.0]], _cov(0.05, 1e-4)[None])
        t.predict()
        assert t.particles[0][0] == pytest.approx(survival, abs=1e-15), (cls, kwargs)
    t = EmptyPriorGPF(death_probability=0.0)
    t.reset(grid, np.random.default_rng(0))
    t.set_particles([1.0], [[5.5, 0.0, 6.5, 0.0]], _cov(0.05, 1e-4)[None])
    cell = grid.grid.cell_of(5.5, 6.5)
    for _ in range(50):
        t.predict()
        t.update(Looks(np.array([cell]), np.zeros(1, dtype=bool)))
    assert t.particles[0][0] == 1.0
    with pytest.raises(ValueError, match="death_probability"):
        trackers.make("gpf", death_probability=1.5).reset(grid, np.random.default_rng(0))


def test_group_heads_and_sorted_runs_equal_np_unique():
    """The merge's group heads and the sorted keys' runs, against ``np.unique`` (which
    sorts): random merges with tied weights and both rules, sorted keys with repeats,
    one key and none."""
    rng = np.random.default_rng(21)
    merged = 0
    for _ in range(200):
        K = int(rng.integers(1, 15))
        w = rng.uniform(0.0, 1.0, K)
        w[rng.random(K) < 0.3] = 0.5  # ties: the stable order decides
        m = np.zeros((K, 4))
        m[:, [0, 2]] = rng.uniform(0.0, 3.0, (K, 2))
        P = np.eye(4)[None] * rng.uniform(0.05, 1.0, (K, 1, 1))
        for rule in ("capped_sum", "bounded_sum"):
            out_w, _, _, label = merge_groups(w, m, P, 4.0, rule)
            lab = label[np.argsort(-w, kind="stable")]
            assert np.array_equal(np.flatnonzero(group_heads(lab)),
                                  np.unique(lab, return_index=True)[1])
            merged += len(out_w) < K
        key = np.sort(rng.integers(-3, 6, int(rng.integers(0, 30))))
        want = np.unique(key, return_inverse=True, return_counts=True)
        got = sorted_runs(key)
        for a, b in zip(got, want, strict=True):
            assert a.dtype == b.dtype and np.array_equal(a, b.reshape(-1))
    assert merged > 100

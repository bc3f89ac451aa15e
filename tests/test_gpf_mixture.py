"""The GPF's tracks with several Gaussians, pooled misses, JPDA* and the count bound.

References are independent of the code under test: enumeration of every joint choice of
a few Bernoulli targets with masses from scipy's bivariate normal CDF, scipy's truncated
normal for a Gaussian cut to a cell, and enumeration of all existence patterns for the
count bound. Tolerances: round-off, or the rectangle-mass accuracy the grid module
promises (1e-10, tests/test_gpf_grid.py) where masses enter.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import stats
from scipy.stats import multivariate_normal

from mttbench import trackers
from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.trackers.gpf import collapse, condition_on_count_bound, merge_particles
from mttbench.trackers.gpf import tracker as gpf
from mttbench.trackers.gpf.grid import grid_update

GRID = Grid(6, 5, cell_size=1.0)
SENSOR = RayleighGridSensor(p_d=0.5, snr=10.0, looks_per_step=10)
MASS_TOL = 1e-9


def _diag_cov(sx, sy, sv=0.05):
    return np.diag([sx * sx, sv * sv, sy * sy, sv * sv])


def _cell_masses(mean, cov, cells):
    """Mass of the position marginal in each cell (scipy's bivariate normal CDF)."""
    mvn = multivariate_normal(mean[[0, 2]], cov[np.ix_([0, 2], [0, 2])])
    x0, x1, y0, y1 = (b.astype(float) for b in GRID.cell_bounds(np.asarray(cells)))
    return np.array([mvn.cdf([a1, b1], lower_limit=[a0, b0])
                     for a0, a1, b0, b1 in zip(x0, x1, y0, y1, strict=True)])


def _options(w, means, covs, cells):
    """Each Gaussian's options and their priors: absent, elsewhere, or one of ``cells``."""
    opts = []
    for i in range(len(w)):
        mass = _cell_masses(means[i], covs[i], cells)
        o = {"absent": 1 - w[i], "elsewhere": w[i] * (1 - mass.sum())}
        o.update({int(c): w[i] * mc for c, mc in zip(cells, mass, strict=True)})
        opts.append(o)
    return opts


def _ratio(returns, T):
    """``prod over looks p(z | T) / p(z | 0)`` from the sensor's own formula."""
    return float(np.exp(SENSOR.log_likelihood_ratio(np.asarray(returns),
                                                    np.full(len(returns), T)).sum()))


def test_count_bound_conditioning_equals_enumeration():
    """Marginal existence given ``count <= n_max``: all 2^T patterns."""
    rng = np.random.default_rng(4)
    for _ in range(40):
        T = int(rng.integers(1, 9))
        n_max = int(rng.integers(0, T + 1))
        w = rng.uniform(0.0, 1.0, T)
        w[rng.uniform(size=T) < 0.2] = 1.0  # certain tracks too
        num, den = np.zeros(T), 0.0
        for bits in itertools.product([0, 1], repeat=T):
            b = np.array(bits)
            if b.sum() <= n_max:
                p = np.prod(np.where(b == 1, w, 1.0 - w))
                num += p * b
                den += p
        want = num / den if den > 0 else w
        np.testing.assert_allclose(condition_on_count_bound(w, n_max), want, atol=1e-12)


def _combinations(opts, lik_of, jpda_star=False):
    """Every joint choice with its unnormalised posterior weight, ``[(choice, weight)]``.

    ``opts[i]``: ``{option: prior}`` with options ``"absent"``, ``"elsewhere"`` or a cell
    index; ``lik_of(choice)``: the likelihood ratio of a joint choice. ``jpda_star``: keep
    only the most probable of the joint choices that swap detected cells between members
    (every cell option here is a detected cell)."""
    combos = []
    for choice in itertools.product(*[list(o) for o in opts]):
        prior = np.prod([o[c] for o, c in zip(opts, choice, strict=True)])
        if prior > 0:
            combos.append((choice, prior * lik_of(choice)))
    if jpda_star:
        best = {}
        for choice, p in combos:
            takers = tuple(i for i, c in enumerate(choice) if isinstance(c, int))
            key = (takers, tuple(sorted(c for c in choice if isinstance(c, int))),
                   tuple(c for c in choice if not isinstance(c, int)))
            if key not in best or p > best[key][1]:
                best[key] = (choice, p)
        combos = list(best.values())
    return combos


def _enumerate(w, opts, lik_of, jpda_star=False):
    """Posterior existence of each member by listing every joint choice
    (:func:`_combinations`)."""
    combos = _combinations(opts, lik_of, jpda_star)
    total = sum(p for _, p in combos)
    return np.array([sum(p for c, p in combos if c[i] != "absent") / total
                     for i in range(len(w))])


def _posterior_mean(i, means, covs, cells, combos):
    """Member ``i``'s posterior position mean given existence: each bin's share of the
    combinations times the mean of its Gaussian in that bin (scipy ``truncnorm`` per axis,
    diagonal covariances; "elsewhere" is the rest of the Gaussian)."""
    sd = np.sqrt(np.diag(covs[i])[[0, 2]])
    mu = means[i][[0, 2]]
    x0, x1, y0, y1 = (b.astype(float) for b in GRID.cell_bounds(np.asarray(cells)))
    cell_mean = np.array([[stats.truncnorm((a - mu[0]) / sd[0], (b - mu[0]) / sd[0],
                                           loc=mu[0], scale=sd[0]).mean(),
                           stats.truncnorm((c - mu[1]) / sd[1], (d - mu[1]) / sd[1],
                                           loc=mu[1], scale=sd[1]).mean()]
                          for a, b, c, d in zip(x0, x1, y0, y1, strict=True)])
    mass = _cell_masses(means[i], covs[i], cells)
    rest_mean = (mu - (mass[:, None] * cell_mean).sum(axis=0)) / (1 - mass.sum())
    share = dict.fromkeys(["elsewhere", *map(int, cells)], 0.0)
    for choice, p in combos:
        if choice[i] != "absent":
            share[choice[i]] += p
    total = sum(share.values())
    return (share["elsewhere"] * rest_mean
            + sum(share[int(c)] * cell_mean[k] for k, c in enumerate(cells))) / total


def test_pooled_misses_equal_enumeration_with_independent_misses():
    """Two Gaussians share a detected cell and cells that returned nothing. With the misses
    pooled, the posterior is the enumeration in which each member's likelihood in a cell
    without a detection is its own ``l(1)`` (the stated approximation: two targets in one
    such cell count as ``l(1)^2``, not ``l(2)``); the detected cell keeps ``l(T)``."""
    w = np.array([0.7, 0.6])
    means = np.array([[2.3, 0.0, 1.6, 0.0], [2.8, 0.0, 1.4, 0.0]])
    covs = np.stack([_diag_cov(0.4, 0.35), _diag_cov(0.35, 0.45)])
    cells = np.array([7, 8, 13, 14])
    returns = np.array([True, False, False, False])
    res = grid_update(w, means, covs, np.array([-1, -1]), cells, returns, GRID, SENSOR,
                      epsilon=0.0, max_combinations=10**6)
    assert res.max_cluster == 2
    opts = _options(w, means, covs, cells)

    def lik(choice):
        in_hit = sum(c == 7 for c in choice)
        out = _ratio([True], in_hit)
        for c in choice:
            if isinstance(c, int) and c != 7:
                out *= _ratio([False], 1)
        return out

    combos = _combinations(opts, lik)
    np.testing.assert_allclose(res.weights, _enumerate(w, opts, lik), rtol=MASS_TOL)
    # posterior position means given existence
    for i in range(2):
        np.testing.assert_allclose(res.means[i, [0, 2]],
                                   _posterior_mean(i, means, covs, cells, combos), rtol=1e-7)


def test_every_looked_cell_detected_equals_the_exact_enumeration():
    """Without cells that returned nothing, pooling only reorders the options: three
    tracks and four detected cells give the enumeration with every cell's exact ``l(T)``
    (no combination cut), under JPDA*: weights and posterior position means."""
    w = np.array([0.7, 0.5, 0.9])
    means = np.array([[2.3, 0.0, 1.6, 0.0], [2.8, 0.0, 1.4, 0.0], [3.4, 0.0, 2.2, 0.0]])
    covs = np.stack([_diag_cov(0.4, 0.35), _diag_cov(0.35, 0.45), _diag_cov(0.5, 0.5)])
    cells = np.array([7, 8, 14, 15])
    returns = np.ones(4, dtype=bool)
    res = grid_update(w, means, covs, np.full(3, -1), cells, returns, GRID, SENSOR,
                      epsilon=0.0, max_combinations=10**6)
    assert res.max_cluster == 3
    opts = _options(w, means, covs, cells)

    def lik(choice):
        return np.prod([_ratio([True], sum(c == cell for c in choice)) for cell in cells])

    combos = _combinations(opts, lik, jpda_star=True)
    np.testing.assert_allclose(res.weights, _enumerate(w, opts, lik, jpda_star=True),
                               rtol=MASS_TOL)
    for i in range(3):
        np.testing.assert_allclose(res.means[i, [0, 2]],
                                   _posterior_mean(i, means, covs, cells, combos), rtol=1e-7)


def test_jpda_star_keeps_one_of_the_swapped_assignments():
    """Two equal broad tracks, two detected cells. The update (JPDA*) equals the
    enumeration that keeps the more probable of the two swapped assignments; the tracks
    then sit on different cells, while the plain rule (every assignment kept) would put
    both on the same blend."""
    w = np.array([0.9, 0.9])
    mean = np.array([3.0, 0.0, 2.5, 0.0])
    means = np.stack([mean, mean + [0.05, 0, 0, 0]])  # a nearly equal pair, not a tie
    covs = np.stack([_diag_cov(1.5, 1.5)] * 2)
    cells = np.array([7, 10])  # (1, 1) and (4, 1)
    returns = np.array([True, True])
    star = grid_update(w, means, covs, np.full(2, -1), cells, returns, GRID, SENSOR,
                       epsilon=0.0, max_combinations=10**6)
    opts = _options(w, means, covs, cells)

    def lik(choice):
        return np.prod([_ratio([True], sum(c == cell for c in choice)) for cell in (7, 10)])

    np.testing.assert_allclose(star.weights, _enumerate(w, opts, lik, jpda_star=True),
                               rtol=MASS_TOL)
    for i in range(2):
        np.testing.assert_allclose(
            star.means[i, [0, 2]],
            _posterior_mean(i, means, covs, cells, _combinations(opts, lik, jpda_star=True)),
            rtol=1e-7)
    plain = [_posterior_mean(i, means, covs, cells, _combinations(opts, lik))
             for i in range(2)]
    assert abs(plain[0][0] - plain[1][0]) < 0.2  # every assignment kept: coalesced
    assert abs(star.means[0, 0] - star.means[1, 0]) > 1.0  # one on each side


def test_split_component_is_the_gaussian_cut_to_the_detected_cell():
    """A broad track, one detected cell and two cells that returned nothing. With
    ``split_share`` the detected cell's part becomes its own component: its weight within
    the track is the posterior probability of the cell, its mean the truncated normal's
    (scipy ``truncnorm`` per axis, diagonal covariance); the mixture's moments equal the
    single moment-matched Gaussian's."""
    w = np.array([0.8])
    mean = np.array([2.2, 0.0, 2.1, 0.0])
    cov = _diag_cov(1.2, 0.9)
    cells = np.array([29, 7, 8])  # (5, 4) detected; (1, 1), (2, 1) missed
    returns = np.array([True, False, False])
    kw = dict(epsilon=0.0)
    one = grid_update(w, mean[None], cov[None], np.array([-1]), cells, returns, GRID, SENSOR,
                      **kw)
    mix = grid_update(w, mean[None], cov[None], np.array([-1]), cells, returns, GRID, SENSOR,
                      split_share=0.05, **kw)
    assert len(mix.means) == 2 and np.array_equal(mix.owner, [0, 0])
    np.testing.assert_allclose(mix.weights, one.weights, rtol=1e-12)
    mass = _cell_masses(mean, cov, cells)
    lik = np.array([_ratio([True], 1), _ratio([False], 1), _ratio([False], 1)])
    p_cell = mass[0] * lik[0] / ((1 - mass.sum()) + (mass * lik).sum())
    cell_row = int(np.argmin(np.abs(mix.means[:, 0] - 5.5)))
    assert mix.alpha[cell_row] == pytest.approx(p_cell, rel=MASS_TOL)
    tx = stats.truncnorm((5 - mean[0]) / 1.2, (6 - mean[0]) / 1.2, loc=mean[0], scale=1.2)
    ty = stats.truncnorm((4 - mean[2]) / 0.9, (5 - mean[2]) / 0.9, loc=mean[2], scale=0.9)
    np.testing.assert_allclose(mix.means[cell_row, [0, 2]], [tx.mean(), ty.mean()], rtol=1e-9)
    np.testing.assert_allclose(mix.covs[cell_row, [0, 2], [0, 2]], [tx.var(), ty.var()],
                               rtol=1e-7)
    m, P = collapse(mix.alpha, mix.means, mix.covs, mix.owner, 1)
    np.testing.assert_allclose(m, one.means, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(P, one.covs, rtol=1e-8, atol=1e-12)


def _fixed_count_model(n_initial=2):
    return TrackingModel(GRID, Dynamics(wna_intensity=1e-3),
                         BirthDeath(n_random_initial=n_initial, birth_rate=0.0,
                                    birth_velocity_std=0.1), SENSOR)


def test_fixed_count_model_never_holds_more_tracks_than_targets():
    """Three confident tracks under a model with two targets and no arrivals: after an
    update the weights are the enumeration's marginals given ``count <= 2``, and the
    undetected field then holds ``2 - sum w`` (here nearly nothing)."""
    t = trackers.make("gpf")
    t.reset(_fixed_count_model(2), np.random.default_rng(0))
    w = np.array([0.95, 0.9, 0.8])
    means = np.array([[0.5, 0, 0.5, 0], [3.5, 0, 2.5, 0], [5.5, 0, 4.5, 0]])
    t.set_particles(w, means, np.stack([_diag_cov(0.2, 0.2)] * 3))
    t.update(Looks(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool)))
    got = t.particles[0]
    num, den = np.zeros(3), 0.0
    for bits in itertools.product([0, 1], repeat=3):
        b = np.array(bits)
        if b.sum() <= 2:
            p = np.prod(np.where(b == 1, w, 1 - w))
            num, den = num + p * b, den + p
    np.testing.assert_allclose(got, num / den, rtol=1e-12)
    assert got.sum() < 2.0
    t.predict()
    survival = 1.0  # no death floor on a model without arrivals: the model's p_s = 1
    assert t._u.total() == pytest.approx(max(2.0 - got.sum() * survival, 0.0), rel=1e-9)


def test_tracks_sharing_a_detection_report_it_once():
    """Two tracks, each a narrow component on the same cell (its heavier part) and another
    elsewhere: the heavier track reports the shared cell, the other its own component."""
    t = trackers.make("gpf")
    t.reset(_fixed_count_model(2), np.random.default_rng(0))
    narrow = _diag_cov(0.29, 0.29)
    m = np.array([[2.5, 0, 2.5, 0], [0.5, 0, 0.5, 0], [2.5, 0, 2.5, 0], [5.5, 0, 4.5, 0]])
    t._set(np.array([0.99, 0.95]), np.array([0, 0, 1, 1]), np.array([0.6, 0.4, 0.7, 0.3]),
           m, np.stack([narrow] * 4))
    est = t.estimate()
    np.testing.assert_allclose(est.states[:, [0, 2]], [[2.5, 2.5], [5.5, 4.5]])


def test_a_confident_narrow_track_is_not_merged_into_a_broad_one():
    """A narrow confident track inside a broad confident one (squared Mahalanobis distance
    of the pair ~0.3, far below the threshold 4). The tracker's rule on a model without
    arrivals (``bounded_sum``: a group's weights may not exceed 1) keeps both, and so does
    ``capped_sum`` with the Bhattacharyya distance, the rule of a track's components (its
    shape term, 2 ln(det S_bar / sqrt(det S_1 det S_2)), is ~14 here); ``capped_sum`` with
    the Mahalanobis distance merges them into one."""
    model = _fixed_count_model(3)
    P = np.stack([_diag_cov(0.3, 0.3), _diag_cov(3.0, 3.0)])
    m = np.array([[2.5, 0, 2.5, 0], [3.2, 0, 2.9, 0]])
    w0 = np.array([0.97, 0.95])
    t = trackers.make("gpf")
    t.reset(model, np.random.default_rng(0))
    t.set_particles(w0, m, P)
    t.update(Looks(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool)))
    w, means, _ = t.particles
    np.testing.assert_allclose(sorted(w), [0.95, 0.97])
    wb, _, _ = merge_particles(w0, m, P, 4.0, "capped_sum", "bhattacharyya")
    np.testing.assert_allclose(sorted(wb), [0.95, 0.97])
    wm, _, _ = merge_particles(w0, m, P, 4.0, "capped_sum", "mahalanobis")
    assert len(wm) == 1 and wm[0] == 1.0


def test_a_far_detection_starts_a_track_instead_of_moving_a_broad_one(monkeypatch):
    """A broad confident track, and one target the model expects that no track holds
    (two targets, no arrivals): after a predict the field holds ``2 - sum w`` spread over
    the cells. A detection far from the track's mean is better explained by a new target
    than by the track: the candidate's posterior (enumeration over the track's options
    absent / in the detected cell / elsewhere and the candidate's absent / present, masses
    from scipy) makes a new track, and the broad track keeps its existence. (The track's
    occupancy of the cell, ~2e-5, is below ``INTERACTION_THRESHOLD``, which would update
    the two apart, and the default cut drops a combination of probability below 1e-4;
    with both at 0 the joint update is exact.)"""
    monkeypatch.setattr(gpf, "INTERACTION_THRESHOLD", 0.0)
    t = trackers.make("gpf", epsilon=0.0)
    t.reset(_fixed_count_model(2), np.random.default_rng(0))
    t.set_particles([0.99], np.array([[1.0, 0, 1.0, 0]]), _diag_cov(1.5, 1.5)[None])
    t.predict()
    w0, m0, P0 = t.particles
    u = t._u.at([29])[0]
    assert u == pytest.approx((2.0 - w0[0]) / GRID.n_cells, rel=1e-9)
    t.update(Looks(np.array([29]), np.array([True])))  # cell (5, 4)
    mass = _cell_masses(m0[0], P0[0], [29])[0]
    opts = [{"absent": 1 - w0[0], 29: w0[0] * mass, "elsewhere": w0[0] * (1 - mass)},
            {"absent": 1 - u, 29: u}]
    want = _enumerate(np.array([w0[0], u]), opts,
                      lambda ch: _ratio([True], sum(c == 29 for c in ch)))
    w, m, _ = t.particles
    assert len(w) == 2 and want[1] > 0.9
    np.testing.assert_allclose(w, want, rtol=MASS_TOL)
    np.testing.assert_allclose(m[1, [0, 2]], [5.5, 4.5])  # the new track: the cell centre
    assert abs(m[0, 0] - m0[0, 0]) < 0.01  # the broad track did not move to the detection

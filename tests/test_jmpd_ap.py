"""``jmpd-ap`` (:mod:`mttbench.trackers.jmpd.ap`) against exact answers.

* :mod:`.cell_proposal`: Gaussian cell masses against scipy (in the far tails too), draws
  from the Gaussian truncated to a cell against ``scipy.stats.truncnorm``, the window of
  cell masses against the in-grid mass.
* :mod:`.partitions`: the AP clustering rule, K-means partition sorting, slot merging.
* the tracker's update on worlds small enough to enumerate: one target (removal, births
  after a removal, positions and Rao-Blackwellised velocities, a predicted mean folded
  at a wall), two coupled targets (the joint law of their cells), births of arrivals and
  of undetected initial targets (none in an occupied cell), the fixed-count rule, and
  the estimate.

Tolerances. Float round-off is named where used. Monte Carlo comparisons: every
frequency is within ``Z_MAX = 4.5`` standard errors of its exact probability. The
standard error is computed exactly from the enumeration: the importance-sampling
variance of the self-normalised estimate, ``(1/N) sum_x q(x) (w(x)/W)^2 (1_A(x) - p_A)^2``
over the proposal ``q`` and weights ``w`` of the tracker's stated algorithm, plus
``p_A (1 - p_A) / N`` for the resampling (multinomial resampling's variance; the
systematic resampling used is typically well below it). Distribution shapes:
Kolmogorov-Smirnov at ``KS_ALPHA = 1e-3``. Every test uses a fixed seed.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import stats
from scipy.sparse.csgraph import connected_components
from scipy.special import log_ndtr

from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.specs import resolve_scenarios
from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.trackers.jmpd import ap as ap_module
from mttbench.trackers.jmpd.ap import JMPDAPTracker
from mttbench.trackers.jmpd.cell_proposal import axis_window, interval_mass, truncated_normal
from mttbench.trackers.jmpd.partitions import cluster_slots, merge_slots, sort_slots

Z_MAX = 4.5      # Monte Carlo band, in standard errors (two-sided ~7e-6 per comparison)
KS_ALPHA = 1e-3  # Kolmogorov-Smirnov level
N_MC = 20000     # particles in the exactness tests


def _rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed))


# ======================================================================== cell_proposal
def _reference_mass(mean, sd, lo, hi):
    """``P(lo <= x < hi)``, ``x ~ N(mean, sd^2)``, from scipy's log tails: the smaller
    tail of the two bounds, ``T(a) (1 - T(b) / T(a))`` with ``T`` the log-cdf or
    log-sf, so that nothing cancels however far out the interval lies."""
    za, zb = (lo - mean) / sd, (hi - mean) / sd
    out = np.empty(np.broadcast(za, zb).shape)
    za, zb = np.broadcast_to(za, out.shape), np.broadcast_to(zb, out.shape)
    up, down = za > 0, zb < 0
    mid = ~(up | down)
    la, lb = stats.norm.logsf(za[up]), stats.norm.logsf(zb[up])
    out[up] = np.exp(la) * -np.expm1(lb - la)
    la, lb = log_ndtr(zb[down]), log_ndtr(za[down])
    out[down] = np.exp(la) * -np.expm1(lb - la)
    out[mid] = stats.norm.cdf(zb[mid]) - stats.norm.cdf(za[mid])
    return out


def test_interval_mass_matches_scipy_in_the_body():
    """Intervals around the mean: ``Phi(b) - Phi(a)`` from scipy, to round-off
    (``rtol = 1e-12``: the masses here are at least 1e-3)."""
    rng = _rng(1)
    mean = rng.normal(0.0, 3.0, 500)
    sd = rng.uniform(0.2, 4.0, 500)
    lo = mean + sd * rng.uniform(-3.0, 0.5, 500)
    hi = lo + sd * rng.uniform(0.05, 3.0, 500)
    ref = stats.norm.cdf((hi - mean) / sd) - stats.norm.cdf((lo - mean) / sd)
    assert ref.min() > 1e-3
    np.testing.assert_allclose(interval_mass(mean, sd, lo, hi), ref, rtol=1e-12, atol=0)


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_interval_mass_keeps_relative_precision_in_the_far_tails(side):
    """Cells 8 to 30 standard deviations from the mean, above and below it: relative
    error below 1e-9 against scipy's log tails. The naive ``Phi(b) - Phi(a)`` is 0 (or
    all rounding) above the mean from about 8.3 sd on, which this test rejects; a
    check that the test can tell: the naive form fails it above the mean."""
    rng = _rng(2)
    n = 400
    mean = rng.uniform(-50.0, 50.0, n)
    sd = rng.uniform(0.1, 5.0, n)
    start = rng.uniform(8.0, 30.0, n)  # in sd
    width = rng.uniform(0.02, 2.0, n)  # in sd
    if side > 0:
        lo, hi = mean + sd * start, mean + sd * (start + width)
    else:
        lo, hi = mean - sd * (start + width), mean - sd * start
    ref = _reference_mass(mean, sd, lo, hi)
    assert (ref > 0).all() and ref.max() < 1e-14  # genuinely far out
    np.testing.assert_allclose(interval_mass(mean, sd, lo, hi), ref, rtol=1e-9, atol=0)
    if side > 0:  # the same comparison rejects the naive form
        naive = stats.norm.cdf((hi - mean) / sd) - stats.norm.cdf((lo - mean) / sd)
        assert not np.allclose(naive, ref, rtol=1e-9, atol=0)


def test_truncated_normal_draws_stay_in_their_interval():
    """Every draw lies in ``[lo, hi)``: body, far tails on both sides, intervals of a
    few ulps, intervals beyond the representable mass (40 sd), uniforms at 0 and near 1."""
    rng = _rng(3)
    n = 20000
    mean = rng.normal(0.0, 10.0, n)
    sd = rng.uniform(0.05, 3.0, n)
    start = rng.choice([-45.0, -20.0, -3.0, -0.5, 0.0, 2.0, 9.0, 40.0], n) + rng.uniform(0, 1, n)
    width = rng.choice([1e-12, 1e-3, 0.3, 2.0, 50.0], n)
    lo = mean + sd * start
    hi = lo + np.maximum(sd * width, np.spacing(np.abs(lo)) * 4)
    u = rng.random(n)
    u[:50], u[50:100] = 0.0, np.nextafter(1.0, 0.0)
    x = truncated_normal(mean, sd, lo, hi, u)
    assert np.isfinite(x).all()
    assert (x >= lo).all() and (x < hi).all()


@pytest.mark.parametrize("a, b", [(-0.7, 1.3), (8.0, 9.0), (30.0, 31.0), (-31.0, -29.5)],
                         ids=["body", "tail-8sd", "tail-30sd", "lower-tail-30sd"])
def test_truncated_normal_matches_scipy_truncnorm(a, b):
    """4000 draws of ``N(2, 1.5^2)`` truncated to ``[2 + 1.5 a, 2 + 1.5 b)`` against
    ``scipy.stats.truncnorm`` by a Kolmogorov-Smirnov test at ``KS_ALPHA``; in the tail
    a uniform draw across the cell (mean near the middle) is rejected by far."""
    rng = _rng(4)
    n, mean, sd = 4000, 2.0, 1.5
    lo, hi = mean + sd * a, mean + sd * b
    x = truncated_normal(np.full(n, mean), np.full(n, sd), np.full(n, lo), np.full(n, hi),
                         rng.random(n))
    law = stats.truncnorm(a, b, loc=mean, scale=sd)
    assert stats.kstest(x, law.cdf).pvalue > KS_ALPHA
    if a > 5:
        assert abs(x.mean() - law.mean()) < 0.1 * (hi - lo)  # not uniform over the cell


def test_axis_window_sums_to_the_in_grid_mass():
    """Windows wide enough to cover 6 sd beyond the mean's cell: the masses sum to the
    in-grid mass (the Gaussian mass beyond 6 sd is 1e-9 per side, hence ``rtol = 5e-9``),
    ``inside`` is the scipy in-grid mass; indices are the clipped mean's cell plus the
    offsets, ``-1`` (with mass 0) off the grid; each in-grid mass is its cell's mass."""
    rng = _rng(5)
    n_axis, cs = 7, 2.5
    shape = (40, 3)
    mean = rng.uniform(-3.0 * cs, (n_axis + 3) * cs, shape)
    sd = rng.uniform(0.1, 1.5, shape) * cs
    half = int(math.ceil(6.0 * sd.max() / cs)) + 1
    index, mass, inside = axis_window(mean, sd, n_axis, cs, half)
    assert index.shape == mass.shape == shape + (2 * half + 1,) and inside.shape == shape
    ref_inside = _reference_mass(mean, sd, 0.0, n_axis * cs)
    np.testing.assert_allclose(inside, ref_inside, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(mass.sum(axis=-1), inside, rtol=5e-9, atol=1e-300)
    centre = np.clip(np.floor(mean / cs), 0, n_axis - 1).astype(int)
    expected = centre[..., None] + np.arange(-half, half + 1)
    off = (expected < 0) | (expected >= n_axis)
    assert off.any() and (~off).any()
    np.testing.assert_array_equal(index, np.where(off, -1, expected))
    assert (mass[off] == 0.0).all()
    cell_mass = _reference_mass(mean[..., None], sd[..., None], expected * cs,
                                (expected + 1) * cs)
    np.testing.assert_allclose(mass[~off], cell_mass[~off], rtol=1e-9, atol=1e-300)


def test_axis_window_width_mode_covers_4_sd():
    """The tracker's windows (``width`` cells from the one holding ``mean - 4 sd``,
    shifted to stay in the grid, ``width = floor(8 sd_max / cell) + 2`` capped at the
    grid): every in-grid cell meeting ``[mean - 4 sd, mean + 4 sd]`` is in the window,
    indices are consecutive and in the grid, and each mass is its cell's Gaussian mass
    (``rtol = 1e-9``, far tails included)."""
    rng = _rng(25)
    n_axis, cs = 9, 1.5
    for sd_max in (0.1, 0.6, 2.0):
        shape = (300,)
        mean = rng.uniform(-2 * cs, (n_axis + 2) * cs, shape)
        sd = rng.uniform(0.2, 1.0, shape) * sd_max * cs
        width = min(int(math.floor(8 * sd_max)) + 2, n_axis)
        index, mass, inside = axis_window(mean, sd, n_axis, cs, 0, width=width)
        assert index.shape == mass.shape == shape + (width,)
        first = np.clip(np.floor((mean - 4 * sd) / cs), 0, n_axis - width).astype(int)
        np.testing.assert_array_equal(index, first[:, None] + np.arange(width))
        lo = np.floor(np.clip(mean - 4 * sd, 0, None) / cs)
        hi = np.floor(np.clip(mean + 4 * sd, None, n_axis * cs * (1 - 1e-15)) / cs)
        meets = lo <= hi  # the 4 sd interval reaches into the grid
        assert meets.any()
        assert (index[meets, 0] <= lo[meets]).all() and (index[meets, -1] >= hi[meets]).all()
        ref = _reference_mass(mean[:, None], sd[:, None], index * cs, (index + 1) * cs)
        np.testing.assert_allclose(mass, ref, rtol=1e-9, atol=1e-300)
        if width == n_axis:
            np.testing.assert_allclose(mass.sum(axis=-1), inside, rtol=1e-12, atol=1e-300)


# =========================================================================== partitions
def test_cluster_slots_threshold_is_strict_distance():
    """Two centres at ``gamma - eps`` are one cluster, at ``gamma + eps`` two."""
    gamma, eps = 2.5, 1e-9
    active = np.array([True, True])
    for d, n_expected in ((gamma - eps, 1), (gamma + eps, 2)):
        centres = np.array([[1.0, 4.0], [1.0 + d * 0.6, 4.0 + d * 0.8]])  # |diff| = d
        clusters = cluster_slots(centres, active, gamma)
        assert len(clusters) == n_expected, d
        assert sorted(np.concatenate(clusters).tolist()) == [0, 1]


def test_cluster_slots_transitive_closure_coupling_and_inactive_slots():
    """A-B and B-C closer than gamma, A-C far: one cluster. Far slots whose holdings
    are coupled: linked. An inactive slot links nothing and appears nowhere."""
    gamma = 2.0
    # slots 0, 1, 2 a chain; 3 alone; 4 and 5 far apart; 6 inactive between 3 and 7;
    # 7 alone
    centres = np.array([[0.0, 0.0], [1.5, 0.0], [3.0, 0.0], [20.0, 0.0],
                        [40.0, 0.0], [45.0, 0.0], [21.5, 0.0], [23.0, 0.0]])
    active = np.array([True, True, True, True, True, True, False, True])
    assert [c.tolist() for c in cluster_slots(centres, active, gamma)] == \
        [[0, 1, 2], [3], [4], [5], [7]]
    coupled = np.zeros((8, 8), dtype=bool)
    coupled[4, 5] = coupled[5, 4] = True
    assert [c.tolist() for c in cluster_slots(centres, active, gamma, coupled)] == \
        [[0, 1, 2], [3], [4, 5], [7]]
    # a coupling with the inactive slot 6 links nothing
    coupled[3, 6] = coupled[6, 3] = True
    assert [c.tolist() for c in cluster_slots(centres, active, gamma, coupled)] == \
        [[0, 1, 2], [3], [4, 5], [7]]
    # the inactive slot 6 would chain 3 and 7 (distances 1.5) if it counted
    active[6] = True
    assert [c.tolist() for c in cluster_slots(centres, active, gamma)] == \
        [[0, 1, 2], [3, 6, 7], [4], [5]]


def test_cluster_slots_equals_connected_components():
    """Random worlds: the clusters are the connected components (scipy) of the graph
    linking active slots closer than gamma or coupled."""
    rng = _rng(6)
    for _ in range(60):
        T = int(rng.integers(1, 15))
        centres = rng.uniform(0, 12, (T, 2))
        active = rng.random(T) < 0.75
        coupled = np.triu(rng.random((T, T)) < 0.05, k=1)
        coupled |= coupled.T
        gamma = float(rng.uniform(0.5, 3.0))
        s = np.flatnonzero(active)
        d = np.linalg.norm(centres[s, None] - centres[None, s], axis=-1)
        if s.size:
            _, lab = connected_components((d < gamma) | coupled[np.ix_(s, s)],
                                          directed=False)
            expected = sorted(sorted(s[lab == k].tolist()) for k in np.unique(lab))
        else:
            expected = []
        got = [c.tolist() for c in cluster_slots(centres, active, gamma, coupled)]
        assert got == expected  # also: each sorted, ordered by first slot


def test_separated_targets_with_wide_posteriors_stay_separate_clusters():
    """``default`` from its declared targets (three, 5-7 cells apart, each looked at once
    every six steps and detected half of those times, so their posteriors widen to 1-3
    cells): their centres stay more than ``cluster_distance`` apart, so they are sampled
    as independent partitions at almost every step, whatever ``N``. Linking slots
    whose particles' extents overlap put all three in one cluster on 59-87% of the steps
    (seeds 0-3, N = 1,000-16,000)."""
    scenario = resolve_scenarios(["default"])[0]
    one_cluster = 0
    for seed in (0, 1):
        tracker = JMPDAPTracker(n_particles=2000, init_fraction=1.0)
        for _ in play(scenario, tracker, seed, n_steps=60):
            one_cluster += tracker.largest_cluster == 3
    assert one_cluster <= 12  # of 120 steps


def _sorting_world(seed: int):
    """600 particles, 6 slots: slots 1, 2, 4 one cluster of three well separated targets
    (30% of the particles miss one of them; their empty slot holds a stale position
    anywhere), slot 0 a cluster of its own, slots 3, 5 outside every cluster."""
    rng = _rng(seed)
    N, T = 600, 6
    true = np.array([[0.0, 0.0], [5.0, 50.0], [30.0, 0.0], [-7.0, 9.0], [0.0, 30.0], [9.0, 9.0]])
    pos = true[None] + rng.normal(0, 0.5, (N, T, 2))
    vel = rng.normal(0, 1, (N, T, 2))
    vvar = rng.uniform(0.1, 2, (N, T, 2))
    valid = np.ones((N, T), dtype=bool)
    gap = rng.random(N) < 0.3  # these particles miss one target of the cluster
    valid[gap, rng.choice([1, 2, 4], gap.sum())] = False
    # an empty slot keeps a stale position anywhere (it must cost nothing)
    pos[~valid] = rng.uniform(-60, 60, ((~valid).sum(), 2))
    return pos, vel, vvar, valid


def test_sort_slots_undoes_random_permutations():
    """40% of the particles get a random non-identity permutation of the cluster's
    slots (positions, velocities, variances and validity together); one sort restores
    every array exactly, counts the permuted particles, and leaves other slots alone."""
    pos, vel, vvar, valid = _sorting_world(7)
    rng = _rng(8)
    N = pos.shape[0]
    cluster = np.array([1, 2, 4])
    perms = np.array(list(itertools.permutations(range(3)))[1:])
    hit = np.flatnonzero(rng.random(N) < 0.4)
    src = cluster[perms[rng.integers(0, len(perms), hit.size)]]
    arrays = [a.copy() for a in (pos, vel, vvar, valid)]
    for a in arrays:
        a[hit[:, None], cluster[None, :]] = a[hit[:, None], src]
    assert not np.array_equal(arrays[0], pos)
    changed = sort_slots(arrays[0], arrays[3], [np.array([0]), cluster], arrays, iterations=2)
    for a, ref in zip(arrays, (pos, vel, vvar, valid), strict=True):
        np.testing.assert_array_equal(a, ref)
    assert changed == hit.size


def test_sort_slots_leaves_a_sorted_world_alone():
    pos, vel, vvar, valid = _sorting_world(9)
    arrays = [a.copy() for a in (pos, vel, vvar, valid)]
    assert sort_slots(arrays[0], arrays[3], [np.array([1, 2, 4])], arrays) == 0
    for a, ref in zip(arrays, (pos, vel, vvar, valid), strict=True):
        np.testing.assert_array_equal(a, ref)


def _targets(pos, vel, valid, i):
    """The multiset of particle ``i``'s targets (sorted rows of position and velocity)."""
    rows = np.concatenate([pos[i, valid[i]], vel[i, valid[i]]], axis=1)
    return sorted(map(tuple, rows))


def test_merge_slots_moves_only_into_empty_kept_slots():
    """Slots 1 (held by more particles) and 3 have nearly equal means; 0 and 2 are far.
    Particles holding 3 but not 1 move their target into 1; those holding both keep
    both; slots 0 and 2 are untouched; no particle's multiset of targets changes."""
    rng = _rng(10)
    N, T = 500, 4
    centres = np.array([[0.0, 0.0], [10.0, 10.0], [20.0, 0.0], [10.1, 10.0]])
    pos = centres[None] + rng.normal(0, 0.3, (N, T, 2))
    vel = rng.normal(0, 1, (N, T, 2))
    vvar = rng.uniform(0.1, 2, (N, T, 2))
    r = rng.random(N)
    valid = np.ones((N, T), dtype=bool)
    valid[:, 1] = r < 0.6          # 60% hold slot 1
    valid[:, 3] = (r > 0.45)       # 55% hold slot 3; 15% hold both
    valid[rng.random(N) < 0.2, 0] = False
    before = [_targets(pos, vel, valid, i) for i in range(N)]
    orig = [a.copy() for a in (pos, vel, vvar, valid)]
    move = valid[:, 3] & ~valid[:, 1]
    arrays = [pos, vel, vvar, valid]
    moved = merge_slots(pos, valid, arrays, distance=0.5)
    assert moved == move.sum() > 0
    np.testing.assert_array_equal(valid[:, 1], orig[3][:, 1] | orig[3][:, 3])
    np.testing.assert_array_equal(valid[:, 3], orig[3][:, 3] & orig[3][:, 1])
    for a, o in zip(arrays, orig, strict=True):
        np.testing.assert_array_equal(a[move, 1], o[move, 3])
        np.testing.assert_array_equal(a[~move][:, [0, 1, 2]], o[~move][:, [0, 1, 2]])
        np.testing.assert_array_equal(a[:, [0, 2]], o[:, [0, 2]])
    assert [_targets(pos, vel, valid, i) for i in range(N)] == before
    # means farther apart than the distance: nothing moves
    arrays = [a.copy() for a in orig]
    assert merge_slots(arrays[0], arrays[3], arrays, distance=0.05) == 0
    for a, o in zip(arrays, orig, strict=True):
        np.testing.assert_array_equal(a, o)


# ================================================================ the tracker, exactly
SENSOR = RayleighGridSensor(p_d=0.6, snr=3.0, looks_per_step=4)


def _model(nx: int, q=(0.5, 0.1, 0.2), qy=(0.04, 0.0, 0.01), sensor=SENSOR,
           **birth_death) -> TrackingModel:
    """A ``nx x 1`` grid of unit cells; per-axis noise ``[[q11, q12], [q12, q22]]``."""
    Q = ((q[0], q[1], 0.0, 0.0), (q[1], q[2], 0.0, 0.0),
         (0.0, 0.0, qy[0], qy[1]), (0.0, 0.0, qy[1], qy[2]))
    return TrackingModel(grid=Grid(nx, 1, 1.0), dynamics=Dynamics(tau=1.0, q_matrix=Q),
                         birth_death=BirthDeath(**birth_death), sensor=sensor)


def _looks(cells, returns) -> Looks:
    return Looks(np.asarray(cells, dtype=np.int64), np.asarray(returns, dtype=bool))


def _lam(sensor: RayleighGridSensor, looks: Looks, n_cells: int, n_max: int) -> np.ndarray:
    """``Lambda_c(n)``, shape ``(n_cells, n_max + 1)``: the product over the looks at
    ``c`` of ``p(z | n) / p(z | 0)``, straight from ``p_d(n)``."""
    lam = np.ones((n_cells, n_max + 1))
    for c, z in zip(looks.cells, looks.returns, strict=True):
        pd = sensor.detection_probability(np.arange(n_max + 1))
        p = pd if z else 1.0 - pd
        lam[c] *= p / p[0]
    return lam


def _cell_masses(mean: float, var: float, nx: int) -> np.ndarray:
    """Predictive masses of the cells ``[c, c + 1)``, renormalised to the grid."""
    edges = np.arange(nx + 1.0)
    g = np.diff(stats.norm.cdf(edges, loc=mean, scale=math.sqrt(var)))
    return g / g.sum()


def _check_frequencies(labels: np.ndarray, q: np.ndarray, w: np.ndarray, coarse=None):
    """Frequencies of ``labels`` (ints) against the exact posterior ``p ∝ q w`` of the
    fine categories, pooled by ``coarse`` (fine -> label; identity by default): within
    ``Z_MAX`` standard errors (module docstring). Returns ``p`` per label."""
    n = labels.size
    q, w = np.asarray(q, float) / np.sum(q), np.asarray(w, float)
    coarse = np.arange(q.size) if coarse is None else np.asarray(coarse)
    W = float((q * w).sum())
    post = q * w / W
    n_labels = int(coarse.max()) + 1
    p = np.bincount(coarse, weights=post, minlength=n_labels)
    ind = coarse[None, :] == np.arange(n_labels)[:, None]  # (labels, fine)
    var_is = (q[None] * (w / W)[None] ** 2 * (ind - p[:, None]) ** 2).sum(axis=1) / n
    se = np.sqrt(var_is + p * (1 - p) / n)
    freq = np.bincount(labels, minlength=n_labels) / n
    assert freq.size == n_labels, "a label outside the enumerated categories"
    z = np.abs(freq - p) / np.maximum(se, 1e-300)
    assert (z <= Z_MAX).all(), {"freq": freq.round(4), "exact": p.round(4),
                                "z": z.round(2)}
    return p


def _tracker(model, seed, **params) -> JMPDAPTracker:
    t = JMPDAPTracker(**params)
    t.reset(model, _rng(seed))
    return t


# one target, every particle at the same state: x predictive N(2.0, 0.8) over 4 cells,
# y predictive N(0.5, 0.09) inside the single row
RHO, M, S = np.array([1.5, 0.5]), np.array([0.5, 0.0]), np.array([0.3, 0.05])
BIRTH_STD = 0.7
ONE_TARGET_LOOKS = {
    "hit-and-misses": ([2, 1, 1, 3], [True, False, False, False]),
    "misses-only": ([1, 3, 3, 0], [False, False, False, False]),
}


@pytest.mark.parametrize("looks_id", list(ONE_TARGET_LOOKS))
def test_one_target_removal_move_and_birth_are_exact(looks_id):
    """One target, removal ``beta = 0.2`` (a parameter), a 4 x 1 grid, the predictive
    ``N(rho + tau m, tau^2 s + q11)`` over three to four cells. The tracker's posterior
    after one update (module docstring steps 2, 4, 5; the fixed-count model returns a
    removed target to the undetected initial targets, so a removed target may be born
    again at a detected cell ``d``): moved to cell ``c`` ``∝ (1 - beta) gamma_c
    Lambda_c(1)``, removed and not born ``∝ beta sum_{c != d} Lambda_c(1) / J`` (the
    removed target is somewhere else, unseen: ``(1 - pi) f`` with ``f`` the mean of
    ``Lambda_c(1)`` over the cells not detected), removed and born in ``d``
    ``∝ beta pi Lambda_d(1)``, ``pi = 1/J``. Born targets are told apart by their
    velocity variance (the birth law's). Then: positions inside a cell follow the
    truncated predictive (KS), velocity means and variances the RB update exactly
    (``atol = 1e-12``), born targets the birth law."""
    cells, returns = ONE_TARGET_LOOKS[looks_id]
    nx, beta = 4, 0.2
    model = _model(nx, initial_states=((1.5, 0.5, 0.5, 0.0),), birth_velocity_std=BIRTH_STD)
    t = _tracker(model, 11, n_particles=N_MC, removal_probability=beta)
    t.pos[:, 0], t.vel[:, 0], t.vvar[:, 0], t.valid[:, 0] = RHO, M, S, True
    t._k = 0  # the update of step 1 (step 0 is the prior, where nobody is removed)
    t.predict()
    looks = _looks(cells, returns)
    t.update(looks)

    # exact enumeration
    q11, q12, q22 = np.array([0.5, 0.04]), np.array([0.1, 0.0]), np.array([0.2, 0.01])
    mean, psi = RHO + M, S + q11
    gamma = _cell_masses(mean[0], psi[0], nx)
    lam = _lam(SENSOR, looks, nx, 1)[:, 1]
    det = np.flatnonzero(lam > 1.0)
    pi = 1.0 / nx
    f = lam[lam <= 1.0].mean()  # the removed target unseen in the cells not detected
    # fine categories: 0 removed (not born), 1 born in d, 2 + c moved to c
    q_move = np.concatenate([[beta], (1 - beta) * gamma * lam])
    if det.size:
        (d,) = det
        b = pi * lam[d] / (1 - pi + pi * lam[d])
        q = np.concatenate([[q_move[0] * (1 - b), q_move[0] * b], q_move[1:]])
        w = np.concatenate([[(1 - pi) / (1 - b) * f, pi * lam[d] / b], np.ones(nx)])
    else:
        q = np.concatenate([[q_move[0], 0.0], q_move[1:]])
        w = np.concatenate([[f, 1.0], np.ones(nx)])

    n_held = t.valid.sum(axis=1)
    assert n_held.max() <= 1
    slot = np.argmax(t.valid, axis=1)
    rows = np.arange(N_MC)
    x, y = t.pos[rows, slot, 0], t.pos[rows, slot, 1]
    vel, vvar = t.vel[rows, slot], t.vvar[rows, slot]
    born = (n_held == 1) & np.all(vvar == BIRTH_STD**2, axis=1)
    moved = (n_held == 1) & ~born
    cell = np.floor(x).astype(int)
    labels = np.where(n_held == 0, 0, np.where(born, 1, 2 + cell))
    p = _check_frequencies(labels, q, w)
    assert p[1] > 0.02 or not det.size  # the birth branch is exercised

    # moved targets: truncated predictive inside the cell, RB velocity update
    sd = np.sqrt(psi)
    c = int(np.argmax(np.bincount(cell[moved], minlength=nx)))
    in_c = moved & (cell == c)
    law_x = stats.truncnorm((c - mean[0]) / sd[0], (c + 1 - mean[0]) / sd[0],
                            loc=mean[0], scale=sd[0])
    assert stats.kstest(x[in_c], law_x.cdf).pvalue > KS_ALPHA
    law_y = stats.truncnorm(-mean[1] / sd[1], (1 - mean[1]) / sd[1], loc=mean[1], scale=sd[1])
    assert stats.kstest(y[moved], law_y.cdf).pvalue > KS_ALPHA
    gain = (S + q12) / psi
    rb_mean = M + gain * (np.stack([x, y], axis=1) - mean)
    np.testing.assert_allclose(vel[moved], rb_mean[moved], rtol=0, atol=1e-12)
    np.testing.assert_allclose(vvar[moved], np.broadcast_to(S + q22 - (S + q12) ** 2 / psi,
                                                            vvar[moved].shape),
                               rtol=0, atol=1e-12)
    if det.size:  # born: uniform in the detected cell, velocity from the birth law
        assert (cell[born] == det[0]).all()
        assert (vel[born] == 0.0).all()
        assert stats.kstest(x[born] - det[0], "uniform").pvalue > KS_ALPHA
    else:
        assert not born.any()


def test_predicted_mean_beyond_a_wall_is_folded():
    """Under ``reflect`` a predicted mean beyond a wall is folded back and its velocity
    mean mirrored (module docstring): ``rho + tau m = 2.7 + 0.7 = 3.4`` on a 3-cell
    grid becomes ``2.6`` with velocity mean ``-0.7``. Misses only, no removal: the
    cells are ``∝ gamma_c Lambda_c(1)`` with ``gamma`` from ``N(2.6, Psi)`` in the grid
    (not ``N(3.4, Psi)`` truncated), equal weights, positions in the busiest cell from
    that truncated predictive (KS), velocity means ``-0.7 + K (x - 2.6)``, ``K = (tau s +
    q12) / Psi`` unchanged (reflecting both position and velocity keeps their covariance)."""
    nx = 3
    model = _model(nx, initial_states=((2.7, 0.7, 0.5, 0.0),))
    t = _tracker(model, 26, n_particles=N_MC, removal_probability=0.0)
    t.pos[:, 0], t.vel[:, 0], t.vvar[:, 0], t.valid[:, 0] = (2.7, 0.5), (0.7, 0.0), \
        (0.1, 0.05), True
    t.predict()
    looks = _looks([2, 0, 1], [False, False, False])
    t.update(looks)
    assert t.ess == pytest.approx(N_MC, rel=1e-9) and t.valid[:, 0].all()
    psi = 0.1 + 0.5
    gamma = _cell_masses(2.6, psi, nx)
    lam = _lam(SENSOR, looks, nx, 1)[:, 1]
    x = t.pos[:, 0, 0]
    cell = np.floor(x).astype(int)
    _check_frequencies(cell, gamma * lam, np.ones(nx))
    sd = math.sqrt(psi)
    in2 = cell == 2
    law = stats.truncnorm((2 - 2.6) / sd, (3 - 2.6) / sd, loc=2.6, scale=sd)
    assert stats.kstest(x[in2], law.cdf).pvalue > KS_ALPHA
    gain = (0.1 + 0.1) / psi  # (tau s + q12) / Psi: the reflection keeps the covariance
    np.testing.assert_allclose(t.vel[:, 0, 0], -0.7 + gain * (x - 2.6), rtol=0, atol=1e-12)


def test_leaving_the_workspace_under_die():
    """Boundary ``die``: the predictive's mass beyond the workspace leaves. One target
    predicted at ``N(2.6, 0.6)`` in x on a 3 x 1 grid (30% of the mass beyond the right
    wall) and ``N(0.5, 0.09)`` in y (10% outside the single row), removal ``beta =
    0.1``, misses only: dead ``∝ beta + (1 - beta) m_out``, cell ``c`` ``∝ (1 - beta)
    gamma_c Lambda_c(1)`` with the unnormalised masses ``gamma_c = g_x(c) g_y(0)``
    (docstring step 2), ``m_out = 1 - sum_c gamma_c``; equal weights."""
    nx, beta = 3, 0.1
    model = _model(nx, initial_states=((2.0, 0.6, 0.5, 0.0),), boundary="die")
    # the particles hold the one target (init_fraction 1: none left undetected); one
    # that leaves or is removed is dead (walls that kill), so the weights stay equal
    t = _tracker(model, 28, n_particles=N_MC, removal_probability=beta, init_fraction=1.0)
    t.pos[:, 0], t.vel[:, 0], t.vvar[:, 0], t.valid[:, 0] = (2.0, 0.5), (0.6, 0.0), \
        (0.1, 0.05), True
    t._k = 0  # step 1 (step 0 is the prior, where nobody is removed)
    t.predict()
    looks = _looks([2, 0], [False, False])
    t.update(looks)
    assert t.ess == pytest.approx(N_MC, rel=1e-9)
    g_x = np.diff(stats.norm.cdf(np.arange(nx + 1.0), loc=2.6, scale=math.sqrt(0.6)))
    g_y = np.diff(stats.norm.cdf([0.0, 1.0], loc=0.5, scale=math.sqrt(0.05 + 0.04)))
    gamma = g_x * g_y
    m_out = 1 - gamma.sum()
    assert m_out > 0.35
    lam = _lam(SENSOR, looks, nx, 1)[:, 1]
    q = np.concatenate([[beta + (1 - beta) * m_out], (1 - beta) * gamma * lam])
    x = t.pos[:, 0, 0]
    labels = np.where(t.valid[:, 0], 1 + np.floor(x).astype(int), 0)
    assert t.valid.sum(axis=1).max() <= 1
    _check_frequencies(labels, q, np.ones(nx + 1))


def _two_target_tracker(seed, sort_iterations):
    nx = 4
    sensor = RayleighGridSensor(p_d=0.5, snr=1.5, looks_per_step=5)
    model = _model(nx, q=(0.3, 0.0, 0.1), sensor=sensor,
                   initial_states=((1.2, 0.2, 0.5, 0.0), (2.5, -0.4, 0.5, 0.0)))
    t = _tracker(model, seed, n_particles=N_MC, removal_probability=0.0,
                 sort_iterations=sort_iterations)
    t.pos[:, 0], t.vel[:, 0], t.vvar[:, 0] = (1.2, 0.5), (0.2, 0.0), (0.1, 0.05)
    t.pos[:, 1], t.vel[:, 1], t.vvar[:, 1] = (2.5, 0.5), (-0.4, 0.0), (0.3, 0.05)
    t.valid[:, :2] = True
    looks = _looks([1, 2, 2, 3, 1], [True, True, False, False, True])
    # exact: predictive N(1.4, 0.4) and N(2.1, 0.6)
    g0, g1 = _cell_masses(1.4, 0.4, nx), _cell_masses(2.1, 0.6, nx)
    lam = _lam(sensor, looks, nx, 2)
    # sequential proposal (module docstring, step 2) and its weight prod_t Z_t
    cells = list(itertools.product(range(nx), repeat=2))
    q, w = [], []
    z0 = float((g0 * lam[:, 1]).sum())
    for c0, c1 in cells:
        ratio = lam[:, 1].copy()  # Lambda(n + 1) / Lambda(n) given slot 0 in c0
        ratio[c0] = lam[c0, 2] / lam[c0, 1]
        z1 = float((g1 * ratio).sum())
        q.append(g0[c0] * lam[c0, 1] / z0 * g1[c1] * ratio[c1] / z1)
        w.append(z0 * z1)
    # the posterior q w must be the joint prod gamma * prod_u Lambda_u(m_u)
    joint = np.array([g0[a] * g1[b] * (lam[a, 2] if a == b else lam[a, 1] * lam[b, 1])
                      for a, b in cells])
    np.testing.assert_allclose(np.array(q) * np.array(w) / np.dot(q, w), joint / joint.sum(),
                               rtol=1e-12)
    return t, looks, cells, np.array(q), np.array(w)


def test_two_coupled_targets_joint_cells_are_exact():
    """Two targets one cluster apart (predicted centres 0.7 cells apart), ``beta = 0``, a
    fixed count of 2, sorting off (slot labels kept): the joint law of (cell of slot 0,
    cell of slot 1) is ``∝ gamma_0(c0) gamma_1(c1) prod_u Lambda_u(m_u)`` with
    ``Lambda(2) != Lambda(1)^2`` (snr 1.5, two looks hit the shared cells). The
    proposal is the locally optimal one, so the weights after recombination are equal
    (ESS = N to round-off)."""
    t, looks, cells, q, w = _two_target_tracker(12, sort_iterations=0)
    t.predict()
    t.update(looks)
    assert t.n_clusters == 1 and t.largest_cluster == 2
    # one cluster: the draw's weight prod_t Z_t is spent in the recombination, and the
    # remaining weight p(z | X) / pi(z | X) is 1 (docstring step 5): equal weights
    assert t.ess == pytest.approx(N_MC, rel=1e-9)
    assert (t.valid.sum(axis=1) == 2).all() and t.valid[:, :2].all()
    c = np.floor(t.pos[:, :2, 0]).astype(int)
    p = _check_frequencies(c[:, 0] * 4 + c[:, 1], q, w)
    assert p[[5, 10]].sum() > 0.1  # both in one cell is common


def test_two_coupled_targets_unordered_cells_survive_sorting():
    """As above with the default partition sorting (which may relabel the two within a
    particle): the unordered pair of cells keeps its exact law."""
    t, looks, cells, q, w = _two_target_tracker(13, sort_iterations=2)
    t.predict()
    t.update(looks)
    held = t.valid.sum(axis=1)
    assert (held == 2).all()
    c = np.sort(np.floor(np.where(t.valid[..., None], t.pos, np.inf)[..., 0]), axis=1)[:, :2]
    c = c.astype(int)
    pairs = {pr: k for k, pr in enumerate(sorted({tuple(sorted(x)) for x in cells}))}
    coarse = [pairs[tuple(sorted(x))] for x in cells]
    _check_frequencies(np.array([pairs[(a, b)] for a, b in c]), q, w, coarse)


def _born_fraction(t, cell):
    c = np.where(t.valid, np.floor(t.pos[..., 0]).astype(int), -1)
    return (c == cell).any(axis=1), c


@pytest.mark.parametrize("p_s", [1.0, 0.9])
def test_births_of_arrivals(p_s):
    """No initial targets, arrivals ``mu = 0.6`` per step (the model's birth rate,
    ``alpha = mu / J`` per cell) on a 2 x 1 grid, no particle holding a target; the
    fraction born in cell ``c`` is ``pi Lambda / (1 - pi + pi Lambda)``, ``pi = 1 -
    exp(-u_c)``, binomial (the weights are equal).

    Arrivals start at step 1 (step 0 holds the initial targets only): at step 0 nobody
    is born at a hit. At step 1, a hit at cell 0 and a miss at cell 1: ``u_0 = alpha``;
    births in cell 0 only, uniform in it, with the birth law's velocity, all in one slot.
    Steps 1 and 2, a miss at cell 0 then hits at both cells: by docstring step 6 (``u <-
    p_s u + alpha`` per step, ``u <- u l(0)`` per look, ``l(0) = (1 - p_d) / (1 - p_f)``)
    ``u_0 = p_s alpha l(0) + alpha`` and ``u_1 = p_s alpha + alpha``."""
    mu, nx = 0.6, 2
    model = _model(nx, birth_rate=mu, survival_probability=p_s, birth_velocity_std=BIRTH_STD)
    alpha = mu / nx
    l0 = (1 - SENSOR.p_d) / (1 - SENSOR.p_f)
    t = _tracker(model, 13, n_particles=N_MC)
    t.predict()
    t.update(_looks([0, 1], [True, True]))
    assert not t.valid.any()  # step 0: no arrivals yet
    # step 1: hit at 0, miss at 1
    t = _tracker(model, 14, n_particles=N_MC)
    t._k = 0
    t.predict()
    looks = _looks([0, 1], [True, False])
    t.update(looks)
    lam = _lam(SENSOR, looks, nx, 1)[:, 1]
    pi = 1 - math.exp(-alpha)
    b = pi * lam[0] / (1 - pi + pi * lam[0])
    in0, c = _born_fraction(t, 0)
    assert not (c == 1).any() and (t.valid.sum(axis=1) <= 1).all()
    _check_frequencies(in0.astype(int), [1 - b, b], [1, 1])
    x = t.pos[t.valid][:, 0]
    assert stats.kstest(x, "uniform").pvalue > KS_ALPHA
    assert (t.vel[t.valid] == 0).all() and (t.vvar[t.valid] == BIRTH_STD**2).all()
    assert (t.valid.any(axis=0)).sum() == 1  # all born in a cell this step share a slot

    # steps 1 and 2: the lazy intensity
    t = _tracker(model, 15, n_particles=N_MC)
    t._k = 0
    t.predict()
    t.update(_looks([0], [False]))
    assert not t.valid.any()
    t.predict()
    looks = _looks([0, 1], [True, True])
    t.update(looks)
    lam = _lam(SENSOR, looks, nx, 1)[:, 1]
    u = np.array([p_s * alpha * l0 + alpha, p_s * alpha + alpha])
    pi = -np.expm1(-u)
    b = pi * lam / (1 - pi + pi * lam)
    for cell in (0, 1):
        born, _ = _born_fraction(t, cell)
        _check_frequencies(born.astype(int), [1 - b[cell], b[cell]], [1, 1])


@pytest.mark.parametrize("first_looks", [None, ([0, 0], [False, False])])
def test_births_of_undetected_initial_targets(first_looks):
    """One random initial target (``n_random_initial = 1``), ``p_s = 1``, no arrivals, a
    3 x 1 grid, particles start empty: a hit at cell 0 and a miss at cell 1 give births
    in cell 0 with ``b = pi Lambda / (1 - pi + pi Lambda)``, ``pi = 1 - (1 - v_0 / sum
    v)^1``: ``1/J`` at the first update, ``l(0)^2 / (l(0)^2 + 2)`` after a first step
    with two misses at cell 0 (``v <- v l(0)`` per look, ``l(0) = (1 - p_d) / (1 -
    p_f)``); no births elsewhere. The particles not born keep the target undetected
    elsewhere, unseen by this step's looks: weight ``f = sum_{c != 0} v_c Lambda_c(1) /
    sum_{c != 0} v_c`` against 1 for those born."""
    nx = 3
    model = _model(nx, n_random_initial=1)
    t = _tracker(model, 16, n_particles=N_MC, arrival_rate=0.0)
    v = np.full(nx, 1.0 / nx)
    if first_looks is not None:
        t.predict()
        t.update(_looks(*first_looks))
        assert not t.valid.any()
        v[0] *= ((1 - SENSOR.p_d) / (1 - SENSOR.p_f)) ** 2
    t.predict()
    looks = _looks([0, 1], [True, False])
    t.update(looks)
    lam = _lam(SENSOR, looks, nx, 1)[:, 1]
    pi = v[0] / v.sum()
    b = pi * lam[0] / (1 - pi + pi * lam[0])
    f = (v[1:] * lam[1:]).sum() / v[1:].sum()
    born, c = _born_fraction(t, 0)
    assert ((c == 1) | (c == 2)).sum() == 0 and (t.valid.sum(axis=1) <= 1).all()
    _check_frequencies(born.astype(int), [1 - b, b], [f, 1])


def test_no_birth_in_an_occupied_cell():
    """Two initial targets (fixed count 2), particles holding one, predicted inside cell 1
    (sd 0.07): one initial target remains undetected, ``pi = 1 - (1 - 1/J)^1``. Hits at
    cells 1 and 3: cell 1 is occupied, so nobody is born there (docstring step 4); in
    cell 3 the births have the proposal fraction ``pi Lambda / (1 - pi + pi Lambda)``,
    weighted 1 against ``f`` for the particles whose target stays undetected (the mean
    of ``Lambda_c(1)`` over the cells not detected: 0, 2, 4)."""
    nx = 5
    model = _model(nx, q=(0.005, 0.0, 0.01),
                   initial_states=((1.5, 0.0, 0.5, 0.0), (3.5, 0.0, 0.5, 0.0)))
    t = _tracker(model, 27, n_particles=N_MC, removal_probability=0.0)
    t.pos[:, 0], t.vel[:, 0], t.vvar[:, 0], t.valid[:, 0] = (1.5, 0.5), 0.0, 1e-4, True
    t.predict()
    looks = _looks([1, 3, 4], [True, True, False])
    t.update(looks)
    c = np.where(t.valid, np.floor(t.pos[..., 0]).astype(int), -1)
    assert ((c == 1).sum(axis=1) == 1).all()  # the held target, never a newborn beside it
    assert not np.isin(c, [0, 2, 4]).any()
    lam = _lam(SENSOR, looks, nx, 1)[:, 1]
    pi = 1.0 / nx
    b = pi * lam[3] / (1 - pi + pi * lam[3])
    f = lam[[0, 2, 4]].mean()
    _check_frequencies((c == 3).any(axis=1).astype(int), [1 - b, b], [f, 1])


def test_fixed_count_rule(monkeypatch):
    """A fixed count of 1 (one initial target, ``p_s = 1``, no arrivals), half the
    particles holding it in slot 0 at cell 1, half in slot 1 at cell 8 of a 10 x 1 grid
    (two clusters, with the coupling of exclusive slots switched off): recombination by
    clusters gives some particles both. Before the final resampling some particles hold
    two (the rule is exercised); after it none holds more than one."""
    model = _model(10, initial_states=((5.0, 0.0, 0.5, 0.0),))
    t = _tracker(model, 17, n_particles=4000, removal_probability=0.0)
    half = t.pos.shape[0] // 2
    t.pos[:half, 0], t.pos[half:, 1] = (1.5, 0.5), (8.5, 0.5)
    t.vel[:] = 0.0
    t.vvar[:] = 0.01
    t.valid[:half, 0] = t.valid[half:, 1] = True
    seen = []
    real = ap_module.systematic_resample

    def spy(w, u):
        seen.append((t.valid.sum(axis=1).copy(), np.asarray(w).copy()))
        return real(w, u)

    monkeypatch.setattr(ap_module, "systematic_resample", spy)
    monkeypatch.setattr(ap_module.JMPDAPTracker, "_coupled_links", lambda self: None)
    t.predict()
    t.update(_looks([1, 8, 5], [True, True, True]))
    assert t.n_clusters == 2
    counts, w = seen[-1]  # the final resampling sees the particles after births
    assert (counts > 1).any() and (counts <= 1).any()
    assert (w[counts > 1] == 0).all()
    assert t.valid.sum(axis=1).max() == 1


# ============================================================================ estimate
def test_estimate_is_the_mean_count_and_holder_averages():
    """Two targets in separate clusters, removal 0.35, a hit near one and misses at the
    other (fixed count 2): ``count`` is the mean number of valid slots after the update
    plus the undetected targets (a removed target returns to them: ``2 - T_i`` per
    particle), so exactly 2; the states are the ``round(mean valid slots)`` most-held
    slots, each averaged over the particles holding it."""
    model = _model(12, initial_states=((2.0, 0.3, 0.5, 0.0), (9.0, -0.2, 0.5, 0.0)))
    t = _tracker(model, 18, n_particles=3000, removal_probability=0.35)
    t.pos[:, 0], t.vel[:, 0], t.vvar[:, 0] = (2.0, 0.5), (0.3, 0.0), (0.2, 0.05)
    t.pos[:, 1], t.vel[:, 1], t.vvar[:, 1] = (9.0, 0.5), (-0.2, 0.0), (0.2, 0.05)
    t.valid[:, :2] = True
    t._k = 0  # step 1 (nobody is removed at step 0)
    t.predict()
    t.update(_looks([2, 9, 9, 10], [True, False, False, False]))
    est = t.estimate()
    N = t.valid.shape[0]
    held = t.valid.sum(axis=0)
    count = held.sum() / N
    assert est.count == pytest.approx(2.0, rel=1e-12)
    assert est.count == pytest.approx(count + t.undetected_mass, rel=1e-12)
    assert t.count_mean == est.count
    assert 1.0 < count < 2.0 and count != round(count)  # a genuine mean
    n_hat = int(round(count))
    order = sorted(np.flatnonzero(held), key=lambda s: -held[s])[:n_hat]
    expected = []
    for s in order:
        m = t.valid[:, s]
        p, v = t.pos[m, s].mean(axis=0), t.vel[m, s].mean(axis=0)
        expected.append([p[0], v[0], p[1], v[1]])
    assert est.states.shape == (n_hat, 4)
    np.testing.assert_allclose(est.states, np.array(expected), rtol=1e-12, atol=1e-12)


def test_undetected_share_stays_normalised_over_many_sweeps():
    """The running total of the undetected initial targets' weights ``v`` (updated by
    differences, ``v <- v (1 - p_d)`` per look) must stay the exact sum: with every cell
    looked each step the total halves per step and would lose every digit to
    cancellation in ~50 steps (the shares ``v_c / sum v`` of the births then meaningless).
    After 300 sweeps of a 4 x 1 grid, the shares sum to 1 within 1e-9."""
    nx = 4
    model = _model(nx, n_random_initial=2)
    t = _tracker(model, 8, n_particles=50, arrival_rate=0.0)
    cells = np.arange(nx)
    for k in range(300):
        t.predict()
        t.update(Looks(np.r_[cells, cells[:1]], np.zeros(nx + 1, dtype=bool)))
        total = t._undetected.dense("v").sum()
        assert abs(t._v_total - total) <= 1e-9 * total, (k, t._v_total, total)


@pytest.mark.parametrize("floor", [0.0, 1e-3, 0.05])
def test_position_noise_floor_sets_the_least_predictive_variance(floor):
    """The predictive position variance is ``tau^2 s + max(q11, floor cell^2)`` per axis:
    the model's q11 (1e-6 here) below the floor, unchanged above it (q11 = 0.04 on y)."""
    model = _model(5, q=(1e-6, 0.0, 1e-6), qy=(0.04, 0.0, 1e-6))
    t = _tracker(model, 3, n_particles=4, position_noise_floor=floor)
    t.valid[:, 0] = True
    t.pos[:, 0] = [2.5, 0.5]
    t.vvar[:, 0] = [0.01, 0.02]
    t.predict()
    _, psi = t._pred
    np.testing.assert_allclose(psi[:, 0, 0], 0.01 + max(1e-6, floor), rtol=1e-12)
    np.testing.assert_allclose(psi[:, 0, 1], 0.02 + max(0.04, floor), rtol=1e-12)


# ============================================================ the model's existence law
def test_nobody_dies_at_step_0_and_the_count_decays_by_p_s():
    """Step 0 is the prior (the simulator's first step holds the initial targets): a
    declared target held by every particle (``init_fraction = 1``), ``p_s = 0.6``, survives
    step 0 in every particle; one random initial target that is never looked at counts
    ``p_s^k`` at step ``k`` (``count = E[T]`` counts the undetected targets), exactly."""
    model = _model(6, initial_states=((2.5, 0.0, 0.5, 0.0),), survival_probability=0.6)
    t = _tracker(model, 30, n_particles=2000, init_fraction=1.0)
    t.predict()
    t.update(_looks([5], [False]))
    assert t.valid[:, 0].all()
    model = _model(6, n_random_initial=1, survival_probability=0.6)
    t = _tracker(model, 31, n_particles=500)
    for k in range(4):
        t.predict()
        t.update(_looks([], []))
        assert t.estimate().count == pytest.approx(0.6 ** k, rel=1e-12)


def test_a_target_let_die_stays_dead():
    """One declared target, ``p_s = 0.5``, no arrivals: a particle that lets it die at
    step 1 keeps no undetected initial target (``r_i = 0``), so a hit far from the track
    at step 2 gives no birth in it; the particles holding the target keep ``r_i = 0`` too
    (they found their one target), so no particle ever holds two."""
    model = _model(12, q=(0.005, 0.0, 0.001), initial_states=((1.5, 0.0, 0.5, 0.0),),
                   survival_probability=0.5)
    t = _tracker(model, 32, n_particles=4000, init_fraction=1.0)
    for looks in (([1], [True]), ([1], [True]), ([9, 9], [True, True])):
        t.predict()
        t.update(_looks(*looks))
        assert (t._remaining() == 0).all()
        assert t.valid.sum(axis=1).max() <= 1
    cells = np.where(t.valid, np.floor(t.pos[..., 0]).astype(int), -1)
    assert not (cells == 9).any()


def test_coupled_slots_are_exclusive_or_dependent_holdings():
    """``coupled_slots``: two slots held by disjoint halves of the particles (one target
    in two labels) are coupled; two held independently (90% each, drawn so) are not; a
    slot held nowhere couples with nothing; a slot held by 3 particles that never hold
    slot 2 with it is coupled to slot 2 (too few for the statistical rule)."""
    from mttbench.trackers.jmpd.partitions import coupled_slots

    rng = np.random.default_rng(40)
    N = 4000
    valid = np.zeros((N, 6), dtype=bool)
    valid[: N // 2, 0] = True
    valid[N // 2:, 1] = True
    valid[:, 2] = rng.random(N) < 0.9
    valid[:, 3] = rng.random(N) < 0.9
    c = coupled_slots(valid)
    assert c[0, 1] and c[1, 0]
    assert not c[2, 3] and not c[3, 2]
    assert not c[4].any() and not c[:, 4].any()
    assert not c.diagonal().any()
    rare = np.flatnonzero(~valid[:, 2])[:3]
    valid[rare, 5] = True
    c = coupled_slots(valid)
    assert c[5, 2] and c[2, 5]


def test_one_random_target_in_clutter_is_never_held_twice():
    """One random initial target, no arrivals, ``p_s = 0.98``, false alarms in about one
    look in ten (``single-clutter``): the model never holds two targets, and neither
    may any particle after any step, whatever its births and recombinations."""
    from mttbench.benchmarks.engine.loop import play
    from mttbench.scenarios import get

    sc = get("single-clutter")
    t = JMPDAPTracker(n_particles=1500)
    for rec in play(sc, t, 1, n_steps=15):
        held = t.valid.sum(axis=1)
        assert held.max() <= 1, rec.k
        assert 0.0 <= rec.estimate.count <= 1.0 + 1e-9


def test_an_undetected_target_shifts_each_count_row_by_a_bernoulli():
    """``P_c(t)`` with the undetected targets: each row is the law of ``N + B``, ``N`` the
    particles' count there and ``B ~ Bernoulli(pi)`` independent, ``pi = 1 - (1 - pi_init)
    (1 - pi_arr)``, the last column "that many or more". Reference: numpy's convolution of
    the two laws, its tail folded into the last column."""
    rng = _rng(3)
    P = rng.dirichlet(np.ones(5), size=6)  # every column, the top two included, > 0
    pi_init, pi_arr = rng.uniform(0, 0.6, 6), rng.uniform(0, 0.3, 6)
    got = ap_module._with_undetected(P, (pi_init[None], pi_arr[None]))
    for row, want_from, a, b in zip(got, P, pi_init, pi_arr, strict=True):
        pi = 1 - (1 - a) * (1 - b)
        full = np.convolve(want_from, [1 - pi, pi])
        want = np.r_[full[:4], full[4:].sum()]
        np.testing.assert_allclose(row, want, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got.sum(axis=1), 1.0, rtol=1e-12)


@pytest.mark.parametrize("compiled", [True, False])
def test_the_predictive_is_the_kalman_prediction_of_a_known_position(compiled):
    """Per slot and axis the position is known and the velocity ``N(m, s)``: the predictive
    of the position is the first entry of ``F P F^T + Q`` with ``P = [[0, 0], [0, s]]``,
    i.e. mean ``rho + tau m`` and variance ``tau^2 s + q11``, with the model's own ``F`` and
    ``Q`` at a time step other than 1 (numpy's pass and the compiled one)."""
    tau, q = 2.5, 0.02
    model = TrackingModel(grid=Grid(40, 30, 1.0), dynamics=Dynamics(tau=tau, wna_intensity=q),
                          birth_death=BirthDeath(n_random_initial=2), sensor=SENSOR)
    tr = _tracker(model, 0, n_particles=50, t_max=4)
    if not compiled:
        tr.uses_compiled_kernels = False
    elif not tr.uses_compiled_kernels:
        pytest.skip("no compiled kernels here")
    rng = _rng(1)
    shape = tr.pos.shape
    tr.pos[:] = rng.uniform(10.0, 20.0, shape)
    tr.vel[:] = rng.normal(0.0, 0.3, shape)
    tr.vvar[:] = rng.uniform(0.01, 0.2, shape)
    tr.valid[:] = True
    pos, vel, vvar = tr.pos.copy(), tr.vel.copy(), tr.vvar.copy()
    tr.predict()
    rhohat, psi = tr._pred
    F, Q = model.dynamics.F, model.dynamics.Q
    for axis, (i, j) in enumerate([(0, 1), (2, 3)]):
        P = np.zeros(vvar.shape[:2] + (2, 2))
        P[..., 1, 1] = vvar[..., axis]
        Fa, Qa = F[np.ix_([i, j], [i, j])], Q[np.ix_([i, j], [i, j])]
        P_pred = Fa @ P @ Fa.T + Qa
        np.testing.assert_allclose(psi[..., axis], P_pred[..., 0, 0], rtol=1e-12)
        np.testing.assert_allclose(rhohat[..., axis], pos[..., axis] + tau * vel[..., axis],
                                   rtol=1e-12)

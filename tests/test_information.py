"""The expected Renyi gain of looks, against brute force on explicit particle sets."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.stats import entropy

from mttbench.benchmarks.engine.information import (
    binomial_likelihood,
    expected_gain,
    gain_of_looks,
    greedy_looks,
)
from mttbench.scenarios.model import RayleighGridSensor

TOL = 1e-12  # brute force vs closed form: same maths, different order of operations


def assert_close(a, b, tol=TOL):
    np.testing.assert_allclose(a, b, rtol=0.0, atol=tol)


# ------------------------------------------------------------------ brute force
def renyi_divergence(post: np.ndarray, prior: np.ndarray, alpha: float) -> float:
    """``D_alpha(post || prior)`` over a discrete space, directly from the definition."""
    keep = prior > 0
    post, prior = post[keep], prior[keep]
    if alpha == 1.0:
        nz = post > 0
        return float(np.sum(post[nz] * np.log(post[nz] / prior[nz])))
    return float(np.log(np.sum(post**alpha * prior ** (1.0 - alpha))) / (alpha - 1.0))


def particle_set(rng: np.random.Generator, n_particles: int, n_cells: int, max_targets: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Explicit joint configurations: per particle, the number of targets in every cell.

    Returns per-particle cell counts ``(N, n_cells)`` and weights ``(N,)``.
    """
    n_targets = rng.integers(0, max_targets + 1, size=n_particles)
    counts = np.zeros((n_particles, n_cells), dtype=np.int64)
    for i, n in enumerate(n_targets):
        for cell in rng.integers(0, n_cells, size=n):
            counts[i, cell] += 1
    w = rng.random(n_particles)
    return counts, w / w.sum()


def brute_force_gain(counts: np.ndarray, w: np.ndarray, p_detect, n_looks: int,
                     alpha: float) -> np.ndarray:
    """Per cell: expectation over all ``2^n`` look sequences of ``D_alpha`` between the
    posterior and the prior *over the particles* (Bayes on each particle)."""
    n_cells = counts.shape[1]
    gains = np.zeros(n_cells)
    for c in range(n_cells):
        pd = p_detect(counts[:, c])  # (N,)
        for seq in itertools.product([0, 1], repeat=n_looks):
            lik = np.ones_like(w)
            for z in seq:
                lik = lik * (pd if z else 1.0 - pd)
            pz = float(np.sum(w * lik))
            if pz == 0.0:
                continue
            post = w * lik / pz
            gains[c] += pz * renyi_divergence(post, w, alpha)
    return gains


def count_distribution(counts: np.ndarray, w: np.ndarray, n_counts: int) -> np.ndarray:
    """``P_c(t)`` from the particles, last column "that many or more"."""
    t = np.minimum(counts, n_counts - 1)
    P = np.zeros((counts.shape[1], n_counts))
    for c in range(counts.shape[1]):
        np.add.at(P[c], t[:, c], w)
    return P


SENSOR = RayleighGridSensor(p_d=0.5, snr=10.0)


# ---------------------------------------------------------------------- single look
@pytest.mark.parametrize("alpha", [0.1, 0.5, 0.999, 1.0, 2.0])
def test_single_look_gain_equals_particle_brute_force(alpha):
    rng = np.random.default_rng(1)
    counts, w = particle_set(rng, 40, 6, 5)
    n_counts = int(counts.max()) + 1  # no truncation: p_d(t) is exact in every column
    P = count_distribution(counts, w, n_counts)
    pd_cols = SENSOR.detection_probability(np.arange(n_counts))
    assert_close(expected_gain(P, pd_cols, alpha),
                 brute_force_gain(counts, w, SENSOR.detection_probability, 1, alpha))


def test_truncated_last_column_uses_its_index():
    """With "that many or more" in the last column, the gain is that of a particle set
    whose counts are capped at the last column (p_d evaluated at the column index)."""
    rng = np.random.default_rng(2)
    counts, w = particle_set(rng, 30, 4, 6)
    n_counts = 3
    P = count_distribution(counts, w, n_counts)
    pd_cols = SENSOR.detection_probability(np.arange(n_counts))

    def capped(t):
        return SENSOR.detection_probability(np.minimum(t, n_counts - 1))

    assert_close(expected_gain(P, pd_cols, 0.5), brute_force_gain(counts, w, capped, 1, 0.5))


def test_outcome_table_and_detection_vector_agree():
    rng = np.random.default_rng(3)
    P = rng.dirichlet(np.ones(4), size=7)
    pd = SENSOR.detection_probability(np.arange(4))
    assert_close(expected_gain(P, pd, 0.5), expected_gain(P, np.stack([1 - pd, pd]), 0.5))


# ------------------------------------------------------------------------- limits
def mutual_information(P: np.ndarray, lik: np.ndarray) -> np.ndarray:
    """``I(z; t) = H(z) - H(z | t)`` per cell with scipy's entropy (nats)."""
    pz = P @ lik.T  # (n_cells, n_outcomes)
    h_z = entropy(pz, axis=1)
    h_z_given_t = P @ entropy(lik, axis=0)
    return h_z - h_z_given_t


def test_alpha_one_is_mutual_information_and_the_limit():
    rng = np.random.default_rng(4)
    P = rng.dirichlet(np.ones(5), size=20)
    pd = SENSOR.detection_probability(np.arange(5))
    lik = np.stack([1 - pd, pd])
    mi = mutual_information(P, lik)
    assert np.all(mi > 1e-3)  # a non-trivial case
    assert_close(expected_gain(P, pd, 1.0), mi)
    # D_alpha is smooth in alpha: within 1e-6 of alpha = 1 the gain moves by O(1e-6 * MI)
    for a in (1.0 - 1e-6, 1.0 + 1e-6):
        np.testing.assert_allclose(expected_gain(P, pd, a), mi, rtol=1e-5, atol=0.0)
    # and it really converges (error shrinks with |alpha - 1|)
    err = [np.max(np.abs(expected_gain(P, pd, 1 - d) - mi)) for d in (1e-1, 1e-2, 1e-3)]
    assert err[0] > err[1] > err[2]


@pytest.mark.parametrize("alpha", [0.5, 1.0, 3.0])
@pytest.mark.parametrize("n_looks", [1, 2, 5])
def test_certain_count_has_zero_gain(alpha, n_looks):
    P = np.eye(4)  # cell c holds exactly c targets
    pd = SENSOR.detection_probability(np.arange(4))
    np.testing.assert_array_equal(gain_of_looks(P, pd, n_looks, alpha), 0.0)


@pytest.mark.parametrize("alpha", [0.05, 0.5, 0.9, 1.0, 1.5, 4.0])
def test_gains_are_non_negative(alpha):
    rng = np.random.default_rng(5)
    P = rng.dirichlet(np.full(4, 0.3), size=500)
    P[rng.random(P.shape) < 0.3] = 0.0  # exact zeros, then renormalise
    P[P.sum(axis=1) == 0, 0] = 1.0
    P /= P.sum(axis=1, keepdims=True)
    P[:10] = np.eye(4)[rng.integers(0, 4, size=10)]  # some certain cells
    pd = SENSOR.detection_probability(np.arange(4))
    for n in (1, 3):
        g = gain_of_looks(P, pd, n, alpha)
        assert np.all(np.isfinite(g))
        assert g.min() >= -1e-15


class _ExtremeSensor(RayleighGridSensor):
    """A Rayleigh sensor whose detection probability is replaced by a fixed table."""

    def detection_probability(self, n_targets):
        table = np.array([0.0, 1.0, 1.0, 0.3])
        return table[np.minimum(np.asarray(n_targets, dtype=np.int64), 3)]


@pytest.mark.parametrize("alpha", [0.5, 1.0, 2.0])
def test_no_nan_with_zero_probabilities_and_degenerate_sensor(alpha):
    sensor = _ExtremeSensor()
    pd = sensor.detection_probability(np.arange(4))  # 0, 1, 1, 0.3: p(z|t) has zeros
    P = np.array([
        [1.0, 0.0, 0.0, 0.0],   # certain: no gain
        [0.5, 0.5, 0.0, 0.0],   # z reveals t exactly: gain = D_alpha of a perfect look
        [0.0, 0.5, 0.5, 0.0],   # p_d = 1 for both: uninformative
        [0.0, 0.0, 0.0, 1.0],
        [0.25, 0.25, 0.25, 0.25],
    ])
    for n in (1, 2, 4):
        g = gain_of_looks(P, pd, n, alpha)
        assert np.all(np.isfinite(g))
        # a particle per count value with weight P_c(t) is the brute-force set here
        for c in range(len(P)):
            keep = P[c] > 0
            counts = np.nonzero(keep)[0][:, None]
            want = brute_force_gain(counts, P[c, keep], sensor.detection_probability, n, alpha)
            assert_close(g[c], want[0])
    g1 = gain_of_looks(P, pd, 1, alpha)
    assert g1[0] == 0.0 and g1[2] == 0.0 and g1[3] == 0.0
    # perfect look on a 50/50 prior: the posterior is a point mass, D_alpha = log 2
    assert_close(g1[1], np.log(2.0))


def test_outcome_that_cannot_happen_contributes_nothing():
    """p(z) = 0 for z = 1 (never a detection) must not give 0/0."""
    P = np.array([[0.3, 0.7]])
    g = expected_gain(P, np.array([0.0, 0.0]), 0.5)
    assert g[0] == 0.0


# ---------------------------------------------------------------------- n looks
@pytest.mark.parametrize("alpha", [0.5, 1.0, 2.0])
def test_n_looks_gain_equals_brute_force_over_all_sequences(alpha):
    rng = np.random.default_rng(6)
    counts, w = particle_set(rng, 25, 3, 4)
    n_counts = int(counts.max()) + 1
    P = count_distribution(counts, w, n_counts)
    pd_cols = SENSOR.detection_probability(np.arange(n_counts))
    for n in range(1, 7):
        want = brute_force_gain(counts, w, SENSOR.detection_probability, n, alpha)
        assert_close(gain_of_looks(P, pd_cols, n, alpha), want)


def test_binomial_table_columns_are_distributions():
    pd = np.array([0.0, 0.2, 1.0])
    tab = binomial_likelihood(pd, 4)
    assert tab.shape == (5, 3)
    assert_close(tab.sum(axis=0), 1.0)
    assert tab[0, 0] == 1.0 and tab[4, 2] == 1.0


# ------------------------------------------------------------------------ greedy
def _gain_curve(P_row, pd, n_max, alpha):
    return np.array([gain_of_looks(P_row[None], pd, n, alpha)[0] for n in range(n_max + 1)])


@pytest.mark.parametrize("alpha", [0.5, 1.0])
def test_second_look_only_when_it_beats_every_first_look(alpha):
    """Cell 0 is uncertain; cell 1's first-look gain is placed just above, then just
    below, cell 0's second-look marginal gain. Two looks: [0, 1] then [0, 0]."""
    pd = SENSOR.detection_probability(np.arange(2))
    p0 = np.array([0.5, 0.5])
    g0 = _gain_curve(p0, pd, 2, alpha)
    second = g0[2] - g0[1]
    assert 0 < second < g0[1]

    def first_gain(q):
        return gain_of_looks(np.array([[1 - q, q]]), pd, 1, alpha)[0]

    # bisection on cell 1's target probability q in (0, 0.5]: first_gain increases in q
    def q_for(target):
        lo, hi = 0.0, 0.5
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if first_gain(mid) < target else (lo, mid)
        return hi

    q_hi, q_lo = q_for(second * 1.01), q_for(second * 0.99)
    assert first_gain(q_hi) > second > first_gain(q_lo)
    quiet = np.array([[1.0, 0.0]] * 3)  # certain cells: zero gain
    for q, want in ((q_hi, [0, 1]), (q_lo, [0, 0])):
        P = np.vstack([p0, [1 - q, q], quiet])
        for seed in range(5):  # whatever the tie-breaking order
            got = greedy_looks(P, pd, 2, alpha, repeats=True, rng=np.random.default_rng(seed))
            assert got.tolist() == want
        # without repeats the second look always goes to another cell
        assert greedy_looks(P, pd, 2, alpha, repeats=False).tolist() == [0, 1]


def test_greedy_allocation_is_marginally_optimal_for_mutual_information():
    """At alpha = 1 the gain of n conditionally independent looks is concave in n, so
    greedy ends with every chosen look's marginal gain >= every look not taken."""
    rng = np.random.default_rng(7)
    P = rng.dirichlet(np.full(4, 0.5), size=30)
    pd = SENSOR.detection_probability(np.arange(4))
    m = 40
    cells = greedy_looks(P, pd, m, 1.0, repeats=True, rng=rng)
    assert cells.shape == (m,)
    n = np.bincount(cells, minlength=len(P))
    assert n.max() > 1  # repeats do happen here
    curves = np.array([_gain_curve(P[c], pd, n.max() + 1, 1.0) for c in range(len(P))])
    idx = np.arange(len(P))
    taken_last = (curves[idx, n] - curves[idx, np.maximum(n - 1, 0)])[n > 0]
    next_gain = curves[idx, n + 1] - curves[idx, n]
    assert taken_last.min() >= next_gain.max() - 1e-15
    # and the total gain beats the best distinct-cell allocation of the same budget
    # where that is possible (here m > n_cells, so compare with one look everywhere)
    assert curves[idx, n].sum() >= curves[:, 1].sum()


def test_top_m_distinct_picks_largest_single_look_gains():
    rng = np.random.default_rng(8)
    P = rng.dirichlet(np.ones(3), size=50)
    pd = SENSOR.detection_probability(np.arange(3))
    g = expected_gain(P, pd, 0.5)
    cells = greedy_looks(P, pd, 10, 0.5, repeats=False, rng=rng)
    assert len(np.unique(cells)) == 10
    assert set(cells.tolist()) == set(np.argsort(-g)[:10].tolist())


def test_all_zero_gain_spreads_looks_over_distinct_random_cells():
    P = np.zeros((100, 2))
    P[:, 0] = 1.0
    pd = SENSOR.detection_probability(np.arange(2))
    a = greedy_looks(P, pd, 24, 0.5, repeats=True, rng=np.random.default_rng(0))
    b = greedy_looks(P, pd, 24, 0.5, repeats=True, rng=np.random.default_rng(1))
    assert len(np.unique(a)) == 24 and len(np.unique(b)) == 24
    assert a.tolist() != b.tolist()


@pytest.mark.parametrize("alpha", [0.5, 2.0])
def test_greedy_bookkeeping_matches_a_naive_greedy(alpha):
    """Many looks on few cells (past the precomputed gains): same allocation as a greedy
    that recomputes ``G_c(n_c + 1) - G_c(n_c)`` from scratch for every cell each look."""
    rng = np.random.default_rng(9)
    P = rng.dirichlet(np.ones(3), size=4)
    pd = SENSOR.detection_probability(np.arange(3))
    m = 30
    n = np.zeros(len(P), dtype=np.int64)
    for _ in range(m):
        gains = [gain_of_looks(P[c:c + 1], pd, n[c] + 1, alpha)[0]
                 - gain_of_looks(P[c:c + 1], pd, n[c], alpha)[0] for c in range(len(P))]
        n[int(np.argmax(gains))] += 1
    got = greedy_looks(P, pd, m, alpha, repeats=True)
    assert n.max() > 5
    np.testing.assert_array_equal(np.bincount(got, minlength=len(P)), n)

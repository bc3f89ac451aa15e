"""Policy and track-metric rules against independent references: lookahead's visibility
to come (the model's per-cell blindness test, step by step), search-track's own field
after its looks (the closed form ``p_d(1) = p_d``), the sparse top-M with own cells tied
with the default row (distinct cells), the P_c(t) check of a row summing below 1, OSPA(2)'s
sliding window and the steps near a crossing (both from their definitions, by brute
force)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from mttbench.benchmarks.engine.information import _top_cells
from mttbench.benchmarks.engine.policies import count_distribution_problem, make_policy
from mttbench.benchmarks.engine.policy_lookahead import future_blindness
from mttbench.benchmarks.engine.track_metrics import crossings, ospa2
from mttbench.scenarios.spec import loads
from mttbench.trackers.cells import CellCounts

SPEC = """
name = "band"
n_steps = 30

[grid]
nx = 7
ny = 5

[dynamics]
wna_intensity = 0.001

[targets]
initial_states = [[1.5, 0.0, 1.5, 0.0]]
n_random_initial = 2
survival_probability = 0.9
birth_rate = 0.4

[sensor]
kind = "rayleigh"
p_d = 0.6
snr = 4.0
looks_per_step = 3

[[occlusion]]
x = [0, 1]
y = [1, 2]
steps = [2, 20]
velocity = [1.0, 0.5]
"""


@pytest.mark.parametrize(("k", "horizon", "discount"), [(0, 1, 0.8), (1, 2, 0.8), (3, 4, 0.5),
                                                        (18, 5, 0.9)])
def test_the_visibility_to_come_sums_each_blind_step_ahead_discounted(k, horizon, discount):
    """``sum_{h=1..H} gamma^h [c blind at k + h]`` for every cell, the blindness read
    from the model's per-cell test (not from its lists of blind cells)."""
    model = loads(SPEC).model
    n = model.grid.n_cells
    want = np.zeros(n)
    for h in range(1, horizon + 1):
        want += discount ** h * model.visibility.is_blocked(k + h, np.arange(n), model.grid)
    cells, values = future_blindness(model, k, horizon, discount)
    got = np.zeros(n)
    got[cells] = values
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=0.0)
    assert np.all(values > 0)


def test_search_tracks_own_field_keeps_the_undetected_share_of_each_looked_cell():
    """Without the tracker's field: ``lambda = n0 / C``, predicted to ``p_s lambda + b / C``
    before the looks, then times ``1 - p_d(1)`` in each looked cell (``p_d(1) = p_d`` for
    the Rayleigh sensor), the other cells as predicted."""
    model = loads(SPEC).model
    C = model.grid.n_cells
    pol = make_policy("search-track")
    pol.reset(model, 3, np.random.default_rng(0))
    P = np.tile([0.9, 0.1], (C, 1))
    chosen = pol.select(0, counts=P)
    predicted = 0.9 * 3 / C + 0.4 / C
    want = np.full(C, predicted)
    want[chosen] *= 1.0 - 0.6
    np.testing.assert_allclose(pol._own.dense(), want, rtol=1e-12)


@pytest.mark.parametrize("seed", [None, 0, 1])
@pytest.mark.parametrize("looks", [2, 3, 5, 9, 10])
def test_the_sparse_top_cells_are_distinct_with_own_cells_tied_with_the_default(seed, looks):
    """Own cells of gain 5, 3, 3, 1 and 6 default cells of gain 3 on 10 cells: the cell
    of gain 5 first, then cells of gain 3 (own or default), the cell of gain 1 last; always
    ``looks`` distinct cells."""
    counts = CellCounts(10, np.array([1, 4, 6, 8]), np.tile([0.5, 0.5], (4, 1)),
                        np.array([0.5, 0.5]))
    gain = np.array([5.0, 3.0, 3.0, 1.0])
    rng = None if seed is None else np.random.default_rng(seed)
    got = _top_cells(counts, gain, 3.0, looks, rng)
    assert len(got) == len(np.unique(got)) == looks
    assert 1 in got
    assert (8 in got) == (looks == 10)


def test_a_row_summing_below_one_is_reported_whatever_the_other_rows():
    P = np.tile([0.7, 0.3], (6, 1))
    P[4] = [0.25, 0.25]
    assert "summing to 0.5" in count_distribution_problem(P, 6)
    P[2] = [0.7, 0.3 + 1e-8]
    assert "summing to 0.5" in count_distribution_problem(P, 6)


def _ospa2_by_definition(X, ax, Y, ay, c, p, window):
    """OSPA(2) at each step from its definition, loops over the window's steps."""
    T = len(X)
    out = np.zeros(T)
    for k in range(T):
        K = range(max(0, k - window + 1), k + 1)
        xs = [i for i in range(X.shape[1]) if any(ax[t, i] for t in K)]
        ys = [j for j in range(Y.shape[1]) if any(ay[t, j] for t in K)]
        m, n = len(xs), len(ys)
        if max(m, n) == 0:
            continue
        if min(m, n) == 0:
            out[k] = c
            continue
        base = np.zeros((m, n))
        for (a, i), (b, j) in itertools.product(enumerate(xs), enumerate(ys)):
            steps = [t for t in K if ax[t, i] or ay[t, j]]
            cost = [min(float(np.linalg.norm(X[t, i] - Y[t, j])), c) if ax[t, i] and ay[t, j]
                    else c for t in steps]
            base[a, b] = min(sum(cost) / len(steps), c) ** p
        r, s = linear_sum_assignment(base)
        big = max(m, n)
        out[k] = ((base[r, s].sum() + c**p * (big - min(m, n))) / big) ** (1 / p)
    return out


@pytest.mark.parametrize("window", [1, 2, 3])
def test_ospa2_windows_span_the_given_number_of_steps(window):
    rng = np.random.default_rng(window)
    T = 7
    truth, tids, est, labels = [], [], [], []
    for _ in range(T):
        ti = np.array([i for i in range(3) if rng.random() < 0.8], dtype=np.int64)
        ei = np.array([j for j in range(3) if rng.random() < 0.7], dtype=np.int64)
        truth.append(rng.uniform(0, 4, (len(ti), 2)))
        tids.append(ti)
        est.append(rng.uniform(0, 4, (len(ei), 2)))
        labels.append(ei)
    got = ospa2(truth, tids, est, labels, c=2.0, p=1.0, window=window)
    X, ax = np.full((T, 3, 2), np.nan), np.zeros((T, 3), bool)
    Y, ay = np.full((T, 3, 2), np.nan), np.zeros((T, 3), bool)
    for k in range(T):
        X[k, tids[k]], ax[k, tids[k]] = truth[k], True
        Y[k, labels[k]], ay[k, labels[k]] = est[k], True
    want = _ospa2_by_definition(X, ax, Y, ay, 2.0, 1.0, window)
    np.testing.assert_allclose(got.per_step, want, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("window", [0, 1, 2])
def test_the_steps_near_a_crossing_lie_within_the_window_on_both_sides(window):
    """Two targets close (distance < 1) at steps 4 and 5 only, of 12: near = every step
    within ``window`` of 4 or 5."""
    T = 12
    gap = np.where(np.isin(np.arange(T), [4, 5]), 0.5, 3.0)
    truth = [np.array([[0.0, 0.0], [gap[k], 0.0]]) for k in range(T)]
    ids = [np.array([0, 1])] * T
    got = crossings(truth, ids, distance=1.0, window=window)
    np.testing.assert_array_equal(got.close, (gap < 1.0).astype(int))
    want = np.array([any(abs(k - t) <= window for t in (4, 5)) for k in range(T)])
    np.testing.assert_array_equal(got.near, want)

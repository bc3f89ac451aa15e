"""OSPA, GOSPA, assigned RMSE and count error against brute-force references.

The references below enumerate every permutation (OSPA, RMSE) or every partial
assignment (GOSPA) with plain Python distances, independently of the implementation
(which uses cdist + linear_sum_assignment).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from mttbench.benchmarks.engine.metrics import (
    GOSPA,
    OSPA,
    assigned_rmse,
    builtin_run_columns,
    count_error,
    gospa,
    ospa,
    step_metrics,
)

SIZES = range(5)  # 0..4 points per set
ORDERS = (1.0, 2.0, 3.0)
CUTOFFS = (0.5, 2.0, 10.0)


def assert_close(actual: float, expected: float, tol: float = 1e-12) -> None:
    """The one tolerance of this module: absolute and relative 1e-12."""
    assert math.isclose(actual, expected, rel_tol=tol, abs_tol=tol), (actual, expected)


def _dist(a, b) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


def brute_ospa(x, y, c, p) -> tuple[float, float, float]:
    """(total, loc, card) by enumerating all injections of the smaller set."""
    x, y = [tuple(v) for v in x], [tuple(v) for v in y]
    if len(x) > len(y):
        x, y = y, x
    n, m = len(x), len(y)
    if m == 0:
        return 0.0, 0.0, 0.0
    best = min(
        sum(min(_dist(x[i], y[j]), c) ** p for i, j in enumerate(perm))
        for perm in itertools.permutations(range(m), n)
    )
    card = c**p * (m - n)
    return ((best + card) / m) ** (1 / p), (best / m) ** (1 / p), (card / m) ** (1 / p)


def brute_gospa(x, y, c, p) -> tuple[float, float, int, int]:
    """(total, loc, #missed, #false) minimising over every partial assignment, raw d^p."""
    x, y = [tuple(v) for v in x], [tuple(v) for v in y]
    n, m = len(x), len(y)
    best = None
    for k in range(min(n, m) + 1):
        for rows in itertools.combinations(range(n), k):
            for cols in itertools.permutations(range(m), k):
                loc = sum(_dist(x[i], y[j]) ** p for i, j in zip(rows, cols, strict=True))
                cost = loc + c**p / 2 * ((n - k) + (m - k))
                if best is None or cost < best[0]:
                    best = (cost, loc, n - k, m - k)
    cost, loc, missed, false = best
    return cost ** (1 / p), loc, missed, false


def brute_rmse(x, y) -> float:
    x, y = [tuple(v) for v in x], [tuple(v) for v in y]
    if len(x) > len(y):
        x, y = y, x
    n, m = len(x), len(y)
    if n == 0:
        return float("nan")
    best = min(
        sum(_dist(x[i], y[j]) ** 2 for i, j in enumerate(perm))
        for perm in itertools.permutations(range(m), n)
    )
    return math.sqrt(best / n)


def _random_sets(seed: int):
    """All size pairs 0..4 x 0..4, points uniform on [0, 4]^2 (distances ~ cut-offs)."""
    rng = np.random.default_rng(seed)
    for n, m in itertools.product(SIZES, SIZES):
        yield rng.uniform(0.0, 4.0, (n, 2)), rng.uniform(0.0, 4.0, (m, 2))


# ----------------------------------------------------------------------------- brute force
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("p", ORDERS)
@pytest.mark.parametrize("c", CUTOFFS)
def test_ospa_equals_brute_force(seed, p, c):
    for x, y in _random_sets(seed):
        got = ospa(x, y, c=c, p=p)
        total, loc, card = brute_ospa(x, y, c, p)
        assert_close(got.total, total)
        assert_close(got.localisation, loc)
        assert_close(got.cardinality, card)
        # total^p = loc^p + card^p
        assert_close(got.total**p, got.localisation**p + got.cardinality**p)
        assert 0.0 <= got.total <= c + 1e-12


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("p", ORDERS)
@pytest.mark.parametrize("c", CUTOFFS)
def test_gospa_equals_brute_force(seed, p, c):
    half = c**p / 2
    for x, y in _random_sets(seed):
        got = gospa(x, y, c=c, p=p)
        total, loc, n_missed, n_false = brute_gospa(x, y, c, p)
        assert_close(got.total, total)
        # continuous random points: the optimal partial assignment is unique a.s.
        assert_close(got.localisation, loc)
        assert_close(got.missed, half * n_missed)
        assert_close(got.false, half * n_false)
        # parts sum to total^p
        assert_close(got.localisation + got.missed + got.false, got.total**p)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_assigned_rmse_equals_brute_force(seed):
    for x, y in _random_sets(seed):
        got = assigned_rmse(x, y)
        expected = brute_rmse(x, y)
        if math.isnan(expected):
            assert math.isnan(got)
        else:
            assert_close(got, expected)


def test_assigned_rmse_is_not_cut_off():
    # A single pair 30 apart: RMSE is the distance itself, not capped at any c.
    assert_close(assigned_rmse(np.array([[0.0, 0.0]]), np.array([[30.0, 40.0]])), 50.0)


# ----------------------------------------------------------------------------- raw-distance trap
def _ospa_assigning_on_raw_distances(x, y, c, p) -> float:
    """The WRONG recipe: assign on raw d, then cut and raise to p (n <= m here)."""
    d = cdist(x, y)
    rows, cols = linear_sum_assignment(d)
    m, n = len(y), len(x)
    return ((np.sum(np.minimum(d[rows, cols], c) ** p) + c**p * (m - n)) / m) ** (1 / p)


def test_power_before_assigning_matters_p2():
    # Raw distances prefer {0 <-> 0, (-1,1) <-> (-1,-2)}: sum d = 3 < sqrt2 + sqrt5,
    # but sum d^2 = 9 > 2 + 5 = 7 for the crossed pairing.
    x = np.array([[0.0, 0.0], [-1.0, 1.0]])
    y = np.array([[0.0, 0.0], [-1.0, -2.0]])
    c, p = 10.0, 2.0
    wrong = _ospa_assigning_on_raw_distances(x, y, c, p)
    assert_close(wrong, math.sqrt(9.0 / 2.0))
    got = ospa(x, y, c=c, p=p).total
    assert_close(got, math.sqrt(7.0 / 2.0))
    assert_close(got, brute_ospa(x, y, c, p)[0])
    assert got < wrong - 0.1
    # GOSPA too: 7 rather than 9
    assert_close(gospa(x, y, c=c, p=p).total, math.sqrt(7.0))


def test_cutoff_before_assigning_matters_p3():
    # On a line: raw distances pair 0-2 and 3-5 (2 + 2 < 5 + 1), but with c = 1.5 both
    # of those are cut, while the crossed pairing keeps one good pair (3-2, d = 1).
    x = np.array([[0.0, 0.0], [3.0, 0.0]])
    y = np.array([[2.0, 0.0], [5.0, 0.0]])
    c, p = 1.5, 3.0
    wrong = _ospa_assigning_on_raw_distances(x, y, c, p)
    assert_close(wrong, ((2 * c**p) / 2) ** (1 / p))
    got = ospa(x, y, c=c, p=p).total
    assert_close(got, ((c**p + 1.0) / 2) ** (1 / p))
    assert_close(got, brute_ospa(x, y, c, p)[0])
    assert got < wrong - 0.05
    g = gospa(x, y, c=c, p=p)
    assert_close(g.localisation, 1.0)
    assert_close(g.missed, c**p / 2)
    assert_close(g.false, c**p / 2)
    assert_close(g.total, brute_gospa(x, y, c, p)[0])


# ----------------------------------------------------------------------------- empty sets
EMPTIES = [np.zeros((0, 2)), np.zeros((0,)), []]


@pytest.mark.parametrize("empty", EMPTIES, ids=["0x2", "0", "list"])
def test_empty_sets(empty):
    pts = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]])
    c, p = 2.0, 2.0
    assert ospa(empty, empty, c, p) == OSPA(0.0, 0.0, 0.0)
    assert gospa(empty, empty, c, p) == GOSPA(0.0, 0.0, 0.0, 0.0)
    for a, b in [(empty, pts), (pts, empty)]:
        assert ospa(a, b, c, p) == OSPA(c, 0.0, c)
        assert math.isnan(assigned_rmse(a, b))
    # 3 missed targets: 3 * c^p / 2 = 6
    assert gospa(pts, empty, c, p) == GOSPA(math.sqrt(6.0), 0.0, 6.0, 0.0)
    assert gospa(empty, pts, c, p) == GOSPA(math.sqrt(6.0), 0.0, 0.0, 6.0)


def test_ospa_of_disjoint_far_sets_is_c():
    x = np.array([[0.0, 0.0]])
    y = np.array([[100.0, 0.0], [0.0, 100.0]])
    assert_close(ospa(x, y, c=3.0, p=1.0).total, 3.0)


def test_gospa_pair_at_cutoff_counts_as_missed_and_false():
    # d == c exactly: documented convention, one missed + one false (same total).
    g = gospa(np.array([[0.0, 0.0]]), np.array([[2.0, 0.0]]), c=2.0, p=2.0)
    assert g == GOSPA(2.0, 0.0, 2.0, 2.0)


# ----------------------------------------------------------------------------- misc
def test_count_error():
    assert count_error(2.5, 4) == 1.5
    assert count_error(4, 2) == 2.0
    assert count_error(0.0, 0) == 0.0


def test_step_metrics_keys_and_values():
    rng = np.random.default_rng(5)
    x, y = rng.uniform(0, 4, (3, 2)), rng.uniform(0, 4, (4, 2))
    row = step_metrics(x, y, estimated_count=3.7, c=1.5, p=1.0)
    assert set(row) == {
        "ospa", "ospa_loc", "ospa_card", "gospa", "gospa_loc", "gospa_missed",
        "gospa_false", "rmse", "count_error", "own_count_error", "true_count", "n_estimated",
    }
    assert all(isinstance(v, float) for v in row.values())
    o, g = ospa(x, y, c=1.5, p=1.0), gospa(x, y, c=1.5, p=1.0)
    assert (row["ospa"], row["ospa_loc"], row["ospa_card"]) == (
        o.total, o.localisation, o.cardinality)
    assert (row["gospa"], row["gospa_loc"], row["gospa_missed"], row["gospa_false"]) == (
        g.total, g.localisation, g.missed, g.false)
    assert_close(row["rmse"], brute_rmse(x, y))
    assert_close(row["count_error"], 1.0)  # 4 states reported for 3 targets
    assert_close(row["own_count_error"], 0.7)  # the tracker's own count, 3.7
    assert row["true_count"] == 3.0 and row["n_estimated"] == 4.0


def test_step_metrics_empty():
    row = step_metrics(np.zeros((0, 2)), np.zeros((0,)), estimated_count=0.2)
    assert row["ospa"] == 0.0 and row["gospa"] == 0.0
    assert math.isnan(row["rmse"])
    assert_close(row["count_error"], 0.0)
    assert_close(row["own_count_error"], 0.2)
    assert row["true_count"] == 0.0 and row["n_estimated"] == 0.0


@pytest.mark.parametrize(
    "call",
    [
        lambda: ospa(np.zeros((3, 4)), np.zeros((2, 2))),  # full states, not positions
        lambda: ospa(np.zeros(2), np.zeros((2, 2))),  # one point without the set axis
        lambda: gospa(np.zeros((1, 2)), np.zeros((1, 2)), alpha=1.0),
        lambda: ospa(np.zeros((1, 2)), np.zeros((1, 2)), p=0.5),
        lambda: gospa(np.zeros((1, 2)), np.zeros((1, 2)), c=0.0),
        lambda: assigned_rmse(np.array([[np.nan, 0.0]]), np.zeros((1, 2))),
    ],
)
def test_invalid_inputs_raise(call):
    with pytest.raises(ValueError):
        call()


def _separate_columns(x, y, n_est, c, p) -> dict[str, float]:
    """The built-in columns from the metrics' own functions, one call each."""
    o, g = ospa(x, y, c=c, p=p), gospa(x, y, c=c, p=p)
    return {"count_error": count_error(len(y), len(x)),
            "own_count_error": count_error(n_est, len(x)),
            "ospa": o.total, "ospa_loc": o.localisation, "ospa_card": o.cardinality,
            "gospa": g.total, "gospa_loc": g.localisation, "gospa_missed": g.missed,
            "gospa_false": g.false, "rmse": assigned_rmse(x, y)}


def _step_case(rng, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """A step's truth and estimate: random, with exact duplicates, on integer points
    (exact ties of distances), or far apart (every pair cut off)."""
    n, m = int(rng.integers(0, 8)), int(rng.integers(0, 8))
    x, y = rng.uniform(0, 6, (n, 2)), rng.uniform(0, 6, (m, 2))
    if kind == "duplicates" and n and m:
        y[: m // 2] = x[rng.integers(0, n, m // 2)]
        y[m // 2:] = y[0]
    elif kind == "integer":
        x, y = np.round(x), np.round(y)
    elif kind == "far":
        y += 100.0
    return x, y


@pytest.mark.parametrize("kind", ["random", "duplicates", "integer", "far"])
@pytest.mark.parametrize("p", ORDERS)
def test_step_metrics_equal_the_separate_functions_bit_for_bit(kind, p):
    """step_metrics' shared assignment gives exactly the numbers of ospa(), gospa(),
    assigned_rmse() and count_error(), including sizes 0 and 1 and exact ties."""
    rng = np.random.default_rng([7, int(p), len(kind)])
    for _ in range(150):
        x, y = _step_case(rng, kind)
        c = float(rng.choice(CUTOFFS))
        n_est = float(rng.uniform(0, 8))
        row = step_metrics(x, y, n_est, c=c, p=p)
        expected = _separate_columns(x, y, n_est, c, p)
        for col, value in expected.items():
            assert row[col] == value or (math.isnan(value) and math.isnan(row[col])), (
                col, row[col], value, x, y, c)


def test_vectorised_distances_equal_cdist_bit_for_bit():
    """builtin_run_columns' distances: sqrt(dx*dx + dy*dy) and dx*dx + dy*dy are cdist's
    euclidean and sqeuclidean numbers exactly (and cdist(y, x) is cdist(x, y).T)."""
    rng = np.random.default_rng(11)
    for scale in (1.0, 50.0, 1e4):
        x, y = rng.uniform(-scale, scale, (300, 2)), rng.uniform(-scale, scale, (200, 2))
        dx = x[:, None, 0] - y[None, :, 0]
        dy = x[:, None, 1] - y[None, :, 1]
        assert np.array_equal(np.sqrt(dx * dx + dy * dy), cdist(x, y))
        assert np.array_equal(dx * dx + dy * dy, cdist(x, y, "sqeuclidean"))
        assert np.array_equal(cdist(y, x), cdist(x, y).T)


@pytest.mark.parametrize("kind", ["random", "duplicates", "integer", "far"])
def test_builtin_run_columns_equal_the_separate_functions_per_step(kind):
    """A whole run's columns at once are, step by step, the metrics' own numbers."""
    rng = np.random.default_rng([12, len(kind)])
    for p in ORDERS:
        steps = [_step_case(rng, kind) for _ in range(40)]
        counts = rng.uniform(0, 8, len(steps))
        c = float(rng.choice(CUTOFFS))
        cols = builtin_run_columns([s[0] for s in steps], [s[1] for s in steps], counts,
                                   c=c, p=p)
        for k, (x, y) in enumerate(steps):
            for col, value in _separate_columns(x, y, counts[k], c, p).items():
                got = cols[col][k]
                assert got == value or (math.isnan(value) and math.isnan(got)), (
                    col, k, got, value)

"""Metric axioms of OSPA and GOSPA (alpha = 2) on random small point sets (hypothesis).

Points lie on a quarter-unit lattice in [-4, 4]^2 so that distinct points are at least
0.25 apart (no underflow of d^p, and exact coincidences and ties are common, which is
where assignment code tends to break). Both metrics are metrics for p >= 1.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mttbench.benchmarks.engine.metrics import gospa, ospa

SETTINGS = settings(max_examples=150, deadline=None)
TOL = 1e-9  # the one tolerance here: rounding of sums of up to 4 powers


def _close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=TOL, abs_tol=TOL)


coord = st.integers(-16, 16).map(lambda i: i / 4)
point_sets = st.lists(st.tuples(coord, coord), min_size=0, max_size=4).map(
    lambda pts: np.array(pts, dtype=float).reshape(-1, 2)
)
orders = st.sampled_from([1.0, 2.0, 3.0]) | st.floats(1.0, 4.0)
cutoffs = st.sampled_from([0.5, 1.0, 2.0, 5.0]) | st.floats(0.1, 10.0)


def _multiset(x: np.ndarray) -> list[tuple[float, float]]:
    return sorted(map(tuple, x.tolist()))


@SETTINGS
@given(x=point_sets, c=cutoffs, p=orders, data=st.data())
def test_identity_of_indiscernibles(x, c, p, data):
    perm = data.draw(st.permutations(range(len(x))))
    x_perm = x[list(perm)].reshape(-1, 2)  # same multiset, other order
    for metric in (ospa, gospa):
        assert metric(x, x, c=c, p=p).total == 0.0
        assert metric(x, x_perm, c=c, p=p).total == 0.0


@SETTINGS
@given(x=point_sets, y=point_sets, c=cutoffs, p=orders)
def test_positive_for_distinct_sets(x, y, c, p):
    o, g = ospa(x, y, c=c, p=p), gospa(x, y, c=c, p=p)
    assert o.total >= 0.0 and g.total >= 0.0
    if _multiset(x) != _multiset(y):
        assert o.total > 0.0 and g.total > 0.0
    else:
        assert o.total == 0.0 and g.total == 0.0


@SETTINGS
@given(x=point_sets, y=point_sets, c=cutoffs, p=orders)
def test_symmetry(x, y, c, p):
    a, b = ospa(x, y, c=c, p=p), ospa(y, x, c=c, p=p)
    assert _close(a.total, b.total)
    assert _close(a.localisation, b.localisation)
    assert _close(a.cardinality, b.cardinality)
    g, h = gospa(x, y, c=c, p=p), gospa(y, x, c=c, p=p)
    assert _close(g.total, h.total)
    # (the missed/false split can differ under ties of the optimal assignment; the
    # roles of truth and estimate are checked against brute force in test_metrics.py)
    assert _close(g.localisation + g.missed + g.false, h.localisation + h.missed + h.false)


@settings(max_examples=200, deadline=None)
@given(x=point_sets, y=point_sets, z=point_sets, c=cutoffs, p=orders)
def test_triangle_inequality(x, y, z, c, p):
    for metric in (ospa, gospa):
        xz = metric(x, z, c=c, p=p).total
        xy = metric(x, y, c=c, p=p).total
        yz = metric(y, z, c=c, p=p).total
        assert xz <= xy + yz + TOL * (1 + xy + yz)


@SETTINGS
@given(x=point_sets, y=point_sets, c=cutoffs, p=orders)
def test_bounds_and_parts(x, y, c, p):
    n, m = len(x), len(y)
    o = ospa(x, y, c=c, p=p)
    assert 0.0 <= o.total <= c * (1 + TOL)
    assert _close(o.total**p, o.localisation**p + o.cardinality**p)
    g = gospa(x, y, c=c, p=p)
    assert _close(g.localisation + g.missed + g.false, g.total**p)
    # leaving everything unassigned is feasible; at least |n - m| points are unmatched
    assert g.total**p <= c**p / 2 * (n + m) * (1 + TOL)
    assert g.missed + g.false >= c**p / 2 * abs(n - m) * (1 - TOL)
    # missed/false are c^p/2 times counts, with the same number of assigned pairs
    n_missed, n_false = g.missed / (c**p / 2), g.false / (c**p / 2)
    assert _close(n_missed, round(n_missed)) and _close(n_false, round(n_false))
    assert round(n - n_missed) == round(m - n_false) >= 0

"""LBP association marginals (trackers/pmb/lbp.py) against brute-force enumeration.

Reference: every joint association written out (each track takes "none" or one of its
measurements, no measurement twice), ``P(a) ~ prod_i w_{i a_i} prod_{j unused} beta_j``,
and the marginals summed from it. On a tree-structured graph the LBP fixed point is exact
(:data:`TREE_TOL`); on small loopy graphs it is the Bethe approximation, within
:data:`LOOPY_TOL`. The loopy error is the method's, not the implementation's: a generic
sum-product over the full message vectors (written separately while testing) gave the
same numbers to 1e-4 on random 2x2 problems.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from mttbench.trackers.pmb.lbp import association_marginals, edge_clusters

#: tree-structured problems: LBP equals the exact marginals
TREE_TOL = 1e-9
#: small loopy problems (fully connected 2x2 .. 3x3, weights within a decade either side
#: of 1): largest absolute error of a marginal. Measured over 200 such problems per shape
#: (seeds 100-299): median 0.003-0.017, 90th percentile 0.034-0.053, largest 0.27
#: (2x2); on the 8 seeds tested here 0.011 (2x2), 0.069 (3x2), 0.058 (3x3)
LOOPY_TOL = 0.1


def brute_force(w0, ei, ej, w, beta):
    """Exact marginals by enumerating every joint association."""
    T, J = len(w0), len(beta)
    options = [[(-1, -1)] + [(int(ej[e]), e) for e in range(len(w)) if ei[e] == i]
               for i in range(T)]
    p_missed, p_edge, p_unused = np.zeros(T), np.zeros(len(w)), np.zeros(J)
    total = 0.0
    for choice in itertools.product(*options):
        used = [j for j, _ in choice if j >= 0]
        if len(used) != len(set(used)):
            continue  # a measurement taken twice
        weight = 1.0
        for i, (j, e) in enumerate(choice):
            weight *= w0[i] if j < 0 else w[e]
        for j in range(J):
            if j not in used:
                weight *= beta[j]
        total += weight
        for i, (j, e) in enumerate(choice):
            if j < 0:
                p_missed[i] += weight
            else:
                p_edge[e] += weight
        for j in range(J):
            if j not in used:
                p_unused[j] += weight
    return p_missed / total, p_edge / total, p_unused / total


def _random_weights(rng, T, J, ei):
    w0 = 10.0 ** rng.uniform(-2, 1, T)
    w = 10.0 ** rng.uniform(-2, 2, len(ei))
    beta = 10.0 ** rng.uniform(-1, 1, J)
    return w0, w, beta


def _random_tree(rng, n_nodes):
    """A random tree on alternating track / measurement nodes: edges (track, meas)."""
    kinds = [0]  # node 0 is a track
    ids = [0]
    counts = [1, 0]
    ei, ej = [], []
    for _ in range(1, n_nodes):
        parent = int(rng.integers(len(kinds)))
        kind = 1 - kinds[parent]
        kinds.append(kind)
        ids.append(counts[kind])
        counts[kind] += 1
        if kind == 1:
            ei.append(ids[parent])
            ej.append(ids[-1])
        else:
            ei.append(ids[-1])
            ej.append(ids[parent])
    return np.array(ei), np.array(ej), counts[0], counts[1]


@pytest.mark.parametrize("seed", range(30))
def test_lbp_equals_exact_on_trees(seed):
    rng = np.random.default_rng(seed)
    ei, ej, T, J = _random_tree(rng, int(rng.integers(2, 10)))
    # an extra lonely track and measurement (no edges)
    T, J = T + 1, J + 1
    w0, w, beta = _random_weights(rng, T, J, ei)
    got = association_marginals(w0, ei, ej, w, beta)
    want = brute_force(w0, ei, ej, w, beta)
    assert got.converged
    np.testing.assert_allclose(got.p_missed, want[0], rtol=0, atol=TREE_TOL)
    np.testing.assert_allclose(got.p_edge, want[1], rtol=0, atol=TREE_TOL)
    np.testing.assert_allclose(got.p_unused, want[2], rtol=0, atol=TREE_TOL)
    assert got.p_missed[-1] == 1.0 and got.p_unused[-1] == 1.0


@pytest.mark.parametrize(("T", "J"), [(2, 2), (3, 2), (3, 3)])
@pytest.mark.parametrize("seed", range(8))
def test_lbp_close_to_exact_on_small_loopy_graphs(T, J, seed):
    rng = np.random.default_rng(100 + seed)
    ei, ej = (a.ravel() for a in np.meshgrid(np.arange(T), np.arange(J), indexing="ij"))
    w0, w, beta = (10.0 ** rng.uniform(-1, 1, n) for n in (T, len(ei), J))
    got = association_marginals(w0, ei, ej, w, beta)
    want = brute_force(w0, ei, ej, w, beta)
    assert got.converged
    for g, x in zip((got.p_missed, got.p_edge, got.p_unused), want, strict=True):
        assert np.max(np.abs(g - x)) < LOOPY_TOL
    # each track's marginals sum to 1, each measurement's too
    tot = got.p_missed + np.bincount(ei, weights=got.p_edge, minlength=T)
    np.testing.assert_allclose(tot, 1.0, atol=1e-12)


def test_loopy_error_is_not_zero():
    """The loopy tolerance is needed: on a 2x2 cycle LBP is approximate (so the tree test
    above is a real check of the tree case, not of a method that is always exact)."""
    ei, ej = np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1])
    w0, w, beta = np.array([0.1, 0.1]), np.array([5.0, 1.0, 1.0, 5.0]), np.array([0.5, 0.5])
    got = association_marginals(w0, ei, ej, w, beta)
    want = brute_force(w0, ei, ej, w, beta)
    assert np.max(np.abs(got.p_edge - want[1])) > 1e-6


def test_clusters_are_connected_components():
    ei, ej = np.array([0, 1, 2, 3]), np.array([0, 0, 1, 2])
    lab = edge_clusters(ei, ej, 4, 3)
    assert lab[0] == lab[1] and len({lab[1], lab[2], lab[3]}) == 3


def test_no_edges():
    got = association_marginals(np.array([0.3, 2.0]), np.zeros(0, int), np.zeros(0, int),
                                np.zeros(0), np.array([1.5]))
    np.testing.assert_array_equal(got.p_missed, [1.0, 1.0])
    np.testing.assert_array_equal(got.p_unused, [1.0])


def test_a_dominant_edge_gives_the_exact_marginals_not_nan():
    """One track whose detection carries a likelihood ratio of 1e30 (many positive repeats
    of one cell) beside a second track on the same measurement: the "total minus own
    term" cancels to nothing in floating point; the floors keep the messages finite and
    the marginals equal brute-force enumeration (a tree: exact)."""
    w0 = np.array([1.0, 1.0])
    ei, ej = np.array([0, 1, 1]), np.array([0, 0, 1])
    w = np.array([1e30, 0.5, 2.0])
    beta = np.array([1e-3, 0.2])
    got = association_marginals(w0, ei, ej, w, beta)
    want = brute_force(w0, ei, ej, w, beta)
    for g, x in zip((got.p_missed, got.p_edge, got.p_unused), want, strict=True):
        assert np.all(np.isfinite(g))
        np.testing.assert_allclose(g, x, rtol=1e-9, atol=1e-12)

"""JMPD target alignment (trackers/jmpd/estimation.py) against plain loops and brute force.

Three functions line the particles' targets up with a reference (the last estimate):
``greedy_assignment`` (closest pair first), ``align_square`` (every particle holds exactly
the reference's number of targets: all permutations up to ``EXACT_ALIGN_MAX``, greedy
above) and ``align_slots`` (the independent-partition proposal's realignment of slots that
may be empty, with a per-slot array such as the cells carried along).

References: a plain-loop greedy (scan every free pair, take the smallest), and the minimum
over all permutations on tiny cases where the optimum is the greedy answer. Random costs
are continuous, so ties have probability zero; tolerance ``EXACT`` (round-off only).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from mttbench.trackers.jmpd import align_slots, align_square, greedy_assignment

EXACT = 1e-12


def _greedy_loop(cost: np.ndarray) -> dict[int, int]:
    """Plain-loop greedy on one ``(a, b)`` cost with ``inf`` forbidden: repeatedly take the
    finite pair of smallest cost among free rows and columns. Returns ``{column: row}``."""
    a, b = cost.shape
    free_r, free_c = set(range(a)), set(range(b))
    out: dict[int, int] = {}
    while free_r and free_c:
        best = min(((cost[i, j], i, j) for i in free_r for j in free_c), default=None)
        if best is None or not np.isfinite(best[0]):
            break
        _, i, j = best
        out[j] = i
        free_r.discard(i)
        free_c.discard(j)
    return out


def _sq_dist(targets: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``(a, b)`` squared position distances of states ``(a, 4)`` to ``(b, 4)``."""
    d = targets[:, None, [0, 2]] - ref[None, :, [0, 2]]
    return (d * d).sum(-1)


def test_greedy_assignment_equals_plain_loop():
    """Random ``(n, a, b)`` costs with a quarter forbidden, rectangular both ways."""
    rng = np.random.default_rng(0)
    for a, b in [(1, 1), (2, 3), (3, 2), (4, 4), (5, 3), (2, 6)]:
        cost = rng.uniform(0.0, 10.0, (50, a, b))
        cost[rng.random(cost.shape) < 0.25] = np.inf
        got = greedy_assignment(cost)
        assert got.shape == (50, b)
        for i in range(50):
            want = _greedy_loop(cost[i])
            np.testing.assert_array_equal(got[i], [want.get(j, -1) for j in range(b)])


@pytest.mark.parametrize("R", [2, 3, 4])
def test_align_square_is_the_best_permutation(R):
    """Up to EXACT_ALIGN_MAX targets the alignment minimises the summed squared position
    distance over all R! orders (brute force), and only reorders each particle's targets."""
    rng = np.random.default_rng(R)
    ref = rng.normal(0.0, 2.0, (R, 4))
    Y = rng.normal(0.0, 2.0, (60, R, 4))
    out = align_square(Y, ref)
    for i in range(60):
        totals = {p: float(sum(_sq_dist(Y[i][[p[b]]], ref[[b]])[0, 0] for b in range(R)))
                  for p in itertools.permutations(range(R))}
        best = min(totals, key=totals.get)
        np.testing.assert_array_equal(out[i], Y[i][list(best)])


def test_align_square_above_the_exact_limit_is_the_greedy_order():
    rng = np.random.default_rng(9)
    for R in (5, 6):
        ref = rng.normal(0.0, 2.0, (R, 4))
        Y = rng.normal(0.0, 2.0, (30, R, 4))
        out = align_square(Y, ref)
        for i in range(30):
            pick = _greedy_loop(_sq_dist(Y[i], ref))
            np.testing.assert_array_equal(out[i], Y[i][[pick[b] for b in range(R)]])


def _align_slots_reference(X: np.ndarray, valid: np.ndarray, cells: np.ndarray,
                           ref: np.ndarray):
    """The documented layout, particle by particle with plain loops: slot ``b < R`` holds
    the target the greedy loop pairs with reference ``b``; the remaining new slots, in
    order, take the unmatched targets, then the empty slots (each in old slot order)."""
    _, T, N = X.shape
    R = min(len(ref), T)
    oX, ov, oc = np.empty_like(X), np.empty_like(valid), np.empty_like(cells)
    for i in range(N):
        slots = [s for s in range(T) if valid[s, i]]
        targets = X[:, slots, i].T  # (n_i, 4)
        pick = _greedy_loop(_sq_dist(targets, ref[:R])) if slots else {}
        new_of = {b: slots[r] for b, r in pick.items()}
        matched = set(new_of.values())
        rest = ([s for s in slots if s not in matched]
                + [s for s in range(T) if not valid[s, i]])
        free = [b for b in range(T) if b not in new_of]
        new_of.update(zip(free, rest, strict=True))
        for b, s in new_of.items():
            oX[:, b, i], ov[b, i], oc[b, i] = X[:, s, i], valid[s, i], cells[s, i]
    return oX, ov, oc


def _random_slots(rng, T, N, spread=4.0):
    X = rng.normal(0.0, spread, (4, T, N))
    valid = rng.random((T, N)) < 0.6
    cells = np.arange(T * N).reshape(T, N) + 1000  # a distinct label per slot
    return X, valid, cells


@pytest.mark.parametrize("T,R", [(1, 1), (3, 2), (4, 3), (4, 4), (5, 2), (3, 5)])
def test_align_slots_equals_the_plain_loop_layout(T, R):
    """Every particle's slots against the plain-loop reference: the targets, their
    validity and their cells (labels here) all move together."""
    rng = np.random.default_rng(10 * T + R)
    X, valid, cells = _random_slots(rng, T, 80)
    ref = rng.normal(0.0, 4.0, (R, 4))
    got = align_slots(X.copy(), valid.copy(), cells.copy(), ref)
    want = _align_slots_reference(X, valid, cells, ref)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)


def test_align_slots_puts_each_target_at_its_nearest_reference_brute_force():
    """Well-separated references (>= 4 apart) and targets each within 0.3 of a distinct
    reference (some references missing in some particles): the alignment is the best
    injection of targets into reference slots over all permutations, which puts every
    target in the slot of its own reference; the cells travel with the targets."""
    rng = np.random.default_rng(4)
    R, T, N = 3, 4, 200
    ref = np.zeros((R, 4))
    ref[:, [0, 2]] = [[1.0, 1.0], [6.0, 2.0], [3.0, 7.0]]
    X = np.zeros((4, T, N))
    valid = np.zeros((T, N), dtype=bool)
    truth_ref = np.full((T, N), -1)
    for i in range(N):
        n_i = int(rng.integers(0, T + 1))
        owners = list(rng.permutation(R))[:min(n_i, R)]  # distinct references
        slots = rng.permutation(T)[:n_i]
        for k, s in enumerate(slots):
            valid[s, i] = True
            if k < len(owners):  # near a reference
                truth_ref[s, i] = owners[k]
                X[[0, 2], s, i] = ref[owners[k], [0, 2]] + rng.uniform(-0.3, 0.3, 2)
            else:  # a fourth target, far from every reference
                X[[0, 2], s, i] = [20.0, 20.0]
        for s in np.flatnonzero(~valid[:, i]):  # empty slots hold junk positions
            X[[0, 2], s, i] = rng.uniform(0.0, 8.0, 2)
    cells = np.arange(T * N).reshape(T, N)
    oX, ov, oc = align_slots(X.copy(), valid.copy(), cells.copy(), ref)
    for i in range(N):
        slots = np.flatnonzero(valid[:, i])
        k = min(len(slots), R)
        # brute force: the injection of k targets into the R reference slots of least cost
        best, best_cost = None, np.inf
        for chosen in itertools.permutations(slots, k):
            for refs in itertools.permutations(range(R), k):
                c = sum(_sq_dist(X[:, [s], i].T, ref[[r]])[0, 0]
                        for s, r in zip(chosen, refs, strict=True))
                if c < best_cost - EXACT:
                    best, best_cost = dict(zip(refs, chosen, strict=True)), c
        for r, s in (best or {}).items():
            assert truth_ref[s, i] == r  # the brute-force optimum is the obvious one
            np.testing.assert_array_equal(oX[:, r, i], X[:, s, i])
            assert ov[r, i] and oc[r, i] == cells[s, i]
        assert ov[:, i].sum() == len(slots)
        assert sorted(oc[:, i]) == sorted(cells[:, i])

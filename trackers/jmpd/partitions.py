"""Partitions of the literature JMPD: which slots are sampled together, and the
per-particle sorting that keeps slot ``t`` the same target in every particle.

* :func:`cluster_slots` -- the adaptive-partition rule (Kreucher, Kastella and Hero,
  IEEE TAES 2005, Table V, with Morelande's closure, IEEE TSP 2007 eq. 12): two slots
  whose estimated centres are closer than ``gamma`` are coupled, and coupling is closed
  under transitivity. A cluster of one slot is proposed independently (IP); a larger
  cluster jointly.
* :func:`sort_slots` -- partition sorting, K-means over per-particle permutations
  (TAES 2005 Sec. III-D, Table VI): the slot means over the particles holding each
  slot, then every particle takes the permutation of a cluster's slots that minimises
  its squared distance to those means. Exhaustive over the permutations of clusters up
  to :data:`SORT_MAX` slots (``5! = 120``); larger clusters are left unsorted.
* :func:`merge_slots` -- one target, one slot: slots whose means nearly coincide are
  merged where their holders do not overlap.
"""

from __future__ import annotations

import itertools

import numpy as np

#: the largest cluster sorted exhaustively (its permutations are enumerated)
SORT_MAX = 5


#: slots are coupled when their joint holding departs from independence by more than
#: this share of the rarer slot's holding and by more than COUPLING_Z standard errors
COUPLING_SHARE = 0.05
COUPLING_Z = 3.0


def coupled_slots(valid: np.ndarray) -> np.ndarray:
    """``(T, T)`` bool: slots ``a, b`` whose holding in the particles ``valid (N, T)`` is
    dependent: ``|P(a b) - P(a) P(b)|`` above ``COUPLING_SHARE min(P(a), P(b))`` and above
    ``COUPLING_Z`` binomial standard errors ``sqrt(P(a) P(b) (1 - P(a) P(b)) / N)``, or
    held but never together (``P(a b) = 0``, however rare): above all two slots that hold
    one target in different particles. Recombining such slots from different ancestors
    would give receivers both or neither, a count the posterior does not have, so they
    are sampled as one cluster (joint sampling is valid for any clusters; a needless link
    costs time only)."""
    N = valid.shape[0]
    v = valid.astype(np.float32)
    joint = (v.T @ v).astype(np.float64) / N
    p = np.diag(joint)
    prod = p[:, None] * p[None, :]
    dev = np.abs(joint - prod)
    se = np.sqrt(prod * (1.0 - prod) / N)
    out = (dev > COUPLING_SHARE * np.minimum(p[:, None], p[None, :])) & (dev > COUPLING_Z * se)
    # never held together: alternatives, however few particles hold them
    out |= (joint == 0.0) & (prod > 0.0)
    np.fill_diagonal(out, False)
    return out


def cluster_slots(centres: np.ndarray, active: np.ndarray, gamma: float,
                  coupled: np.ndarray | None = None) -> list[np.ndarray]:
    """Clusters of the active slots: ``centres (T, 2)``, ``active (T,)`` bool; slots
    ``i, j`` are linked when ``|centre_i - centre_j| < gamma`` (Euclidean, positions
    only) or when ``coupled (T, T)`` (:func:`coupled_slots`) says their holdings depend
    on each other wherever they are, and a cluster is a connected component of the
    links. Returns the clusters as arrays of slot indices, each sorted, ordered by their
    first slot.

    The particles' extents are no link (as in the papers): the extent of ``N`` draws
    grows with ``N``, so wide posteriors would put every target in one cluster at large
    ``N`` and undo the independent partitions exactly where a converged filter needs
    them."""
    slots = np.flatnonzero(active)
    parent = {int(s): int(s) for s in slots}

    def root(s: int) -> int:
        while parent[s] != s:
            parent[s] = parent[parent[s]]
            s = parent[s]
        return s

    if len(slots) > 1:
        d = np.linalg.norm(centres[slots, None, :] - centres[None, slots, :], axis=-1)
        link = d < gamma
        if coupled is not None:
            link |= coupled[np.ix_(slots, slots)]
        for i, j in zip(*np.nonzero(np.triu(link, k=1)), strict=True):
            ri, rj = root(int(slots[i])), root(int(slots[j]))
            if ri != rj:
                parent[max(ri, rj)] = min(ri, rj)
    groups: dict[int, list[int]] = {}
    for s in slots:
        groups.setdefault(root(int(s)), []).append(int(s))
    return [np.array(g, dtype=np.int64) for _, g in sorted(groups.items())]


def permutations(h: int) -> np.ndarray:
    """The ``h!`` permutations of ``range(h)`` ``(h!, h)``, the identity first."""
    return np.array(list(itertools.permutations(range(h))), dtype=np.int64)


def sort_slots(pos: np.ndarray, valid: np.ndarray, clusters: list[np.ndarray],
               arrays: list[np.ndarray], iterations: int = 2) -> int:
    """K-means partition sorting in place.

    ``pos (N, T, 2)`` positions, ``valid (N, T)`` bool; ``arrays`` are the per-slot
    arrays ``(N, T, ...)`` to permute along with them (``pos`` and ``valid`` must be
    among them). An empty slot costs nothing wherever it goes. Returns the number of
    particles whose order changed.
    """
    n = pos.shape[0]
    rows = np.arange(n)[:, None]
    changed = 0
    for slots in clusters:
        slots = np.asarray(slots)
        h = len(slots)
        if h < 2 or h > SORT_MAX:
            continue
        perms = permutations(h)  # (P, h)
        for _ in range(iterations):
            v = valid[:, slots]  # (N, h)
            held = v.sum(axis=0)
            if (held == 0).all():
                break
            means = (pos[:, slots] * v[..., None]).sum(axis=0) / np.maximum(held, 1)[:, None]
            # cost[i, q] = sum_j valid * |pos[i, slots[perm_q[j]]] - mean_j|^2
            moved = pos[:, slots][:, perms]  # (N, P, h, 2)
            d2 = ((moved - means[None, None]) ** 2).sum(axis=-1)
            d2 = np.where(v[:, perms], d2, 0.0)
            # a slot without a mean (held nowhere) attracts nothing
            d2 = np.where(held[None, None, :] > 0, d2, 0.0)
            best = np.argmin(d2.sum(axis=-1), axis=1)  # (N,); 0 is the identity
            move = best != 0
            if not move.any():
                break
            changed += int(move.sum())
            src = slots[perms[best[move]]]  # (m, h): new slot j takes old slot src[:, j]
            r = rows[move]
            for a in arrays:
                a[r, slots[None, :]] = a[r, src]
    return changed


def merge_slots(pos: np.ndarray, valid: np.ndarray, arrays: list[np.ndarray],
                distance: float,
                slot_sums: tuple[np.ndarray, np.ndarray] | None = None) -> int:
    """Give one target one slot: when the means of two slots are closer than
    ``distance``, every particle that holds the second slot but not the first moves its
    target into the first (the slot held by more particles). Slots differ only in their
    labels, so the density is unchanged; the split arises when particles start the same
    target in different steps. ``arrays`` as in :func:`sort_slots`; ``slot_sums``
    optionally the holders ``(T,)`` and the sums of the held positions ``(T, 2)`` of
    the current state (in particle order), computed otherwise. Returns the number of
    targets moved."""
    held = valid.sum(axis=0) if slot_sums is None else slot_sums[0]
    slots = np.flatnonzero(held > 0)
    if len(slots) < 2:
        return 0
    if slot_sums is None:
        sums = (pos[:, slots] * valid[:, slots, None]).sum(axis=0)
    else:
        sums = slot_sums[1][slots]
    means = sums / held[slots, None]
    d = np.linalg.norm(means[:, None] - means[None, :], axis=-1)
    moved = 0
    order = slots[np.argsort(-held[slots], kind="stable")]  # keep the most-held slot
    rank = {int(s): r for r, s in enumerate(order)}
    for i, j in zip(*np.nonzero(np.triu(d < distance, k=1)), strict=True):
        a, b = int(slots[i]), int(slots[j])
        if rank[a] > rank[b]:
            a, b = b, a
        move = valid[:, b] & ~valid[:, a]
        if move.any():
            for arr in arrays:
                arr[move, a] = arr[move, b]
            valid[move, b] = False
            moved += int(move.sum())
    return moved

"""Accuracy metrics between the true and the estimated target positions of one step.

All functions take two finite sets of POSITIONS in workspace units::

    truth     (n, 2)   rows (px, py) of the true targets      (callers pass state[:, [0, 2]])
    estimate  (m, 2)   rows (px, py) of the estimated targets

An empty set may be given as shape ``(0,)`` or ``(0, 2)``. Distances are Euclidean,
``d(x, y) = ||x - y||_2``, and ``d_c(x, y) = min(d(x, y), c)`` is the distance cut at ``c``.

Optimal assignments are found with :func:`scipy.optimize.linear_sum_assignment`. The
cut-off and the power are applied to the cost matrix BEFORE assigning (cost ``d_c^p``):
the permutation that minimises ``sum d`` is in general not the one that minimises
``sum d_c^p``, so assigning on raw distances would overstate OSPA/GOSPA.

Metrics are computed outside the timed tracker calls; they are not on the hot path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

__all__ = [
    "GOSPA",
    "OSPA",
    "assigned_rmse",
    "count_error",
    "gospa",
    "ospa",
    "step_metrics",
]


@dataclass(frozen=True)
class OSPA:
    """OSPA distance and its two parts (same units as the positions).

    ``total ** p == localisation ** p + cardinality ** p``.
    """

    total: float
    localisation: float
    cardinality: float


@dataclass(frozen=True)
class GOSPA:
    """GOSPA distance (alpha = 2) and its parts.

    ``total`` is in position units; ``localisation``, ``missed`` and ``false`` are COSTS in
    the p-th-power domain (units ** p), so ``localisation + missed + false == total ** p``.
    ``missed`` and ``false`` are ``c**p / 2`` times the number of missed true targets and of
    false estimates, not the counts themselves.
    """

    total: float
    localisation: float
    missed: float
    false: float


def _as_positions(points: np.ndarray, name: str) -> np.ndarray:
    """``(k, 2)`` float64 array of positions; accepts ``(0,)`` for the empty set."""
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim == 1 and arr.size == 0:
        return arr.reshape(0, 2)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (k, 2) of positions (px, py), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite positions")
    return arr


def _check_order_cutoff(c: float, p: float) -> None:
    if not (np.isfinite(c) and c > 0):
        raise ValueError(f"cut-off c must be positive and finite, got {c}")
    if not (np.isfinite(p) and p >= 1):
        raise ValueError(f"order p must be >= 1 (metric) and finite, got {p}")


def _cut_cost_assignment(
    truth: np.ndarray, estimate: np.ndarray, c: float, p: float
) -> tuple[np.ndarray, np.ndarray]:
    """Optimal assignment of ``min(n, m)`` pairs on the cost ``d_c^p``.

    Returns ``(distances (k,), costs (k,))`` of the assigned pairs, ``k = min(n, m)``:
    raw distances ``d`` and cut costs ``min(d, c) ** p``.
    """
    d = cdist(truth, estimate)  # (n, m)
    cost = np.minimum(d, c) ** p
    rows, cols = linear_sum_assignment(cost)
    return d[rows, cols], cost[rows, cols]


def ospa(truth: np.ndarray, estimate: np.ndarray, c: float = 2.0, p: float = 2.0) -> OSPA:
    """OSPA metric of order ``p`` with cut-off ``c`` (Schuhmacher, Vo & Vo, 2008).

    With ``X = truth`` (n points), ``Y = estimate`` (m points) and, without loss of
    generality, ``n <= m`` (the metric is symmetric; the smaller set is permuted into
    the larger one)::

        d_c(x, y) = min(||x - y||, c)
        D         = min over injections pi of sum_{i=1..n} d_c(x_i, y_pi(i)) ** p
        OSPA      = ( (D + c**p * (m - n)) / m ) ** (1/p)
        loc       = ( D / m ) ** (1/p)
        card      = ( c**p * (m - n) / m ) ** (1/p)

    so ``OSPA**p = loc**p + card**p`` and ``0 <= OSPA <= c``. Both sets empty gives 0
    (all parts 0); exactly one empty gives ``OSPA = card = c``, ``loc = 0``.

    Args:
        truth: ``(n, 2)`` true positions.
        estimate: ``(m, 2)`` estimated positions.
        c: cut-off distance (> 0), position units.
        p: order (>= 1).
    """
    _check_order_cutoff(c, p)
    x = _as_positions(truth, "truth")
    y = _as_positions(estimate, "estimate")
    if len(x) > len(y):
        x, y = y, x
    n, m = len(x), len(y)
    if m == 0:
        return OSPA(0.0, 0.0, 0.0)
    _, costs = _cut_cost_assignment(x, y, c, p)
    loc_p = float(costs.sum()) / m
    card_p = c**p * (m - n) / m
    return OSPA(
        total=(loc_p + card_p) ** (1.0 / p),
        localisation=loc_p ** (1.0 / p),
        cardinality=card_p ** (1.0 / p),
    )


def gospa(
    truth: np.ndarray,
    estimate: np.ndarray,
    c: float = 2.0,
    p: float = 2.0,
    alpha: float = 2.0,
) -> GOSPA:
    """GOSPA metric with ``alpha = 2`` (Rahmathullah, Garcia-Fernandez & Svensson, 2017).

    With ``X = truth`` (n points), ``Y = estimate`` (m points) and ``gamma`` ranging over
    partial assignments (sets of disjoint pairs ``(i, j)``)::

        GOSPA = ( min_gamma [ sum_{(i,j) in gamma} d(x_i, y_j) ** p
                              + c**p / 2 * (#missed + #false) ] ) ** (1/p)
        #missed = n - |gamma|,   #false = m - |gamma|

    Leaving a pair unassigned costs ``c**p / 2 + c**p / 2 = c**p``, so only pairs with
    ``d < c`` are worth assigning and the minimum equals an ordinary assignment of
    ``min(n, m)`` pairs on the cost ``min(d, c) ** p`` plus ``c**p / 2 * |n - m|``; we
    solve that and then count an assigned pair with ``d >= c`` as one missed and one
    false target (at ``d == c`` both readings give the same total).

    Parts, in the p-th-power domain so that ``localisation + missed + false == total**p``::

        localisation = sum over assigned pairs with d < c of d ** p
        missed       = c**p / 2 * #missed
        false        = c**p / 2 * #false

    Both sets empty gives all zeros. Only ``alpha = 2`` is supported: it is the value for
    which the distance splits into localisation, missed and false costs.

    Args:
        truth: ``(n, 2)`` true positions.
        estimate: ``(m, 2)`` estimated positions.
        c: cut-off distance (> 0), position units.
        p: order (>= 1).
        alpha: must be 2.
    """
    _check_order_cutoff(c, p)
    if alpha != 2:
        raise ValueError(f"only alpha = 2 is supported (missed/false split), got {alpha}")
    x = _as_positions(truth, "truth")
    y = _as_positions(estimate, "estimate")
    n, m = len(x), len(y)
    if n == 0 or m == 0:
        n_assigned = 0
        loc = 0.0
    else:
        d, _ = _cut_cost_assignment(x, y, c, p)
        kept = d < c
        n_assigned = int(kept.sum())
        loc = float(np.sum(d[kept] ** p))
    missed = c**p / 2 * (n - n_assigned)
    false = c**p / 2 * (m - n_assigned)
    return GOSPA(
        total=(loc + missed + false) ** (1.0 / p),
        localisation=loc,
        missed=missed,
        false=false,
    )


def assigned_rmse(truth: np.ndarray, estimate: np.ndarray) -> float:
    """Root-mean-square position error over the optimal assignment.

    The ``k = min(n, m)`` pairs minimise the total squared distance (no cut-off)::

        RMSE = sqrt( (1/k) * min over injections pi of sum_i ||x_i - y_pi(i)||**2 )

    Unassigned points are ignored (cardinality errors are in OSPA/GOSPA and the count
    error). Returns ``nan`` when either set is empty. Position units.
    """
    x = _as_positions(truth, "truth")
    y = _as_positions(estimate, "estimate")
    if len(x) == 0 or len(y) == 0:
        return float("nan")
    sq = cdist(x, y, "sqeuclidean")
    rows, cols = linear_sum_assignment(sq)
    return float(np.sqrt(np.mean(sq[rows, cols])))


def count_error(estimated_count: float, true_count: int) -> float:
    """Absolute error of the estimated number of targets, ``|estimated - true|``."""
    return float(abs(float(estimated_count) - float(true_count)))


def step_metrics(
    truth: np.ndarray,
    estimate: np.ndarray,
    estimated_count: float,
    c: float = 2.0,
    p: float = 2.0,
) -> dict[str, float]:
    """All per-step accuracy metrics as one flat dict (one row of the results table).

    ``estimated_count`` is the tracker's count estimate (may be fractional, e.g. a
    posterior mean), which may differ from the number of estimated positions ``m``.
    GOSPA uses ``alpha = 2``; its ``gospa_*`` parts are in the p-th-power domain.

    Keys: ``ospa, ospa_loc, ospa_card, gospa, gospa_loc, gospa_missed, gospa_false,
    rmse, count_error, true_count, n_estimated``.
    """
    x = _as_positions(truth, "truth")
    y = _as_positions(estimate, "estimate")
    o = ospa(x, y, c=c, p=p)
    g = gospa(x, y, c=c, p=p, alpha=2.0)
    return {
        "ospa": o.total,
        "ospa_loc": o.localisation,
        "ospa_card": o.cardinality,
        "gospa": g.total,
        "gospa_loc": g.localisation,
        "gospa_missed": g.missed,
        "gospa_false": g.false,
        "rmse": assigned_rmse(x, y),
        "count_error": count_error(estimated_count, len(x)),
        "true_count": float(len(x)),
        "n_estimated": float(len(y)),
    }

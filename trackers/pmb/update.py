"""The PMB measurement update on the Rayleigh cell sensor (track-oriented, one step).

Measurements and ratios. The looks of a step are summarised per looked cell ``c`` (sorted
unique ``U``): ``n_c`` looks, of which ``k_c`` positive. Only ratios to an empty cell
matter (cells without targets contribute the same factor to every hypothesis: Kreucher,
Kastella and Hero, IEEE TAES 2005, the likelihood ratio of the JMPD; docs/pmb.md);
with ``l(z) = p(z | 1) / p(z | 0)`` of one look (``p_d = p_d(1)``, ``p_f``)::

    L_c = prod_{looks at c} l(z)        a target in c, alone (exact for T_c <= 1)
    M_c = l(0) ** n_c                    a target in c whose own looks all missed it
    S_c = L_c - M_c                      a target in c that is the source of c's detection

so ``M_c = L_c`` and ``S_c = 0`` in a cell without a detection. A cell with a detection is
a *measurement* ``j``; it has at most one source (the point-measurement assumption of the
PMB filters, which Kropfreiter, Williams and Meyer, "Multiobject tracking for thresholded
cell measurements", 2024, keep for cell measurements): a track, a target of the
undetected Poisson process (PPP), or none (a false alarm). A target in a measured cell
that is not its source is "missed" there (ratio ``M_c``); for a target alone in ``c`` the
two add up to the exact ``L_c = S_c + M_c``.

Bernoulli ``i`` (existence ``r_i``, Gaussian ``N(m_i, P_i)``), with ``m_ic`` its mass in
looked cell ``c`` (cells within 6 marginal sd of the mean;
:func:`~mttbench.trackers.gpf.grid.rect_state_moments`) and ``m_i,out = 1 - sum_c m_ic``::

    Q_i  = m_i,out + sum_c m_ic M_c                     (present, source of nothing)
    w_i0 = 1 - r_i + r_i Q_i                            (a_i = 0)
    w_ij = r_i m_ij S_j                                 (a_i = j, the source of cell j)
    beta_j = 1 + lambda_j S_j                           (cell j: false alarm or a new target)

``lambda_j`` is the PPP intensity (expected undetected targets) in cell ``j``, uniform in
the cell; the 1 is the false alarm, whose ratio to an empty cell is 1 by construction.
These are Williams' (TAES 2015, "Marginal multi-Bernoulli filters", the
track-oriented PMB update) single-target weights with ``P_D(x) g(z | x) / lambda_FA``
replaced by ``m_ij S_j`` and the missed-detection factor ``1 - P_D(x)`` by ``M_c``.
The association marginals ``P(a_i = 0)``, ``P(a_i = j)``, ``P(b_j = 0)`` come from loopy
belief propagation (:mod:`.lbp`). The marginal multi-Bernoulli update is then (Williams
2015, the TOMB/P filter):

* track ``i``: ``r_i' = P(a_i = 0) r_i Q_i / w_i0 + sum_j P(a_i = j)``; its density the
  mixture of ``N g_0 / Q_i`` (``g_0 = M_c`` in looked cells, 1 elsewhere: the
  missed-detection truncation) with weight ``P(a_i = 0) r_i Q_i / w_i0`` and of ``N``
  truncated to cell ``j`` with weight ``P(a_i = j)``. A track's density is itself a
  Gaussian mixture (rows ``alpha_r N_r``): each row gives one posterior row per hypothesis
  (Williams' Bernoulli mixture), moment matched within the row (the truncation and moment
  match of :func:`~mttbench.trackers.gpf.grid.known_existence_update`: sums of the
  rectangles' ``(mass, M1, M2)`` from the shared ``rect_state_moments``). The tracker then
  merges the rows of one track that truncate to the same cell, drops rows below a weight
  floor and moment-matches the lightest beyond ``max_components`` into one (the deviation
  from Williams: a bounded mixture; ``max_components = 1`` is the one-Gaussian TOMB);
* measurement ``j``: a new Bernoulli with ``r = P(b_j = 0) lambda_j S_j / beta_j``, uniform
  on the cell (moment matched: centre, variance ``cell^2 / 12``; velocity from the model);
* the PPP: ``lambda_c <- lambda_c M_c`` in every looked cell (its targets missed).

Several targets in one cell (``T >= 2``): a measured cell has one source, so the
"both detected" event of the point model is absent and ``p(z | T)`` enters through
products of single-target factors: in a cell without a detection two targets give
``M_c^2`` = ``l(0)^2`` (exact: ``(1 - p_d(2)) / (1 - p_f)``, 0.305 / 0.5 = 0.61 against
0.25 at ``p_d = 0.5``, ``snr = 10``), in a cell with one detection ``2 S_c M_c + M_c^2``
(about ``p_d(1 - p_d) / p_f`` against the exact ``p_d(2) / p_f``: 0.5 against 0.695 in
units of ``1 / p_f``). So two targets in one cell are under-weighted relative to one (a
mild pull apart, like the point-measurement PMB); docs/pmb.md gives the measured effect.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ...scenarios.model import Grid, RayleighGridSensor
from ..cells import look_log_ratios
from ..gpf.grid import rect_state_moments
from ..grid_backend import looked_in_boxes
from .lbp import Marginals, association_marginals

#: looked cells farther than this many marginal sds from a track's mean are ignored
#: (mass below 2e-9 per axis)
RANGE_SIGMAS = 6.0
#: log-ratios are clipped here (many positive repeats at one cell stay finite)
MAX_LOG = 700.0


@dataclass(frozen=True)
class CellRatios:
    """Per looked cell: ``cells (n_u,)`` sorted unique, ``L (n_u,)``, ``M (n_u,)``,
    ``S = L - M (n_u,)`` (module docstring) and ``positive (n_u,)`` (a detection)."""

    cells: np.ndarray
    L: np.ndarray
    M: np.ndarray
    S: np.ndarray
    positive: np.ndarray


@functools.lru_cache(maxsize=64)
def one_look_ratios(sensor: RayleighGridSensor) -> tuple[float, float, float]:
    """``log l(1)`` of one look with a return and without, as :func:`.cells.
    look_log_ratios` computes them (column 1 of its per-look array), and the miss factor's
    ``log l(0)`` as :func:`cell_ratios` computes it: the compiled update's inputs (the
    sensor is immutable)."""
    pos, neg = sensor.log_likelihood_ratio(np.array([True, False])[:, None],
                                           np.arange(2)[None, :])[:, 1]
    miss = sensor.log_likelihood_ratio(np.array(False), np.array(1))
    return float(pos), float(neg), float(miss)


def cell_ratios(sensor: RayleighGridSensor, cells: np.ndarray, returns: np.ndarray
                ) -> CellRatios:
    """:class:`CellRatios` of the looks ``cells (L,)``, ``returns (L,)`` (repeats multiply)."""
    cells = np.asarray(cells, dtype=np.int64).reshape(-1)
    returns = np.asarray(returns, dtype=bool).reshape(-1)
    U, LL = look_log_ratios(sensor, cells, returns, 1)
    inv = np.searchsorted(U, cells)
    n = np.bincount(inv, minlength=len(U)).astype(float)
    k = np.bincount(inv, weights=returns.astype(float), minlength=len(U))
    ll_miss = float(sensor.log_likelihood_ratio(np.array(False), np.array(1)))
    L = np.exp(np.minimum(LL[:, 1], MAX_LOG))
    M = np.exp(np.minimum(n * ll_miss, MAX_LOG))
    positive = k > 0
    S = np.where(positive, np.maximum(L - M, 0.0), 0.0)
    return CellRatios(U, L, np.where(positive, M, L), S, positive)


@dataclass(frozen=True)
class PMBUpdate:
    """Result of :func:`pmb_update`. Tracks: ``r (T,)``. Posterior Gaussian rows, one per
    (prior row, hypothesis): ``own (R',)`` their track, ``alpha (R',)`` their weight within
    the track (summing to 1 per track with ``r > 0``), ``means (R', 4)``, ``covs (R', 4,
    4)``, ``hyp (R',)`` the hypothesis (-1: the track is the source of nothing; ``j``: the
    source of measured cell ``j``). The measured cells ``meas_cells (J,)`` with their new
    Bernoullis' existence ``r_new (J,)``; the association ``marginals``; ``n_pairs``
    (Gaussian row, looked cell) pairs."""

    r: np.ndarray
    own: np.ndarray
    alpha: np.ndarray
    means: np.ndarray
    covs: np.ndarray
    hyp: np.ndarray
    meas_cells: np.ndarray
    r_new: np.ndarray
    marginals: Marginals
    n_pairs: int


def pmb_update(r: np.ndarray, m: np.ndarray, P: np.ndarray, ratios: CellRatios,
               lam_meas: np.ndarray, grid: Grid, own: np.ndarray | None = None,
               alpha: np.ndarray | None = None, range_sigmas: float = RANGE_SIGMAS
               ) -> PMBUpdate:
    """One PMB update (module docstring) of tracks ``r (T,)`` whose densities are the
    Gaussian mixtures of rows ``m (R, 4)``, ``P (R, 4, 4)``, ``own (R,)`` (the track of each
    row; default: row ``t`` is track ``t``), ``alpha (R,)`` (weights within the track;
    default 1), on the looked cells ``ratios`` with the PPP intensity ``lam_meas (J,)`` at
    the measured cells (``ratios.cells[ratios.positive]``, in that order). The PPP's own
    update (``lambda_c M_c``) is the caller's.

    Each prior row gives one posterior row per hypothesis of its track (Williams' Bernoulli
    mixture): "source of nothing" (the row times ``g_0``, moment matched) and "source of
    measured cell ``j``" (the row truncated to ``j``, for every ``j`` the track may have
    made); weights ``c0 alpha_r Z0_r`` and ``P(a = j) alpha_r m_rj / m_tj``. Moment matching
    a track's rows together gives the single-Gaussian update."""
    r = np.asarray(r, dtype=float)
    T, R = len(r), len(m)
    own = np.arange(R) if own is None else np.asarray(own, dtype=np.int64)
    alpha = np.ones(R) if alpha is None else np.asarray(alpha, dtype=float)
    U = ratios.cells
    n_u = len(U)
    meas = np.nonzero(ratios.positive)[0]
    J = len(meas)
    jmap = np.full(n_u, -1, dtype=np.int64)
    jmap[meas] = np.arange(J)
    # ---- (row, looked cell) pairs within range, each row's Gaussian on each cell
    s = grid.cell_size
    sx = np.sqrt(np.maximum(P[:, 0, 0], 0.0))
    sy = np.sqrt(np.maximum(P[:, 2, 2], 0.0))
    if R and n_u:
        pr, pu = looked_in_boxes(np.floor((m[:, 0] - range_sigmas * sx) / s),
                                 np.floor((m[:, 0] + range_sigmas * sx) / s),
                                 np.floor((m[:, 2] - range_sigmas * sy) / s),
                                 np.floor((m[:, 2] + range_sigmas * sy) / s), U,
                                 grid.nx, grid.ny)
    else:
        pr = pu = np.zeros(0, dtype=np.int64)
    if len(pr):
        x0, x1, y0, y1 = grid.cell_bounds(U[pu])
        mass, M1, M2 = rect_state_moments(m, P, x0.astype(float), x1.astype(float),
                                          y0.astype(float), y1.astype(float), owner=pr)
        mass = np.clip(mass, 0.0, 1.0)
    else:
        mass, M1, M2 = np.zeros(0), np.zeros((0, 4)), np.zeros((0, 4, 4))
    # ---- per (track, looked cell): the track's mass m_tc = sum_r alpha_r m_rc
    key = own[pr] * n_u + pu
    tkey, pair_tc = np.unique(key, return_inverse=True)
    pair_tc = pair_tc.reshape(-1)
    m_tc = np.bincount(pair_tc, weights=alpha[pr] * mass, minlength=len(tkey))
    t_of, u_of = tkey // max(n_u, 1), tkey % max(n_u, 1)
    m_out = 1.0 - np.bincount(t_of, weights=m_tc, minlength=T)
    Q = np.maximum(m_out, 0.0) + np.bincount(t_of, weights=m_tc * ratios.M[u_of], minlength=T)
    # ---- association weights and marginals over (track, measured cell) edges
    w0 = np.maximum(1.0 - r + r * Q, 1e-300)
    is_edge = ratios.positive[u_of] & (m_tc > 0.0)
    edge_of = np.full(len(tkey), -1, dtype=np.int64)
    edge_of[is_edge] = np.arange(int(is_edge.sum()))
    ei, eu = t_of[is_edge], u_of[is_edge]
    w_edge = r[ei] * m_tc[is_edge] * ratios.S[eu]
    nu_new = lam_meas * ratios.S[meas]
    beta = 1.0 + nu_new
    marg = association_marginals(w0, ei, jmap[eu], w_edge, beta)
    c0 = marg.p_missed * r / w0
    # ---- "source of nothing": every row times g_0 (M_c in looked cells, 1 elsewhere)
    coef = ratios.M[pu] - 1.0
    Z0 = 1.0 + np.bincount(pr, weights=coef * mass, minlength=R)
    S1 = np.zeros((R, 4))
    np.add.at(S1, pr, coef[:, None] * M1)
    S2 = P.copy()
    np.add.at(S2, pr, coef[:, None, None] * M2)
    w_miss = c0[own] * alpha * Z0
    ok = Z0 > 1e-300
    d0 = np.where(ok[:, None], S1 / np.where(ok, Z0, 1.0)[:, None], 0.0)
    mean0 = m + d0
    cov0 = np.where(ok[:, None, None], S2 / np.where(ok, Z0, 1.0)[:, None, None], P)
    cov0 = cov0 - d0[:, :, None] * d0[:, None, :]
    # ---- "source of measured cell j": each row truncated to j, weight P(a = j) share
    e_pair = edge_of[pair_tc]
    src = (e_pair >= 0) & (mass > 0.0)
    ps = np.nonzero(src)[0]
    w_src = (marg.p_edge[e_pair[ps]] * alpha[pr[ps]] * mass[ps] / m_tc[pair_tc[ps]])
    d1 = M1[ps] / mass[ps, None]
    mean1 = m[pr[ps]] + d1
    cov1 = M2[ps] / mass[ps, None, None] - d1[:, :, None] * d1[:, None, :]
    # ---- the posterior rows, their track's existence and weights within it
    out_own = np.concatenate([own, own[pr[ps]]])
    w_all = np.concatenate([w_miss, w_src])
    r_post = np.clip(np.bincount(out_own, weights=w_all, minlength=T), 0.0, 1.0)
    tot = np.bincount(out_own, weights=w_all, minlength=T)
    alpha_post = np.where(tot[out_own] > 0.0, w_all / np.where(tot > 0.0, tot, 1.0)[out_own],
                          np.concatenate([alpha, np.zeros(len(ps))]))
    covs = np.concatenate([cov0, cov1])
    covs = 0.5 * (covs + np.swapaxes(covs, -1, -2))
    hyp = np.concatenate([np.full(R, -1, dtype=np.int64), jmap[pu[ps]]])
    r_new = marg.p_unused * nu_new / beta
    return PMBUpdate(r_post, out_own, alpha_post, np.concatenate([mean0, mean1]), covs, hyp,
                     U[meas], r_new, marg, len(pr))

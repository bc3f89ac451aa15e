"""``ss-gnn``'s association and track management by existence (``association="existence"``).

Each track ``k`` is a Bernoulli target: present with probability ``r_k`` (``r <- p_s r`` at
the prediction) in its predicted position Gaussian, whose mass in cell ``c`` is ``m_kc``.
The cell sensor's ratio of one target in ``c`` against none is ``r_c``
(:mod:`~mttbench.trackers.cell_evidence`: ``(p_d / p_f)^k_c ((1 - p_d) / (1 - p_f))^(n_c -
k_c)`` for ``n_c`` looks of which ``k_c`` positive), so the step's looks weigh "track
``k`` is a target" against "it is not" by (a target is in at most one cell)::

    L_k0 = 1 + sum_{c negative} m_kc (r_c - 1)        it takes no detection
    L_kz = L_k0 + m_kz (r_z - 1)                       it takes the detection of cell z

Marginalised over its existence the track's looks are ``1 - r_k + r_k L`` times as likely
as under "no target". A detection no track takes is clutter or a new target, ``1 + u_z
(r_z - 1)`` times as likely as clutter alone, ``u_z = 1 - exp(-lambda_z)`` the probability
of an untracked target in its cell (``lambda_z`` the undetected intensity before the
step's looks). Relative to every detection being clutter or new, an assignment's
likelihood is the product of its hypotheses' weights::

    miss          w_k0 = 1 - r_k + r_k L_k0
    detection z   w_kz = (1 - r_k + r_k L_kz) / (1 + u_z (r_z - 1))

and the GNN takes the assignment of largest product: Stone Soup's ``GNNWith2DAssignment``
on distance hypotheses of distance ``-log w`` (with probability hypotheses it maximises
the **sum** of the weights, which is not an assignment's likelihood). The update is Bayes'
rule for the Bernoulli, ``r <- r L / (1 - r + r L)`` with the ``L`` of the chosen
hypothesis; a detection no track takes starts a track of existence ``r0 = u_z r_z / (u_z
r_z + 1 - u_z)`` (the posterior that its cell holds a new target). These are the equations
of the file-driven GNN (docs/examples/stonesoup_gnn.py, IPDA-style; Musicki, Evans and
Stankovic 1994) but for ``r_c``: the ratio of every look at the cell, where that example
reads only whether the cell was positive (``q1 / q0``); the two agree at one look per cell.
Approximation of both: the weights treat each track's and each free detection's terms as
independent (two tracks' Gaussians in one cell are not coupled), as a GNN does.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import expit, ndtr

from ...scenarios.model import Grid


def cell_mass(grid: Grid, mean_xy: np.ndarray, cov_xy: np.ndarray, cell: int) -> float:
    """The mass of the position Gaussian ``N(mean_xy, cov_xy)`` in ``cell`` (flat index ``iy
    nx + ix``): the product of the per-axis masses (the x-y covariance is dropped, as in
    :func:`~mttbench.trackers.cell_evidence.cell_evidence`; zero when ``F``, ``Q`` and
    ``R`` act per axis)."""
    s = grid.cell_size
    ix, iy = cell % grid.nx, cell // grid.nx
    sx = max(math.sqrt(max(float(cov_xy[0, 0]), 0.0)), 1e-12 * s)
    sy = max(math.sqrt(max(float(cov_xy[1, 1]), 0.0)), 1e-12 * s)
    mx, my = float(mean_xy[0]), float(mean_xy[1])
    return float((ndtr(((ix + 1) * s - mx) / sx) - ndtr((ix * s - mx) / sx))
                 * (ndtr(((iy + 1) * s - my) / sy) - ndtr((iy * s - my) / sy)))


def miss_weight(r: float, lik0: float) -> float:
    """``w_k0 = 1 - r + r L_k0``: the track takes no detection."""
    return 1.0 - r + r * lik0


def detection_weight(r: float, lik0: float, mass: float, ratio: float, u: float) -> float:
    """``w_kz = (1 - r + r (L_k0 + m_kz (r_z - 1))) / (1 + u_z (r_z - 1))``: the track takes
    the detection of cell ``z`` (``ratio = r_z``, ``u = u_z``)."""
    return (1.0 - r + r * (lik0 + mass * (ratio - 1.0))) / (1.0 + u * (ratio - 1.0))


def existence_update(r: np.ndarray | float, lik: np.ndarray | float) -> np.ndarray:
    """Bayes' rule for a Bernoulli of existence ``r`` whose data are ``lik`` times as likely
    with the target as without: ``r L / (1 - r + r L)``."""
    r, lik = np.asarray(r, dtype=float), np.asarray(lik, dtype=float)
    return r * lik / (1.0 - r + r * lik)


def birth_existence(lam: np.ndarray | float, log_ratio: np.ndarray | float) -> np.ndarray:
    """A new track's existence ``u r_z / (u r_z + 1 - u)``, ``u = 1 - exp(-lambda)``:
    ``sigmoid(log(exp(lambda) - 1) + log r_z)`` (0 for ``lambda = 0``)."""
    lam = np.asarray(lam, dtype=float)
    with np.errstate(divide="ignore"):
        return expit(np.log(np.expm1(lam)) + np.asarray(log_ratio, dtype=float))

"""The cell sensor's evidence about one target, shared by the trackers that score tracks
against looks (``kfnn``, ``ss-gnn``, ``ss-gmphd``, ``ss-jpda``).

A look at cell ``c`` is positive with ``p_d`` when a target is in it and with ``p_f`` when
none is (the Rayleigh sensor's ``p_d = p_d(1)``). One target in ``c`` against none, ``n_c``
looks of which ``k_c`` returned 1, has the likelihood ratio::

    r_c = (p_d / p_f) ** k_c * ((1 - p_d) / (1 - p_f)) ** (n_c - k_c)

A track whose predicted position Gaussian puts mass ``m_kc`` in cell ``c`` is in at most
one cell, so the step's ratio of "a target" against "a false track" is ``1 + sum_c m_kc
(r_c - 1)`` over the cells that bear on it (Blackman and Popoli 1999, ch. 6.2, with the
point score replaced by the cell-exact ratio: the cell quantisation is not Gaussian
noise). Blackman's prior odds of a target come from the model's target density per cell.
A target that goes untracked loses intensity by the miss ratio ``(1 - p_d) / (1 - p_f)``
at every look at its cell (pmb's ``l(0)``): a negative look is that much more likely
with the target than without, and a positive one's target becomes a track.

Nothing here costs ``O(cells)``: every function works on the looked cells and on the
cells within 6 sd of a track (:data:`~mttbench.trackers.cells.BOX_SD`).
"""

from __future__ import annotations

import math
import sys
from typing import NamedTuple

import numpy as np
from scipy.special import ndtr

from ..scenarios.model import Grid, RayleighGridSensor, TrackingModel
from .cells import BOX_SD, looked_in_boxes
from .grid_backend import compiled_grid_kernels

#: log r_c is clipped here: r_c - 1 stays finite (many positive looks at one cell)
_MAX_LOG_RATIO = 700.0


def target_prior_logodds(model: TrackingModel) -> float:
    """Blackman's prior log-odds that a detection's track is a target, ``L0 = log(q / (1 -
    q))``, ``q = 1 - exp(-rho)``, ``rho`` the model's target density per cell (initial count
    and one step's arrivals over the grid); ``-inf`` for a model without targets."""
    bd = model.birth_death
    q = -math.expm1(-(bd.initial_count_mean + bd.birth_rate) / model.grid.n_cells)
    if q <= 0.0:
        return -math.inf
    return math.log(q) - math.log1p(-q) if q < 1.0 else math.inf


class LookRatios(NamedTuple):
    """A look at a cell, one target in it against none (the Rayleigh sensor's ``p_d`` and
    ``p_f``): ``log_pos = log(p_d / p_f)`` for a positive look, ``log_neg = log((1 - p_d)
    / (1 - p_f))`` for a negative one, and ``miss = (1 - p_d) / (1 - p_f)``, the ratio of
    a look that misses a target (pmb's ``l(0)``), by which an untracked target's
    intensity falls at every look, positive or not."""

    log_pos: float
    log_neg: float
    miss: float


def look_ratios(sensor: RayleighGridSensor) -> LookRatios:
    """:class:`LookRatios` of ``sensor`` (``p_f`` floored at the smallest float)."""
    p_d, p_f = sensor.p_d, sensor.p_f
    return LookRatios(math.log(p_d) - math.log(max(p_f, sys.float_info.min)),
                      math.log1p(-p_d) - math.log1p(-p_f), (1.0 - p_d) / (1.0 - p_f))


def drop_raise(tested: np.ndarray | float, steps: np.ndarray | float,
               budget_share: float) -> np.ndarray:
    """``max(0, log(rate / f))``, ``rate = (tested + 1) / (steps + 1 / f)``: what a
    confirmed track's deletion drop rises by when its ``steps`` tested it (``tested`` the
    sum of its predicted mass in the tested cells) more often than the model's look budget,
    a share ``f`` of the grid a step spread evenly, would (the drop test restarts at every
    new peak, so a track tested more often is deleted while present more often per step;
    :mod:`~mttbench.trackers.kfnn`)."""
    return np.log(np.maximum((tested + 1.0) / (budget_share * steps + 1.0), 1.0))


def looked_log_ratios(cells: np.ndarray, returns: np.ndarray, log_pos: float,
                      log_neg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The looked cells (sorted), the looks at each, the positive cells (one detection
    each) and ``log r_c`` per looked cell, one target in it against none: ``k_c log_pos +
    (n_c - k_c) log_neg`` (clipped at :data:`_MAX_LOG_RATIO`). With the compiled backend
    :func:`.grid_kernels.looked_log_ratios` computes the same, bit for bit."""
    cells = np.ascontiguousarray(cells, dtype=np.int64).reshape(-1)
    returns = np.ascontiguousarray(returns, dtype=bool).reshape(-1)
    kernels = compiled_grid_kernels()
    if kernels is not None:  # one pass instead of two sorts (the same numbers)
        return kernels.looked_log_ratios(cells, returns, float(log_pos), float(log_neg),
                                         _MAX_LOG_RATIO)
    looked, n_looks = np.unique(cells, return_counts=True)
    det_cells = np.unique(cells[returns])
    positive = np.bincount(np.searchsorted(looked, cells[returns]), minlength=len(looked))
    log_r = np.minimum(positive * log_pos + (n_looks - positive) * log_neg, _MAX_LOG_RATIO)
    return looked, n_looks, det_cells, log_r


def cell_evidence(grid: Grid, mean_xy: np.ndarray, cov_xy: np.ndarray, looked: np.ndarray,
                  log_r: np.ndarray, det_cells: np.ndarray, rows: np.ndarray,
                  hit_cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``log(1 + sum_c m_kc (r_c - 1))`` per track ``(K,)``: ``c`` over the negative
    looked cells in the track's 6-sd box and, for the tracks ``rows``, their associated
    detection's cell ``hit_cells``; ``m_kc`` the predicted position Gaussian's mass.
    Also ``min(1, sum_c m_kc)`` per track, the share of it those looks tested. With the
    compiled backend (:mod:`.grid_backend`) :func:`.grid_kernels.cell_evidence` computes
    the same numbers, bit for bit."""
    s = grid.cell_size
    kernels = compiled_grid_kernels()
    if kernels is not None:  # the same arithmetic in one pass (bit for bit)
        c = np.ascontiguousarray
        return kernels.cell_evidence(
            float(s), grid.nx, grid.ny, c(mean_xy, dtype=float), c(cov_xy, dtype=float),
            float(BOX_SD), c(looked, dtype=np.int64), c(log_r, dtype=float),
            c(det_cells, dtype=np.int64), c(rows, dtype=np.int64),
            c(hit_cells, dtype=np.int64))
    sx = np.maximum(np.sqrt(np.maximum(cov_xy[:, 0, 0], 0.0)), 1e-12 * s)
    sy = np.maximum(np.sqrt(np.maximum(cov_xy[:, 1, 1], 0.0)), 1e-12 * s)
    mx, my = mean_xy[:, 0], mean_xy[:, 1]
    negative = looked[~_member(looked, det_cells)]
    with np.errstate(invalid="ignore", over="ignore"):
        box, i = looked_in_boxes(
            np.floor((mx - BOX_SD * sx) / s), np.floor((mx + BOX_SD * sx) / s),
            np.floor((my - BOX_SD * sy) / s), np.floor((my + BOX_SD * sy) / s),
            negative, grid.nx, grid.ny)
    box = np.concatenate([box, np.asarray(rows, dtype=np.int64)])
    cell = np.concatenate([negative[i], np.asarray(hit_cells, dtype=np.int64)])
    if not len(box):
        return np.zeros(len(mean_xy)), np.zeros(len(mean_xy))
    ix, iy = cell % grid.nx, cell // grid.nx
    mass = ((ndtr(((ix + 1) * s - mx[box]) / sx[box]) - ndtr((ix * s - mx[box]) / sx[box]))
            * (ndtr(((iy + 1) * s - my[box]) / sy[box])
               - ndtr((iy * s - my[box]) / sy[box])))
    ratio_minus_1 = np.expm1(log_r[np.searchsorted(looked, cell)])
    total = np.bincount(box, weights=mass * ratio_minus_1, minlength=len(mean_xy))
    looked_mass = np.minimum(np.bincount(box, weights=mass, minlength=len(mean_xy)), 1.0)
    # r_c - 1 >= -1, so the sum stays above -1 (mass <= 1): log1p is finite
    return np.log1p(np.maximum(total, -1.0 + 1e-300)), looked_mass




def _member(x: np.ndarray, sorted_set: np.ndarray) -> np.ndarray:
    """``np.isin(x, sorted_set)`` for a sorted ``sorted_set``, by binary search."""
    if not len(sorted_set):
        return np.zeros(len(x), dtype=bool)
    i = np.minimum(np.searchsorted(sorted_set, x), len(sorted_set) - 1)
    return sorted_set[i] == x

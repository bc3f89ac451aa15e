"""KF-NN: one Kalman filter per track, gated nearest-neighbour association, and a
sequential track score (Blackman's SPRT) that confirms and deletes tracks.

The classical baseline tracker. Tracks are held as arrays with a leading track
axis ``K`` (no object per track): means ``(K, 4)``, covariances ``(K, 4, 4)``, ids,
the track score, a confirmed flag and the age in steps.

Measurements (Rayleigh grid sensor only)
    Every cell with at least one positive look during the step gives ONE point
    detection ``z = (cx, cy)`` at the cell centre -- several positive looks at the
    same cell in one step are one detection (they cannot be told apart: they see
    the same targets), and a cell with one positive and some negative looks counts
    as positive. The detection model is ``z = H x + w``, ``H`` picking
    ``(px, py)``, ``w ~ N(0, R)``, ``R = cell_size**2 / 12 * I`` (the variance of a
    position uniform over the cell). This treats the quantisation error as white
    noise, which it is not for a slow target: the filter grows over-confident
    inside one cell, and a crossing into the next cell may fall outside the gate
    (the track is then replaced by a new one).

Prediction
    ``m <- F m``, ``P <- F P F^T + Q`` with ``F``, ``Q`` of the model
    (:mod:`trackers.kalman`). With boundary ``"die"`` a track whose predicted mean
    leaves the workspace is deleted; with ``"reflect"`` the filter does not model
    the bounce (the cell of a mean outside the workspace is the nearest edge cell).

Gating and association
    Innovation ``y = z - H m``, ``S = H P H^T + R``, ``d^2 = y^T S^-1 y``; a pair is
    admissible when ``d^2 < chi2.ppf(gate_probability, 2)``. Up to :data:`DENSE_PAIRS`
    track-detection pairs ``d^2`` is computed for every pair; beyond (hundreds of tracks)
    only for the pairs a k-d tree finds within the gate's radius (:func:`gated_pairs`),
    and the assignment below is solved per connected component of the admissible pairs
    (:func:`associate_pairs`: the same optimum; of assignments tied for it exactly, another
    may be chosen).
    ``association="global"`` (default) solves one assignment problem
    (``scipy.optimize.linear_sum_assignment``) on the gated ``d^2`` with forbidden
    pairs priced above any sum of admissible ones: the result has the largest
    possible number of admissible pairs and, among those, the least total ``d^2``.
    ``association="greedy"`` repeatedly takes the admissible pair of smallest
    ``d^2`` whose track and detection are both still free. Associated tracks get a
    Kalman update (Joseph form).

Birth
    Every unassociated detection starts a tentative track at the cell centre with zero
    velocity, ``P = diag(R_x, sv^2, R_y, sv^2)``, ``sv = birth_velocity_scale`` times the
    model's ``birth_velocity_std``.

Track score (sequential probability ratio test; Blackman and Popoli 1999, ch. 6.2)
    Each track carries ``L``, the log-likelihood ratio of "a target" (H1) against "a
    false track" (H0) of the looks since its birth. The looks of a step that can bear on
    track ``k`` are the looked cells ``c`` inside its predicted position's 6-sd box; with
    ``m_kc`` the predicted Gaussian's mass in ``c`` (x-y correlation ignored) and ``n_c``
    looks at ``c`` of which ``k_c`` returned 1, one target in ``c`` against none gives the
    per-cell ratio (the model's ``p_d = p_d(1)`` and ``p_f``)::

        r_c = (p_d / p_f) ** k_c * ((1 - p_d) / (1 - p_f)) ** (n_c - k_c)

    and, the target being in at most one cell,
    ``L <- L + log(1 + sum_c m_kc (r_c - 1))`` over the track's negative cells and the
    cell of its associated detection (a positive cell given to another track tells this
    one nothing). A birth starts at its cell's ``log r_c``. Blackman's score adds the
    prior odds that the detection is a new target, one per track from its birth cell
    ``c``: ``L0 = log(exp(lambda) - 1)``, the log-odds of ``1 - exp(-lambda)`` (at least
    one untracked target in ``c``), ``lambda = lambda_c`` the untracked intensity there
    before the step's looks (below) plus, on a model without arrivals, the share of its
    expected count ``E[N_k] = p_s^k n0`` that neither the tracks (``sum r``) nor the
    intensity holds, ``max(0, E[N_k] - sum r - sum lambda) / n`` (the rule of the Stone
    Soup peers, :mod:`~mttbench.trackers.stonesoup.peers`). At the first step this is
    Blackman's prior of the model's density per cell; where the looks have since found
    nothing, or a track holds the target, a detection is most likely clutter and starts
    less likely (docs/kfnn.md). ``sigmoid(L0 + L)`` is the posterior probability that the
    track is a target (the ratios: :mod:`~mttbench.trackers.cell_evidence`). With
    ``alpha = false_track_probability`` and ``beta =
    lost_track_probability``::

        confirm when L0 + L >= log((1 - alpha) / alpha)   (P(false track) <= alpha)
        delete  when L <= T1 = log(beta / (1 - alpha))     (Wald's lower threshold)
        delete a confirmed track when L <= max L - log(1 / beta) - max(0, log(rate / f))

    The tentative deletion reads the evidence since the birth alone: in heavy clutter the
    prior odds of a single detection are far below ``T1``, and a test that starts below its
    lower threshold never runs. A confirmed track is deleted when its score drops ``log(1 /
    beta)`` below the highest it reached (Blackman's score-drop deletion): under "still
    there" the ratio of "gone" to "there" is a martingale, so it grows by ``1 / beta`` with
    probability at most ``beta`` (Ville), whatever ``alpha`` (Wald's ``|T1|`` as the drop
    would tie it to ``alpha``; docs/kfnn.md). That test starts again at every new
    peak (a CUSUM, with a false alarm about every ``1 / beta`` tests), so a track tested
    more often deletes a present target more often per step: the drop is raised by
    ``log(rate / f)``, ``f`` the model's looks per step over the grid's cells (how often
    the budget spread evenly tests a track) and ``rate = (tested + 1) / (age + 1 / f)``,
    ``tested`` the sum over its steps of its predicted mass in the cells that bore on its
    score. Under raster ``rate`` stays near ``f`` and nothing changes; under renyi, which
    looks at held tracks every step, the false deletions per step return to ``beta``'s
    (docs/kfnn.md). The score is not capped, so
    ``sigmoid(L0 + L)`` of a long-held track tends to 1. The thresholds keep their meaning
    at any clutter and density: at ``p_f = 5e-4`` with 3 targets on 144 cells one
    first-step detection confirms (``6.93 - 3.86 >= 0``), at ``p_d = 0.9, p_f = 0.31``
    (``log r = 1.07`` per hit, ``-1.93`` per miss) several. Under H0 the ratio is a
    martingale from the birth's ``r_c``, so of the tracks born from false alarms at most
    ``r_birth / exp(T2 - L0)`` are confirmed (Ville's inequality; a test checks it), ``T2 =
    log((1 - alpha) / alpha)``. The default ``alpha = 1/2`` confirms a track once it is
    more likely a target than not.
    Confirmation does not decide what is reported (Estimate, below): ``alpha`` only moves
    a track from Wald's test to the drop from its peak.
    A track whose box holds no looked cell coasts (``L`` unchanged).

Estimate
    The ``round(sum r)`` tracks of largest existence ``r = sigmoid(L0 + L)``, confirmed or
    not (count ``sum r``, the mean of their Poisson-binomial count): the count estimate of
    a Bayesian filter (pmb and the GPF report the same way), which keeps the cardinality
    OSPA charges ``c`` for. Confirmation (``alpha``) decides which deletion test a track
    is under. (The confirmed tracks alone report nothing where a detection is worth too
    little to confirm within the run, and every false alarm confirmed at birth until the
    raster refutes it; docs/kfnn.md.)

Predicted count distribution ``P_c(t)`` (for sensor management)
    Each track is a Bernoulli target, present with the posterior probability of its
    score, ``sigmoid(L0 + L)``, and
    then in cell ``c`` with the mass of its predicted position Gaussian there
    (:func:`trackers.cells.gaussian_cell_mass_sparse`: x-y correlation ignored, and
    only the cells within 6 marginal sd of the mean, which leaves out less than 4e-9
    of its mass). Targets not yet tracked are an undetected Poisson intensity
    ``lambda_c`` per cell: ``initial_count_mean / n_cells`` at reset, ``lambda <- p_s
    lambda + birth_rate / n_cells`` at each predict (no spatial diffusion), and
    ``lambda_c <- lambda_c (1 - p_d) / (1 - p_f)`` for each look at ``c``, positive or not
    (the ratio of a look that misses a target, pmb's ``l(0)``: a negative look is ``(1 -
    p_d) / (1 - p_f)`` times as likely with the target as without, and a positive one's
    target becomes a track; ``(1 - p_d)`` alone would count the clutter's share of a
    negative look as evidence against targets). A deleted
    track's existence ``sigmoid(L0 + L)`` returns to it over its Gaussian's cells,
    ``lambda_c += r m_c`` (recycling, Williams 2012, as pmb: without it a target whose
    track was deleted leaves no trace, and a policy that looks where it expects targets
    would not look there again; a track leaving the workspace under ``die`` is not
    recycled). The
    intensity enters as one more Bernoulli per cell with probability ``1 -
    exp(-lambda_c)`` (at least one untracked target). Per cell, the count of these
    independent Bernoullis is Poisson-binomial (:func:`trackers.cells.
    bernoulli_cell_counts`), truncated to 0..3 with the last column "3 or more".

Cost per step: nothing per cell of the grid. The association and the filters cost
``O(tracks + looks)``; the intensity is a :class:`~trackers.cells.CellField`, one value
shared by the cells never looked at plus the cells looked at so far with their own (the
same arithmetic as a dense array, bit for bit), so its predict costs ``O(cells looked at
so far)``, two flops each (at most the looks made so far, at most the grid).
``P_c(t)`` is a :class:`~trackers.cells.CellCounts`: rows of their own for the cells in
a track's 6-sd box and the looked-at cells, the untracked-only row for all others.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.special import expit

from ..scenarios.model import Looks, RayleighGridSensor, TrackingModel
from . import kalman
from .base import (
    BOX_CELLS,
    LOOKED_CELL_BYTES,
    LOOKED_CELL_S,
    TARGET_S,
    Estimate,
    ResourceTerms,
    Tracker,
    gaussian_boxes,
    register,
)
from .cell_evidence import (
    cell_evidence,
    drop_raise,
    look_ratios,
    looked_log_ratios,
)
from .cells import (
    CellCounts,
    CellField,
    bernoulli_cell_counts,
    gaussian_cell_mass_sparse,
    untracked_probabilities,
)
from .grid_backend import compiled_grid_kernels
from .params import Budget, Param, Search
from .pmb.ppp import recycle

#: count columns of P_c: 0, 1, 2 and "3 or more"
N_COUNTS = 4
#: at most this many (track, detection) pairs: the association works on the full
#: ``(K, D)`` array; above, on the pairs within the gate only (:func:`gated_pairs`)
DENSE_PAIRS = 10_000
#: seconds per step beyond the per-target terms (:meth:`KFNNTracker.resource_terms`)
KFNN_STEP_S = 5e-4
#: H picks (px, py) out of [px, vx, py, vy]
_H = np.eye(4)[kalman.POSITION]


def associate(cost: np.ndarray, gate: float, method: str = "global"
              ) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-neighbour association of tracks (rows) to detections (columns).

    ``cost (K, D)`` holds squared Mahalanobis distances; pairs with ``cost >= gate``
    (or non-finite) are not admissible.

    * ``"global"``: maximise the number of admissible pairs, then minimise their
      total cost (one ``linear_sum_assignment`` with inadmissible pairs priced at
      ``gate * (min(K, D) + 1)``, more than any sum of admissible costs).
    * ``"greedy"``: repeatedly take the admissible pair with the smallest cost
      among free tracks and detections (ties broken by row-major order).

    Returns ``(rows, cols)``, int64 arrays of equal length, sorted by row.
    """
    cost = np.asarray(cost, dtype=float)
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    if cost.ndim != 2:
        raise ValueError(f"cost must be (K, D), got shape {cost.shape}")
    admissible = np.isfinite(cost) & (cost < gate)
    if not admissible.any():
        return empty
    if method == "global":
        big = gate * (min(cost.shape) + 1.0)
        priced = np.where(admissible, cost, big)
        rows, cols = linear_sum_assignment(priced)  # rows sorted (scipy's contract)
        keep = admissible[rows, cols]
        return rows[keep].astype(np.int64), cols[keep].astype(np.int64)
    elif method == "greedy":
        cand_r, cand_c = np.nonzero(admissible)  # row-major order
        order = np.argsort(cost[cand_r, cand_c], kind="stable")
        row_free = np.ones(cost.shape[0], dtype=bool)
        col_free = np.ones(cost.shape[1], dtype=bool)
        rows_l, cols_l = [], []
        for i in order:  # at most K*D admissible pairs; K and D are small
            r, c = cand_r[i], cand_c[i]
            if row_free[r] and col_free[c]:
                row_free[r] = col_free[c] = False
                rows_l.append(r)
                cols_l.append(c)
        rows, cols = np.array(rows_l, dtype=np.int64), np.array(cols_l, dtype=np.int64)
        by_row = np.argsort(rows, kind="stable")
        return rows[by_row], cols[by_row]
    raise ValueError(f"association must be 'global' or 'greedy', got {method!r}")


def gated_pairs(pred_z: np.ndarray, S: np.ndarray, z: np.ndarray, gate: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The admissible (track, detection) pairs: ``d2 = y^T S_k^-1 y < gate`` with ``y = z_j
    - pred_z[k]``, without forming all ``K x D`` pairs.

    ``d2 < gate`` implies ``|y|^2 < gate * lambda_max(S_k)``, so a k-d tree over the
    detections (``scipy.spatial.cKDTree``) lists the detections within that radius of the
    tracks (``O((K + D) log D)`` plus the pairs found) and ``d2`` is computed for those only,
    the same expression per pair as on the full ``(K, D)`` array (tracks grouped in bands
    of radius within a factor 2, one search per band). Returns ``rows, cols``
    (int64, sorted row-major) and ``d2`` of the pairs with ``d2 < gate``.
    """
    K, D = len(pred_z), len(z)
    empty = np.zeros(0, dtype=np.int64)
    if K == 0 or D == 0:
        return empty, empty, np.zeros(0)
    a, b, c = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    lam = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)  # largest eigenvalue of S_k
    radius = np.sqrt(gate * lam) * (1.0 + 1e-9) + 1e-12
    ok = np.isfinite(radius) & np.all(np.isfinite(pred_z), axis=1)
    # tracks in bands of radius (powers of two): one search per band, at its largest radius
    tree = cKDTree(z)
    band = np.where(ok, np.ceil(np.log2(np.maximum(radius, 1e-300))), 0).astype(np.int64)
    rows_l, cols_l = [empty], [empty]
    for b in np.unique(band[ok]):
        members = np.flatnonzero(ok & (band == b))
        found = cKDTree(pred_z[members]).sparse_distance_matrix(
            tree, float(radius[members].max()), output_type="ndarray")
        rows_l.append(members[found["i"]].astype(np.int64))
        cols_l.append(found["j"].astype(np.int64))
    rows, cols = np.concatenate(rows_l), np.concatenate(cols_l)
    # a track whose mean or covariance is not finite: every detection, as the full array
    bad = np.flatnonzero(~ok)
    if len(bad):
        rows = np.concatenate([rows, np.repeat(bad, D)])
        cols = np.concatenate([cols, np.tile(np.arange(D), len(bad))])
    order = np.lexsort((cols, rows))
    rows, cols = rows[order], cols[order]
    d2 = kalman.mahalanobis_sq(z[cols] - pred_z[rows], S[rows])
    keep = np.isfinite(d2) & (d2 < gate)
    return rows[keep], cols[keep], d2[keep]


def associate_pairs(rows: np.ndarray, cols: np.ndarray, cost: np.ndarray, gate: float,
                    method: str = "global") -> tuple[np.ndarray, np.ndarray]:
    """:func:`associate` from the admissible pairs only (``rows, cols`` sorted row-major,
    ``cost < gate``), in ``O(pairs)`` plus the assignment problems.

    ``"greedy"``: the same pairs in the same order, so the same result. ``"global"``:
    the number of admissible pairs and their total cost are sums over the connected
    components of the admissibility graph, so each component is solved on its own
    (``linear_sum_assignment`` on its rows and columns, inadmissible pairs priced as in
    :func:`associate`), a component of one pair taken as it is. That is the full
    problem's optimum; when several assignments tie for it exactly, the one chosen
    may differ from the full problem's.
    """
    rows = np.asarray(rows, dtype=np.int64)
    cols = np.asarray(cols, dtype=np.int64)
    cost = np.asarray(cost, dtype=float)
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    if not len(rows):
        return empty
    if method == "greedy":
        order = np.argsort(cost, kind="stable")
        row_free, col_free = {}, {}
        out_r, out_c = [], []
        for i in order:
            r, c = int(rows[i]), int(cols[i])
            if r not in row_free and c not in col_free:
                row_free[r] = col_free[c] = True
                out_r.append(r)
                out_c.append(c)
        out_r, out_c = np.array(out_r, dtype=np.int64), np.array(out_c, dtype=np.int64)
    elif method == "global":
        # components of the bipartite graph: nodes are the rows, then the columns
        ur, ri = np.unique(rows, return_inverse=True)
        uc, ci = np.unique(cols, return_inverse=True)
        n_r = len(ur)
        graph = coo_matrix((np.ones(len(rows)), (ri, n_r + ci)),
                           shape=(n_r + len(uc),) * 2)
        _, label = connected_components(graph, directed=False)
        comp = label[ri]
        size = np.bincount(comp)
        single = size[comp] == 1
        out_r, out_c = [rows[single]], [cols[single]]
        multi = np.flatnonzero(~single)
        if len(multi):
            part = multi[np.argsort(comp[multi], kind="stable")]
            pc = comp[part]
            # each component's rows and columns numbered from 0, ascending (one pass)
            kr, lr = np.unique(pc * (len(ur) + 1) + ri[part], return_inverse=True)
            kc, lc = np.unique(pc * (len(uc) + 1) + ci[part], return_inverse=True)
            first_r = np.searchsorted(kr // (len(ur) + 1), pc)
            first_c = np.searchsorted(kc // (len(uc) + 1), pc)
            lr, lc = lr - first_r, lc - first_c
            starts = np.flatnonzero(np.r_[True, pc[1:] != pc[:-1]])
            for a, b in zip(starts, np.r_[starts[1:], len(part)], strict=True):
                n_r, n_c = int(lr[a:b].max()) + 1, int(lc[a:b].max()) + 1
                big = gate * (min(n_r, n_c) + 1.0)
                priced = np.full((n_r, n_c), big)
                priced[lr[a:b], lc[a:b]] = cost[part[a:b]]
                admissible = np.zeros((n_r, n_c), dtype=bool)
                admissible[lr[a:b], lc[a:b]] = True
                rr, cc = linear_sum_assignment(priced)
                keep = admissible[rr, cc]
                # back to track and detection indices: local index -> the pair holding it
                row_of = np.empty(n_r, dtype=np.int64)
                row_of[lr[a:b]] = rows[part[a:b]]
                col_of = np.empty(n_c, dtype=np.int64)
                col_of[lc[a:b]] = cols[part[a:b]]
                out_r.append(row_of[rr[keep]])
                out_c.append(col_of[cc[keep]])
        out_r, out_c = np.concatenate(out_r), np.concatenate(out_c)
    else:
        raise ValueError(f"association must be 'global' or 'greedy', got {method!r}")
    by_row = np.argsort(out_r, kind="stable")
    return out_r[by_row].astype(np.int64), out_c[by_row].astype(np.int64)


@register
class KFNNTracker(Tracker):
    """Kalman filter per track with gated nearest-neighbour association (module docstring)."""

    name = "kfnn"
    summary = ("Kalman filter per track, gated nearest-neighbour association of cell "
               "detections, SPRT track score from the model's p_d and p_f")
    parameters: ClassVar[dict[str, Param]] = {
        # tuning (mttbench tune): the gate as d^2 = 4.6 ... 23; the two SPRT error rates
        # over the decades where Wald's thresholds move from one detection to many (alpha
        # up to 1/2, the default: confirm a track once it is more likely a target than
        # not, docs/kfnn.md); the
        # birth velocity sd as a multiple of the model's, half to twice
        "gate_probability": Param(float, 0, 1, low_open=True, high_open=True,
                                  doc="gate d^2 < chi2.ppf(gate_probability, 2)",
                                  search=Search(choices=(0.9, 0.95, 0.99, 0.999, 0.9999,
                                                         0.99999))),
        "association": Param(choices=("global", "greedy"),
                             search=Search(choices=("global", "greedy"))),
        "false_track_probability": Param(
            float, 0, 1, low_open=True, high_open=True,
            doc="SPRT alpha: a false track is confirmed with at most this probability",
            search=Search(1e-6, 0.5, log=True)),
        "lost_track_probability": Param(
            float, 0, 1, low_open=True, high_open=True,
            doc="SPRT beta: a true track is deleted with at most this probability",
            search=Search(1e-3, 0.5, log=True)),
        "birth_velocity_scale": Param(float, 0, low_open=True,
                                      doc="velocity sd of a new track, in multiples of the "
                                          "model's birth velocity sd",
                                      search=Search(0.5, 2.0, log=True)),
    }
    #: no budget: one track per target, nothing to trade
    budget: ClassVar[dict[str, Budget]] = {}

    def __init__(
        self,
        gate_probability: float = 0.9999,
        association: str = "global",
        false_track_probability: float = 0.5,
        lost_track_probability: float = 0.1,
        birth_velocity_scale: float = 1.0,
    ) -> None:
        self.gate_probability = gate_probability
        self.association = association
        self.false_track_probability = false_track_probability
        self.lost_track_probability = lost_track_probability
        self.birth_velocity_scale = birth_velocity_scale

    # ----------------------------------------------------------------- checks
    def unsupported_reason(self, model: TrackingModel) -> str | None:
        if not isinstance(model.sensor, RayleighGridSensor):
            return ("KF-NN associates per-target detections; the superposition sensor "
                    "reports only the mean of all targets, so there is nothing to associate")
        return None

    # ------------------------------------------------------------- life cycle
    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        """Empty track arrays; the undetected intensity gets the initial count prior."""
        reason = self.unsupported_reason(model)
        if reason:
            raise ValueError(reason)
        self.validate_params(self.get_params())  # the declaration above (built directly)
        self._model = model
        self._rng = rng  # unused: the tracker is deterministic
        compiled_grid_kernels()  # compile or load the cell kernels now, not in a timed step
        self._grid = model.grid
        self._F, self._Q = model.dynamics.F, model.dynamics.Q
        s = model.grid.cell_size
        self._r_var = s * s / 12.0
        self._R = self._r_var * np.eye(2)
        self._gate = kalman.gate_d2(self.gate_probability)
        bd = model.birth_death
        sv = self.birth_velocity_scale * bd.birth_velocity_std
        self._birth_P = np.diag([self._r_var, sv * sv, self._r_var, sv * sv])
        self._p_s, self._boundary = bd.survival_probability, bd.boundary
        n = model.grid.n_cells
        self._birth_per_cell = bd.birth_rate / n
        sensor = model.sensor
        self._log_pos, self._log_neg, self._miss = look_ratios(sensor)
        alpha, beta = self.false_track_probability, self.lost_track_probability
        # confirmed when P(false track | looks) <= alpha: L0 + L >= log((1 - alpha) / alpha)
        self._confirm_at = math.log1p(-alpha) - math.log(alpha)
        self._delete_at = math.log(beta) - math.log1p(-alpha)  # T1
        # a confirmed track is deleted when its score drops log(1 / beta) below its peak:
        # under "still there" the ratio of "gone" to "there" is a martingale, so it rises
        # by 1 / beta with probability at most beta (Ville), whatever alpha
        self._drop = -math.log(beta)
        self._budget_share = min(1.0, model.sensor.looks_per_step / n)
        self._undetected = CellField(n, bd.initial_count_mean / n)  # lambda_c
        self._expected = bd.initial_count_mean  # the model's expected count, E[N_k]
        # the tracks: leading axis K
        self._m = np.zeros((0, 4))
        self._P = np.zeros((0, 4, 4))
        self._id = np.zeros(0, dtype=np.int64)
        self._score = np.zeros(0)  # L: the SPRT log-likelihood ratio since birth
        self._prior_logodds = np.zeros(0)  # L0: a new target's prior log-odds at birth
        self._peak = np.zeros(0)  # a confirmed track's highest L (its deletion reference)
        self._tested = np.zeros(0)  # sum over steps of its predicted mass in tested cells
        self._confirmed = np.zeros(0, dtype=bool)
        self._age = np.zeros(0, dtype=np.int64)  # steps since birth
        self._next_id = 0

    def _keep(self, keep: np.ndarray) -> None:
        """Drop the tracks where ``keep (K,)`` is False."""
        self._m, self._P, self._id = self._m[keep], self._P[keep], self._id[keep]
        self._score, self._peak = self._score[keep], self._peak[keep]
        self._prior_logodds = self._prior_logodds[keep]
        self._tested = self._tested[keep]
        self._confirmed = self._confirmed[keep]
        self._age = self._age[keep]

    def predict(self) -> None:
        """Kalman predict of every track; undetected intensity ``p_s lambda + b / n``."""
        self._m, self._P = kalman.predict(self._m, self._P, self._F, self._Q)
        self._age += 1
        grid = self._grid
        width, height = grid.extent
        if self._boundary == "die" and len(self._m):
            px, py = self._m[:, 0], self._m[:, 2]
            self._keep((px >= 0) & (px < width) & (py >= 0) & (py < height))
        self._undetected.affine(self._p_s, self._birth_per_cell)
        self._expected = self._p_s * self._expected + self._birth_per_cell * self._grid.n_cells

    def cell_count_distribution(self) -> CellCounts:
        """Poisson-binomial of track Bernoullis and untracked targets: rows of their own
        for the cells within 6 sd of a track and the cells looked at so far, the default
        row (untracked targets only) everywhere else."""
        comp, cells, mass = gaussian_cell_mass_sparse(
            self._grid, *kalman.position_marginal(self._m, self._P))
        exist = expit(self._prior_logodds + self._score)
        return bernoulli_cell_counts(self._grid.n_cells, N_COUNTS, cells, mass * exist[comp],
                                     *untracked_probabilities(self._undetected))

    def update(self, looks: Looks) -> None:
        """Associate, update, score hits/misses, confirm/delete, and start new tracks."""
        grid = self._grid
        # log r_c of each looked cell: one target in it against none
        looked, n_looks, det_cells, log_r = looked_log_ratios(
            looks.cells, looks.returns, self._log_pos, self._log_neg)
        z = grid.cell_centers(det_cells)  # (D, 2)
        K, D = len(self._m), len(det_cells)
        det_used = np.zeros(D, dtype=bool)
        rows = cols = np.zeros(0, dtype=np.int64)
        if K:
            pred_z, P_pos = kalman.position_marginal(self._m, self._P)
        if K and D:
            # d2[k, j] = y^T S_k^-1 y, y = z_j - H m_k, S_k = H P_k H^T + R, for the pairs
            # within the gate only (a k-d tree), then the assignment per component
            S = P_pos + self._R  # (K, 2, 2)
            if K * D <= DENSE_PAIRS:  # every pair: small, and the same numbers as always
                y = z[None, :, :] - pred_z[:, None, :]  # (K, D, 2)
                d2 = kalman.mahalanobis_sq(y, S[:, None, :, :])
                rows, cols = associate(d2, self._gate, self.association)
            else:  # the pairs within the gate only (a k-d tree), solved per component
                pr, pc, d2 = gated_pairs(pred_z, S, z, self._gate)
                rows, cols = associate_pairs(pr, pc, d2, self._gate, self.association)
        if K:
            # the score's evidence from the predicted Gaussians, then the Kalman update
            gain, tested = cell_evidence(grid, pred_z, P_pos, looked, log_r, det_cells, rows,
                                         det_cells[cols])
            self._score = self._score + gain
            self._tested = self._tested + tested
        if len(rows):
            m_new, P_new, _, _ = kalman.update(self._m[rows], self._P[rows], z[cols],
                                               _H, self._R)
            self._m[rows], self._P[rows] = m_new, P_new
            det_used[cols] = True

        self._confirm()
        # a tentative track's test ends at T1; a confirmed one is deleted below its peak,
        # by a drop raised where the track is looked at more often than the budget's share
        drop = self._drop + drop_raise(self._tested, self._age, self._budget_share)
        keep = np.where(self._confirmed, self._score > self._peak - drop,
                        self._score > self._delete_at)
        gone = ~keep
        dropped = (expit(self._prior_logodds[gone] + self._score[gone]), self._m[gone],
                   self._P[gone])
        self._keep(keep)

        # a new track's prior: the untracked targets in its cell before this step's looks
        new_cells = det_cells[~det_used]
        n_new = len(new_cells)
        prior_new = self._birth_prior_logodds(new_cells) if n_new else None
        # untracked targets (for P_c): each look scales them by the miss ratio, positive or
        # not; a deleted track's existence returns to them (recycling, as pmb)
        self._undetected.multiply(looked, self._miss ** n_looks)
        recycle(self._undetected, grid, *dropped)

        if n_new:
            ones = np.ones(n_new, dtype=np.int64)
            score_new = log_r[np.searchsorted(looked, new_cells)]
            self._m = np.concatenate([self._m, kalman.at_rest(grid.cell_centers(new_cells))])
            self._P = np.concatenate([self._P, np.broadcast_to(self._birth_P, (n_new, 4, 4))])
            self._id = np.concatenate([self._id, self._next_id + np.arange(n_new)])
            self._next_id += n_new
            self._score = np.concatenate([self._score, score_new])
            self._prior_logodds = np.concatenate([self._prior_logodds, prior_new])
            self._peak = np.concatenate([self._peak, score_new])
            self._confirmed = np.concatenate([self._confirmed, np.zeros(n_new, dtype=bool)])
            self._age = np.concatenate([self._age, 0 * ones])
            self._tested = np.concatenate([self._tested, np.zeros(n_new)])
            self._confirm()

    def _birth_prior_logodds(self, cells: np.ndarray) -> np.ndarray:
        """``L0 = log(exp(lambda) - 1)`` of a new track in each of ``cells``: ``lambda``
        the untracked intensity there (before the step's looks) plus, on a model without
        arrivals, ``max(0, E[N_k] - sum r - sum lambda) / n`` (``sum r`` the held tracks'
        existence); ``-inf`` where ``lambda = 0``."""
        lam = self._undetected.at(cells)
        if self._birth_per_cell == 0.0 and len(cells):
            held = float(expit(self._prior_logodds + self._score).sum())
            held += self._undetected.total()
            lam = lam + max(0.0, self._expected - held) / self._grid.n_cells
        with np.errstate(divide="ignore"):
            return np.log(np.expm1(lam))

    def _confirm(self) -> None:
        """Confirm the tracks whose score reaches the level; a confirmed track's peak
        follows its highest score (``L`` itself is not capped: ``sigmoid(L0 + L)`` is the
        track's existence in ``P_c(t)``, near 1 for a track long held)."""
        level = self._prior_logodds + self._score  # posterior log-odds of a target
        self._confirmed = self._confirmed | (level >= self._confirm_at)
        self._peak = np.where(self._confirmed, np.maximum(self._peak, self._score), self._score)

    def estimate(self) -> Estimate:
        """The ``round(sum r)`` tracks of largest ``r = sigmoid(L0 + L)``, in track order
        (count ``sum r``): states ``(n, 4)``, covariances ``(n, 4, 4)`` and labels (the
        track ids, kept for the track's life)."""
        r = expit(self._prior_logodds + self._score)
        total = float(r.sum())
        sel = np.sort(np.argsort(-r, kind="stable")[:min(int(round(total)), len(r))])
        return Estimate(total, self._m[sel].copy(), self._P[sel].copy(),
                        self._id[sel].astype(np.int64))

    # ---------------------------------------------------------- for tests/plots
    def undetected_intensity(self) -> CellField:
        """The untracked-target intensity ``lambda_c`` (the tracker's own object: read only)."""
        return self._undetected

    def track_table(self) -> dict[str, np.ndarray]:
        """Copies of the track arrays (ids, means, covariances, flags, counters, the prior
        log-odds ``L0`` of each track's birth)."""
        return {"id": self._id.copy(), "mean": self._m.copy(), "cov": self._P.copy(),
                "confirmed": self._confirmed.copy(), "score": self._score.copy(),
                "prior": self._prior_logodds.copy(),
                "peak": self._peak.copy(),
                "age": self._age.copy()}

    @classmethod
    def resource_terms(cls, params, model, looks_per_step, targets) -> ResourceTerms:
        """A Kalman filter per target, the undetected field of the cells looked at so far,
        ``P_c(t)`` from the tracks' boxes (``N_COUNTS`` columns)."""
        return ResourceTerms(step_seconds=KFNN_STEP_S, target_seconds=TARGET_S,
                             looked_cell_bytes=LOOKED_CELL_BYTES,
                             looked_cell_seconds=LOOKED_CELL_S,
                             prediction_entries=gaussian_boxes(targets) * BOX_CELLS,
                             prediction_counts=float(N_COUNTS))

"""``pmb``: a track-oriented Poisson multi-Bernoulli filter on the Rayleigh cell sensor.

J. L. Williams, "Marginal multi-Bernoulli filters: RFS derivation of MHT, JIPDA, and
association-based MeMBer", IEEE TAES 51(3), 2015 (the track-oriented PMB, TOMB/P), with
the association marginals of Williams and Lau (TAES 2014) by loopy belief propagation
(:mod:`.lbp`) and the cell likelihood of :mod:`.update` (after Kropfreiter, Williams and
Meyer, "Multiobject tracking for thresholded cell measurements", 2024: positive cells as
measurements with at most one source each, ratios to an empty cell).

State (arrays, never an object per Bernoulli): per track existence ``r (T,)`` and a label
``(T,)`` (a counter assigned at birth, kept for the track's life); per Gaussian row its
track ``own (R,)``, weight within the track ``a (R,)``, ``m (R, 4)``, ``P (R, 4, 4)``
(rows ``[px, vx, py, vy]``): a Bernoulli's density is a mixture of at most
``max_components`` Gaussians (Williams' Bernoulli mixture, bounded: :func:`reduce_rows`);
and the PPP of undetected targets, an intensity per cell held sparsely (:mod:`.ppp`).

Step:

* **predict**: ``m <- F m``, ``P <- F P F^T + Q``, ``r <- p r`` with ``p = min(p_s, 1 -
  death_probability)``; walls as the truth: "reflect" folds the Gaussian back into the
  workspace (:func:`~mttbench.trackers.gpf.grid.fold_into_workspace`), "die" truncates it
  to the workspace and multiplies ``r`` by the mass inside
  (:func:`~mttbench.trackers.gpf.tracker.truncate_to_workspace`). The PPP:
  ``lambda <- p_s lambda + birth_rate / n_cells``.
* **update** (:func:`.update.pmb_update`): the association marginals over (tracks,
  cells with a detection) by LBP per connected cluster, the marginal multi-Bernoulli
  update of every track (a looked cell without a detection updates every track whose
  6-sd box holds it), a new Bernoulli per cell with a detection, weighed against the
  PPP and the false alarm; the PPP is multiplied by its miss ratio in the looked cells.
* **reduce** (:func:`reduce_rows`): per track, the rows that truncate to the same
  measured cell are merged, rows below ``COMPONENT_FLOOR`` dropped, the lightest beyond
  ``max_components`` moment matched into one.
* no count bound: a model without arrivals never has more targets than its initial
  set, and the GPF conditions its existences on that after every update; tried here, it
  helped ``default`` a little but, re-applied every step to a product of Bernoullis, it
  held every track of the heavy-clutter point ``env-pf-0.1`` below 0.5, so the filter
  keeps the PMB's Poisson prior (measured in docs/pmb.md).
* **recycle** (Williams 2015's recycling): tracks with ``r < recycle_threshold``, and new
  Bernoullis born below it, go into the PPP (their mass per cell); beyond ``max_tracks``
  the weakest too. Nothing is dropped without being recycled.

Estimate: the ``round(sum r)`` tracks of largest existence (``extraction="round_sum"``,
the default, as the GPF's) or those with ``r > extraction_threshold`` (``"threshold"``,
Williams' ``r > 0.5`` at the default threshold), each by its heaviest Gaussian row (mean,
covariance) and its label; the count is ``sum r`` (the PMB's expected number of tracked
targets; the PPP's undetected targets are not counted). In heavy clutter, where no track
reaches 0.5 within the run, ``r > 0.5`` reports almost nothing; the two rules are level
on the presets (docs/pmb.md).

``P_c(t)``: per cell the Poisson-binomial of the tracks' Bernoullis (``r`` times the
Gaussian's mass in the cell, 6-sd boxes) and one more Bernoulli ``1 - exp(-lambda_c)``
for the PPP (:func:`~mttbench.trackers.cells.bernoulli_cell_counts`): own rows in the
tracks' boxes and the PPP's own cells, one default row elsewhere.

Death floor (not in the model): with ``p_s = 1`` and arrivals, a lost track whose
existence has rounded to 1 would never end; ``death_probability=None`` is
``DEFAULT_DEATH_FLOOR`` on models with arrivals (the GPF's measured default) and 0 on
models without (where ``p_s`` is the truth: a target never dies, and a lost track finds
its target again).

Cost per step: the tracks' (track, looked cell) pairs within 6 sd, the LBP over the
edges to cells with a detection, the PPP's looked cells; nothing is ``O(cells)``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ...scenarios.model import Looks, RayleighGridSensor, TrackingModel
from .. import kalman
from ..base import (
    BOX_CELLS,
    LOOKED_CELL_BYTES,
    LOOKED_CELL_S,
    PAIR_BYTES,
    PAIR_S,
    TARGET_S,
    Estimate,
    ResourceTerms,
    Tracker,
    gaussian_boxes,
    param_number,
    register,
)
from ..cells import (
    CellCounts,
    CellField,
    bernoulli_cell_counts,
    gaussian_cell_mass_sparse,
    untracked_probabilities,
)
from ..gpf.grid import _gl_table, fold_into_workspace, position_regression
from ..gpf.tracker import collapse, merge_groups, truncate_to_workspace
from ..grid_backend import compiled_grid_kernels
from ..params import Budget, Param, Search
from .backend import WAIT_S, compiled_pmb_kernels
from .lbp import LBP_MAX_ITER, LBP_TOL, Marginals
from .ppp import add_intensity, predict_intensity, recycle
from .update import MAX_LOG, RANGE_SIGMAS, PMBUpdate, cell_ratios, one_look_ratios, pmb_update

#: per-step death floor on models with arrivals (``death_probability=None``)
DEFAULT_DEATH_FLOOR = 0.003
#: a Gaussian row with a smaller weight within its track is dropped (the track keeps its
#: heaviest row); the GPF's floor
COMPONENT_FLOOR = 0.02
#: bytes per track (mean, covariance, their working copies in the update)
PMB_TRACK_BYTES = 1024
#: seconds per step beyond the pairs and the targets (LBP set-up, P_c, bookkeeping)
PMB_STEP_S = 1e-3


@register
class PMBTracker(Tracker):
    """Track-oriented Poisson multi-Bernoulli filter (module docstring)."""

    name = "pmb"
    summary = ("track-oriented Poisson multi-Bernoulli filter (Williams 2015): PPP of "
               "undetected targets, Gaussian Bernoullis, association marginals by LBP")
    parameters: ClassVar[dict[str, Param]] = {
        "extraction": Param(choices=("threshold", "round_sum"),
                            doc="which tracks are reported: existence above "
                                "extraction_threshold, or the round(sum r) most likely",
                            search=Search(choices=("threshold", "round_sum"))),
        "extraction_threshold": Param(float, 0, 1, high_open=True,
                                      doc="tracks with existence above it are reported "
                                          "(threshold): trades missed targets for false "
                                          "tracks",
                                      search=Search(0.2, 0.8)),
        "recycle_threshold": Param(float, 0, 1, high_open=True,
                                   doc="tracks (and new Bernoullis) with existence below it "
                                       "go into the PPP: higher is cheaper and forgets "
                                       "faint tracks' velocities sooner",
                                   search=Search(1e-3, 0.1, log=True)),
        "death_probability": Param(float, 0, 1, allow_none=True,
                                   none="DEFAULT_DEATH_FLOOR with arrivals, else 0",
                                   doc="per-step death floor of the tracks: higher ends "
                                       "lost tracks sooner, at some count error",
                                   search=Search(1e-4, 0.05, log=True)),
        "max_components": Param(int, 1, doc="Gaussians per track (a Bernoulli with a "
                                            "Gaussian-mixture density); 1: the one-Gaussian "
                                            "TOMB, cheaper",
                                search=Search(1, 6)),
        "merge_threshold": Param(float, 0, doc="squared Mahalanobis distance below which "
                                               "two tracks' Gaussians merge into one "
                                               "Bernoulli (existence the capped sum); 0: "
                                               "never (Williams' PMB)",
                                 search=Search(1.0, 16.0, log=True)),
        "max_tracks": Param(int, 1, doc="at most this many Bernoullis (the weakest are "
                                        "recycled): bounds time and memory"),
        "n_counts": Param(int, 2, doc="count columns of P_c(t), the last 'n_counts - 1 or "
                                      "more'"),
    }
    budget: ClassVar[dict[str, Budget]] = {
        "max_components": Budget(1, 8, doc="Gaussians per track; beyond 8 the components "
                                           "are merged or dropped anyway"),
        "max_tracks": Budget(10, 200, doc="Bernoullis; 200 is the default, 10 is below "
                                          "a crowd's count"),
    }

    def __init__(self, extraction: str = "round_sum", extraction_threshold: float = 0.5,
                 recycle_threshold: float = 0.01,
                 death_probability: float | None = None, max_components: int = 4,
                 merge_threshold: float = 0.0, max_tracks: int = 200,
                 n_counts: int = 4) -> None:
        self.extraction = extraction
        self.extraction_threshold = extraction_threshold
        self.recycle_threshold = recycle_threshold
        self.death_probability = death_probability
        self.max_components = max_components
        self.merge_threshold = merge_threshold
        self.max_tracks = max_tracks
        self.n_counts = n_counts

    def unsupported_reason(self, model: TrackingModel) -> str | None:
        if not isinstance(model.sensor, RayleighGridSensor):
            return ("the PMB filter is built for the cell (Rayleigh grid) sensor; the "
                    "superposition sensor's mean of all targets is no point measurement")
        return None

    # --------------------------------------------------------------- life cycle
    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        self.validate_params(self.get_params())
        compiled_grid_kernels()  # compile or load the grid kernels now, not in a timed step
        compiled_pmb_kernels(wait=WAIT_S)  # and the update's (or numpy until they are in)
        self._model = model
        self._grid = model.grid
        self._F, self._Q = model.dynamics.F, model.dynamics.Q
        bd = model.birth_death
        floor = self.death_probability
        if floor is None:
            floor = DEFAULT_DEATH_FLOOR if bd.birth_rate > 0.0 else 0.0
        self._survival = min(bd.survival_probability, 1.0 - floor)
        s, bv = model.grid.cell_size, bd.birth_velocity_std
        self._P_new = np.diag([s * s / 12.0, bv * bv, s * s / 12.0, bv * bv])
        # tracks t: existence r (T,), label tid (T,); Gaussian rows: track own (R,),
        # weight a (R,) within the track, mean m (R, 4), covariance P (R, 4, 4)
        self._r = np.zeros(0)
        self._tid = np.zeros(0, dtype=np.int64)
        self._own = np.zeros(0, dtype=np.int64)
        self._a = np.zeros(0)
        self._m = np.zeros((0, 4))
        self._P = np.zeros((0, 4, 4))
        self._next_tid = 0
        n_cells = model.grid.n_cells
        self._ppp = CellField(n_cells, bd.initial_count_mean / n_cells)
        self._last_update = None

    def set_tracks(self, r: np.ndarray, m: np.ndarray, P: np.ndarray) -> None:
        """Replace the Bernoullis (tests, warm starts): ``r (T,)``, ``m (T, 4)``,
        ``P (T, 4, 4)``; new labels."""
        self._r = np.array(r, dtype=float).reshape(-1)
        self._m = np.array(m, dtype=float).reshape(-1, 4)
        self._P = np.array(P, dtype=float).reshape(-1, 4, 4)
        self._own = np.arange(len(self._r))
        self._a = np.ones(len(self._r))
        self._tid = self._next_tid + np.arange(len(self._r), dtype=np.int64)
        self._next_tid += len(self._r)

    def set_intensity(self, value: float) -> None:
        """A uniform PPP intensity ``value`` per cell (tests)."""
        self._ppp = CellField(self._grid.n_cells, float(value))

    @property
    def tracks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Copies of ``r (T,)``, ``m (T, 4)``, ``P (T, 4, 4)`` (each track's mixture moment
        matched) and ``labels (T,)``."""
        m, P = collapse(self._a, self._m, self._P, self._own, len(self._r))
        return self._r.copy(), m, P, self._tid.copy()

    @property
    def components(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Copies of the Gaussian rows: ``track (R,)``, ``weight within it (R,)``,
        ``m (R, 4)``, ``P (R, 4, 4)``."""
        return self._own.copy(), self._a.copy(), self._m.copy(), self._P.copy()

    @property
    def last_update(self):
        """The :class:`.update.PMBUpdate` of the last update (diagnostics), or None."""
        return self._last_update

    @property
    def intensity(self) -> CellField:
        """The PPP of undetected targets (the live field: read only)."""
        return self._ppp

    # ------------------------------------------------------------------ predict
    def predict(self) -> None:
        bd = self._model.birth_death
        self._m, self._P = kalman.predict(self._m, self._P, self._F, self._Q)
        self._r = self._r * self._survival
        if len(self._r):
            if bd.boundary == "reflect":
                self._m, self._P = fold_into_workspace(self._m, self._P, self._grid)
            else:
                width, height = self._grid.extent
                inside, self._m, self._P = truncate_to_workspace(self._m, self._P, width,
                                                                 height)
                kept = self._a * inside  # a row keeps its share inside; r the track's
                tot = np.bincount(self._own, weights=kept, minlength=len(self._r))
                self._r = self._r * np.minimum(tot, 1.0)
                self._a = np.where(tot[self._own] > 0.0,
                                   kept / np.where(tot > 0.0, tot, 1.0)[self._own], self._a)
        predict_intensity(self._ppp, bd.survival_probability, bd.birth_rate)

    # ------------------------------------------------------- count distribution
    def cell_count_distribution(self) -> CellCounts:
        n_cells = self._grid.n_cells
        row, cell, mass = gaussian_cell_mass_sparse(
            self._grid, *kalman.position_marginal(self._m, self._P))
        # a track's mass in a cell: its rows' sum, times its existence (one Bernoulli)
        key, inv = np.unique(self._own[row] * n_cells + cell, return_inverse=True)
        p = np.bincount(inv.reshape(-1), weights=self._a[row] * mass, minlength=len(key))
        p_default, ppp_cells, ppp_probs = untracked_probabilities(self._ppp)
        return bernoulli_cell_counts(n_cells, self.n_counts, key % n_cells,
                                     self._r[key // n_cells] * p, last_default=p_default,
                                     last_cells=ppp_cells, last_probs=ppp_probs)

    # ------------------------------------------------------------------- update
    def undetected_intensity(self) -> CellField:
        """The PPP's intensity ``lambda_c`` (a copy): the expected number of undetected
        targets per cell."""
        return self._ppp.copy()

    def update(self, looks: Looks) -> None:
        if not len(looks):
            return
        kernels = compiled_pmb_kernels()
        if kernels is None:
            self._update_numpy(looks)
            weak = True
        else:
            weak = self._update_compiled(kernels, looks)
        if self.merge_threshold > 0.0 and len(self._r) > 1:
            self._merge()
            weak = True
        if weak:
            self._recycle()

    def _update_numpy(self, looks: Looks) -> None:
        """The update up to the merge and recycling (numpy form, the reference)."""
        ratios = cell_ratios(self._model.sensor, looks.cells, looks.returns)
        lam_meas = self._ppp.at(ratios.cells[ratios.positive])
        res = pmb_update(self._r, self._m, self._P, ratios, lam_meas, self._grid,
                         own=self._own, alpha=self._a)
        self._last_update = res
        # the PPP's targets missed by the looks
        self._ppp.multiply(ratios.cells, ratios.M)
        T = len(self._r)
        own, a, m, P = reduce_rows(res.own, res.alpha, res.means, res.covs, res.hyp, T,
                                   self.max_components)
        # new Bernoullis: kept above the recycling threshold, else back into the PPP
        keep_new = res.r_new >= self.recycle_threshold
        add_intensity(self._ppp, res.meas_cells[~keep_new], res.r_new[~keep_new])
        n_new = int(keep_new.sum())
        cm = kalman.at_rest(self._grid.cell_centers(res.meas_cells[keep_new]))
        self._r = np.concatenate([res.r, res.r_new[keep_new]])
        self._own = np.concatenate([own, T + np.arange(n_new)])
        self._a = np.concatenate([a, np.ones(n_new)])
        self._m = np.concatenate([m, cm])
        self._P = np.concatenate([P, np.repeat(self._P_new[None], n_new, axis=0)])
        self._tid = np.concatenate([self._tid, self._next_tid + np.arange(n_new,
                                                                          dtype=np.int64)])
        self._next_tid += n_new

    def _update_compiled(self, kernels, looks: Looks) -> bool:
        """:meth:`_update_numpy` in one compiled pass (:func:`.update_kernels.step_update`,
        the same numbers bit for bit); the position regression's matmuls stay numpy.
        Returns whether some track is to be recycled."""
        c = np.ascontiguousarray
        B, resid = position_regression(self._P)
        ll_pos, ll_neg, ll_miss = one_look_ratios(self._model.sensor)
        ppp, grid = self._ppp, self._grid
        ints, floats = kernels.step_update(
            c(self._r, float), c(self._own, np.int64), c(self._a, float), c(self._m, float),
            c(self._P, float), c(self._tid, np.int64), int(self._next_tid), B, resid,
            c(looks.cells, np.int64), c(looks.returns, bool), ll_pos, ll_neg, ll_miss,
            MAX_LOG, float(ppp.default), c(ppp.cells, np.int64), c(ppp.values, float),
            float(grid.cell_size), int(grid.nx), int(grid.ny), RANGE_SIGMAS, LBP_TOL,
            LBP_MAX_ITER, int(self.max_components), COMPONENT_FLOOR,
            float(self.recycle_threshold), int(self.max_tracks), self._P_new, *_gl_table())
        head = ints[:kernels.HEADER].tolist()
        T2, R2, n_out, J, E, n_f, iterations, converged, n_pairs, next_tid, weak = head[:11]
        T = len(self._r)
        own, tid, cells, out_own, hyp, meas_cells, cluster = _cut(
            ints, kernels.HEADER, (R2, T2, n_f, n_out, n_out, J, E))
        (r, a, m, P, values, r_post, alpha_post, means, covs, r_new, p_missed, p_edge,
         p_unused) = _cut(floats, 0, (T2, R2, 4 * R2, 16 * R2, n_f, T, n_out, 4 * n_out,
                                      16 * n_out, J, T, E, J))
        self._r, self._own, self._a, self._tid = r, own, a, tid
        self._m, self._P = m.reshape(R2, 4), P.reshape(R2, 4, 4)
        self._next_tid = next_tid
        ppp.cells, ppp.values = cells, values
        self._last_update = PMBUpdate(
            r_post, out_own, alpha_post, means.reshape(n_out, 4), covs.reshape(n_out, 4, 4),
            hyp, meas_cells, r_new,
            Marginals(p_missed, p_edge, p_unused, iterations, bool(converged), cluster),
            n_pairs)
        return bool(weak)

    def _merge(self) -> None:
        """Tracks whose moment-matched Gaussians are closer than ``merge_threshold``
        (squared Mahalanobis, :func:`~mttbench.trackers.gpf.tracker.merge_groups`, greedily from
        the most likely) become one Bernoulli: existence ``min(1, sum r)``, the members'
        rows with weights ``r_i a_r`` (renormalised), the label of the most likely member;
        then the mixture is bounded again (:func:`reduce_rows`)."""
        T = len(self._r)
        cm, cP = collapse(self._a, self._m, self._P, self._own, T)
        r_new, _, _, label = merge_groups(self._r, cm, cP, self.merge_threshold,
                                          "capped_sum", "mahalanobis")
        if len(r_new) == T:
            return
        head = np.unique(label[np.argsort(-self._r, kind="stable")], return_index=True)[1]
        self._tid = self._tid[np.argsort(-self._r, kind="stable")][head]
        a = self._a * self._r[self._own]
        own = label[self._own]
        tot = np.bincount(own, weights=a, minlength=len(r_new))
        a = np.where(tot[own] > 0.0, a / np.where(tot > 0.0, tot, 1.0)[own], 1.0)
        hyp = np.full(len(own), -1, dtype=np.int64)
        self._own, self._a, self._m, self._P = reduce_rows(own, a, self._m, self._P, hyp,
                                                           len(r_new), self.max_components)
        self._r = r_new

    def _recycle(self) -> None:
        """Tracks below ``recycle_threshold``, and the weakest beyond ``max_tracks``, into
        the PPP."""
        weak = self._r < self.recycle_threshold
        if len(self._r) - int(weak.sum()) > self.max_tracks:
            order = np.argsort(-self._r, kind="stable")
            weak[order[self.max_tracks:]] = True
        if not weak.any():
            return
        rows = weak[self._own]
        recycle(self._ppp, self._grid, self._r[self._own[rows]] * self._a[rows],
                self._m[rows], self._P[rows])
        keep = ~weak
        index = np.cumsum(keep) - 1
        self._r, self._tid = self._r[keep], self._tid[keep]
        self._own, self._a = index[self._own[~rows]], self._a[~rows]
        self._m, self._P = self._m[~rows], self._P[~rows]

    # ----------------------------------------------------------------- estimate
    def estimate(self) -> Estimate:
        """The tracks with ``r > extraction_threshold`` (or the ``round(sum r)`` most
        likely), each by its heaviest Gaussian row; the count ``sum r``."""
        count = float(self._r.sum())
        if self.extraction == "round_sum":
            n = min(int(round(count)), len(self._r))
            kernels = compiled_pmb_kernels()
            if kernels is not None:  # the same selection, one compiled pass
                c = np.ascontiguousarray
                rows, labels = kernels.estimate_rows(
                    c(self._r, float), c(self._own, np.int64), c(self._a, float),
                    c(self._m, float), c(self._P, float), c(self._tid, np.int64), n)
                return Estimate(count, rows[:4 * n].reshape(n, 4),
                                rows[4 * n:].reshape(n, 4, 4), labels)
            sel = np.sort(np.argsort(-self._r, kind="stable")[:n])
        else:
            sel = np.nonzero(self._r > self.extraction_threshold)[0]
        order = np.lexsort((-self._a, self._own))  # each track's rows, heaviest first
        first = np.searchsorted(self._own[order], sel)
        rows = order[first]
        return Estimate(count, self._m[rows].copy(), self._P[rows].copy(),
                        self._tid[sel].copy())

    @classmethod
    def resource_terms(cls, params, model, looks_per_step, targets) -> ResourceTerms:
        """Gaussian rows: ``2 T + 16`` at once (the GPF's count of Gaussians present; a
        track's extra rows are short-lived), each paired with the looked cells of its box
        (at most ``BOX_CELLS``: the shared per-pair costs of the grid update); state for
        ``max_components`` rows per track; the PPP keeps a value per cell looked at so
        far; ``P_c(t)`` from the rows' boxes, ``n_counts`` columns. Upper estimates:
        measured on ``large`` (25 targets, 250 looks; bench_pmb.py) a step takes 0.6 ms of
        CPU, the terms declare 23 ms."""
        present = min(gaussian_boxes(targets), param_number(params, "max_tracks", 200))
        rows = present * max(1.0, param_number(params, "max_components", 4))
        pairs = present * min(float(BOX_CELLS), looks_per_step)
        return ResourceTerms(
            state_bytes=rows * PMB_TRACK_BYTES, update_bytes=pairs * PAIR_BYTES,
            looked_cell_bytes=LOOKED_CELL_BYTES, step_seconds=PMB_STEP_S,
            target_seconds=TARGET_S, update_seconds=pairs * PAIR_S,
            looked_cell_seconds=LOOKED_CELL_S, prediction_entries=present * BOX_CELLS,
            prediction_counts=max(2.0, param_number(params, "n_counts", 4)))


def _cut(packed: np.ndarray, start: int, sizes: tuple[int, ...]) -> list[np.ndarray]:
    """Consecutive views of ``packed`` from ``start``, of the given sizes."""
    out = []
    for n in sizes:
        out.append(packed[start:start + n])
        start += n
    return out


def reduce_rows(own: np.ndarray, a: np.ndarray, m: np.ndarray, P: np.ndarray,
                hyp: np.ndarray, T: int, max_components: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Bound each track's mixture after an update: rows ``own (R,)``, ``a (R,)`` (weights
    within the track), ``m (R, 4)``, ``P (R, 4, 4)``, ``hyp (R,)`` (:class:`.update.
    PMBUpdate`). The rows of one track that are truncations to the same measured cell are
    moment matched into one; rows below :data:`COMPONENT_FLOOR` go (a track keeps its
    heaviest); beyond ``max_components`` the lightest are moment matched into one
    (``max_components = 1``: the whole mixture). Returns the new ``own``, ``a``, ``m``,
    ``P``, sorted by track."""
    n_h = int(hyp.max()) + 2 if len(hyp) else 1
    key = np.where(hyp >= 0, own * n_h + hyp + 1, -1 - np.arange(len(own)))
    _, grp = np.unique(key, return_inverse=True)
    grp = grp.reshape(-1)
    n_g = int(grp.max()) + 1 if len(grp) else 0
    g_own = np.zeros(n_g, dtype=np.int64)
    g_own[grp] = own
    g_a = np.bincount(grp, weights=a, minlength=n_g)
    if n_g < len(own):
        m, P = collapse(a, m, P, grp, n_g)
    else:  # nothing to merge: the rows in the groups' order
        perm = np.empty(n_g, dtype=np.int64)
        perm[grp] = np.arange(len(grp))
        m, P = m[perm], P[perm]
    own, a = g_own, g_a
    # the floor, each track keeping its heaviest row
    order = np.lexsort((-a, own))
    first = np.ones(len(order), dtype=bool)
    first[1:] = own[order[1:]] != own[order[:-1]]
    keep = a >= COMPONENT_FLOOR
    keep[order[first]] = True
    own, a, m, P = own[keep], a[keep], m[keep], P[keep]
    # beyond max_components: the lightest of a track moment matched into one
    order = np.lexsort((-a, own))
    own, a, m, P = own[order], a[order], m[order], P[order]
    rank = np.arange(len(own)) - np.searchsorted(own, own)
    n_rows = np.bincount(own, minlength=T)
    excess = (rank >= max_components - 1) & (n_rows[own] > max_components)
    if np.any(excess):
        g = np.where(excess, max_components - 1, rank)
        uk, grp = np.unique(own * max_components + g, return_inverse=True)
        grp = grp.reshape(-1)
        wsum = np.bincount(grp, weights=a)
        m, P = collapse(a, m, P, grp, len(uk))
        own, a = uk // max_components, wsum
    tot = np.bincount(own, weights=a, minlength=T)
    a = np.where(tot[own] > 0.0, a / np.where(tot > 0.0, tot, 1.0)[own], 1.0)
    return own, a, m, P

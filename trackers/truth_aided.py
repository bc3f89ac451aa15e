"""``truth-aided``: a reference that is told the count and the association (USES THE TRUTH).

It marks the floor of the error a tracker can reach on a scenario: what one filter per
target achieves when the number of targets, their births and deaths, and which look
belongs to which target are all known. It is not an estimator anyone could run; the
harness gives it the truth and marks every one of its rows ``tracker_uses_truth`` (as
the ``oracle`` policy's ``policy_uses_truth``). It never returns the truth as its
estimate: the states it reports are its filters' means, computed from the looks alone
once the bookkeeping is known.

Truth it is given (``observe_truth``, called by the harness at every step after
``predict`` and before the cell selection and ``update``): the true states ``(n, 4)`` and
ids ``(n,)`` of the current step. It uses only

* the ids: one filter per true id, dropped when the id disappears (death, or leaving the
  workspace under ``boundary = "die"``); the count it reports is the number of true
  targets of the step;
* for ``start = "birth"`` (the default, the one the tables use): the true state at the
  step the id first appears, as the filter's start ``N(x_true, P0)`` with
  ``P0 = diag(sp^2, sv^2, sp^2, sv^2)``, ``sp = start_position_std * cell``,
  ``sv = start_velocity_std * cell / tau`` (defaults 0.1 cell and 0.01 cell per step:
  a known start, not a perfect one);
* for ``start = "first_detection"``: the true cell of a target not yet tracked, to know
  when a positive look at that cell is its first detection; the filter then starts from
  the cell's uniform moments (mean at the centre, position variance ``cell^2 / 12`` per
  axis), zero velocity with the model's ``birth_velocity_std``; the detection is used by
  that start and not applied again. Until then the target has no state (its count is
  still reported);
* for ``attribution = "truth"`` (the default): the true cell of each target, only to tell
  whether a positive look is that target's detection (below).

Update (grid sensor), each target alone, with known existence and known association.
The position likelihood of one step is piecewise constant over cells: ``g(x) =
Lambda_c`` for ``x`` in a looked cell ``c``, 1 elsewhere, with ``Lambda_c = prod_{looks at
c} p(z_i | 1) / p(z_i | 0)`` (one target in the cell, :meth:`~mttbench.scenarios.model.
RayleighGridSensor.log_likelihood_ratio`) and ``z_i`` the look as target ``i`` alone would
have produced it. With ``attribution = "truth"`` (the default, the one the tables use):
a positive look at the cell that truly holds target ``i`` is its detection (a look at a
cell holding several targets is credited to each, even a false alarm there); a positive
look anywhere else is another target's detection or a false alarm, known by the
association, and counts for ``i`` as the miss it is for ``i`` (false alarms and other
targets' detections are ignored as detections of ``i``); a negative look removes the
looked cell's share of every target's mass. ``attribution = "overlap"`` applies every
return as it is to every target whose Gaussian overlaps the cell (no attribution, the
literal "as if it were the only target"): then another target's detections, with
``Lambda = p_d / p_f`` ~ 1000 on the default sensor, pull a nearby filter onto that
target and it can follow it for good (docs/truth_aided.md). The target is also known
to be inside the workspace ``W`` (it exists, and the truth never leaves ``W``), so the
posterior of the prior ``N(m, P)`` is::

    p(x | z) = N(x; m, P) 1_W(x) g(x) / Z

a mixture, over the looked cells and "the rest of W", of the Gaussian truncated to each
(weights ``mass_c Lambda_c`` and ``mass_W - sum_c mass_c``). With the centred moments of
the Gaussian on a rectangle ``R`` (:func:`~mttbench.trackers.gpf.grid.rect_state_moments`:
``mass_R``, ``M1_R = int_R (x - m) N``, ``M2_R = int_R (x - m)(x - m)^T N``, position and
velocity jointly)::

    Z  = mass_W + sum_c (Lambda_c - 1) mass_c
    d  = (M1_W + sum_c (Lambda_c - 1) M1_c) / Z
    m' = m + d,   P' = (M2_W + sum_c (Lambda_c - 1) M2_c) / Z - d d^T

the exact first two moments of the posterior (the moment match to one Gaussian). Cells
farther than 6 marginal standard deviations from the mean are left out (mass < 1e-8);
a Gaussian whose 6-sigma box lies inside ``W`` uses ``mass_W = 1, M1_W = 0, M2_W = P``.
The ``Lambda`` are scaled by their largest one per target before use (many positive
repeats cannot overflow).

Prediction: ``m <- F m``, ``P <- F P F^T + Q`` (the model's ``F`` and ``Q``). Under
``boundary = "die"`` that is the prior, and its restriction to ``W`` above is the
conditioning on survival. Under ``"reflect"`` the truth is folded back into ``W`` by
reflection (position mirrored, that velocity negated), so the prior inside ``W`` is the
sum of the predicted Gaussian's images (:func:`reflection_images`: per axis ``p + 2nL``
and ``2nL - p`` with the velocity negated on a mirror, ``n`` in ``{-1, 0, 1}``; only the
images with mass above 1e-9 inside ``W``, so a target far from the walls has just
itself). The update above then runs on every image (the same ``Lambda``; the mixture has
one more level, images times cells) and moment-matches the whole posterior once: the
fold is exact for a Gaussian prior, and nothing is truncated twice (truncation alone
runs a filter into the wall after its target bounced; docs/truth_aided.md).

Predicted per-cell count distribution ``P_c(t)``: each tracked target is present with
probability 1, in cell ``c`` with its predicted Gaussian's mass there (summed over its
images under ``"reflect"``; :func:`~mttbench.trackers.cells.gaussian_cell_mass_sparse`,
x-y correlation ignored, only the cells within 6 sd of each image's mean: less than 4e-9
of its mass left out) renormalised to ``W``; a known but not yet detected target
(``first_detection``) is uniform over the cells; the count is Poisson-binomial
(:func:`~mttbench.trackers.cells.bernoulli_cell_counts`), columns 0, 1, 2 and "3 or
more". It is a :class:`~mttbench.trackers.cells.CellCounts`: rows of their own in the
targets' boxes, one default row (the not yet detected targets only) everywhere else.
Nothing in a step costs ``O(cells)``: the filters' update works on the looked cells near
each target (:func:`~mttbench.trackers.gpf.grid.known_existence_update`).

Superposition sensor: not supported (the linear update with a known count would need
the targets' joint covariance; this reference is for the grid sensor).

Driven without ``observe_truth`` (outside the harness), nothing is born or dies: with no
truth ever given it holds no target and reports none.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..scenarios.model import Looks, RayleighGridSensor, TrackingModel
from . import kalman
from .base import (
    BOX_CELLS,
    PAIR_BYTES,
    PAIR_S,
    TARGET_S,
    Estimate,
    ResourceTerms,
    Tracker,
    gaussian_boxes,
    register,
)
from .cells import CellCounts, bernoulli_cell_counts, gaussian_cell_mass_sparse
from .gpf.grid import known_existence_update, reflection_images
from .params import Param

#: count columns of P_c: 0, 1, 2 and "3 or more"
N_COUNTS = 4
@register
class TruthAidedTracker(Tracker):
    """Known count and association, one moment-matched grid filter per true target
    (module docstring). A reference that uses the truth, never an estimator."""

    name = "truth-aided"
    summary = ("REFERENCE, USES THE TRUTH: count and association known, one grid filter "
               "per true target (every look, positive or negative), the floor of the error")
    uses_truth = True
    parameters: ClassVar[dict[str, Param]] = {
        "start": Param(choices=("birth", "first_detection"),
                       doc="a filter starts at the target's birth (known start) or at its "
                           "first detection (cell centre)"),
        "start_position_std": Param(float, 0, low_open=True,
                                    doc="known start: position sd, in cells"),
        "start_velocity_std": Param(float, 0, low_open=True,
                                    doc="known start: velocity sd, in cells per time unit"),
        "attribution": Param(choices=("truth", "overlap"),
                             doc="a positive look counts for the targets in its cell only "
                                 "(a miss for the others), or for every target"),
    }

    def __init__(self, start: str = "birth", start_position_std: float = 0.1,
                 start_velocity_std: float = 0.01, attribution: str = "truth") -> None:
        self.start = start
        self.start_position_std = start_position_std
        self.start_velocity_std = start_velocity_std
        self.attribution = attribution

    def unsupported_reason(self, model: TrackingModel) -> str | None:
        if not isinstance(model.sensor, RayleighGridSensor):
            return ("the truth-aided reference is built for the grid sensor; on the "
                    "superposition sensor it would need the targets' joint covariance")
        return None

    # --------------------------------------------------------------- life cycle
    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        self._model = model
        self._grid = model.grid
        self._F, self._Q = model.dynamics.F, model.dynamics.Q
        self._reflect = model.birth_death.boundary == "reflect"
        s, tau = model.grid.cell_size, model.dynamics.tau
        sp = self.start_position_std * s
        sv = self.start_velocity_std * s / tau
        self._P0 = np.diag([sp * sp, sv * sv, sp * sp, sv * sv])
        bv = model.birth_death.birth_velocity_std
        r = s * s / 12.0
        self._P_cell = np.diag([r, bv * bv, r, bv * bv])
        self._ids = np.zeros(0, dtype=np.int64)
        self._m = np.zeros((0, 4))
        self._P = np.zeros((0, 4, 4))
        self._own = np.zeros(0, dtype=np.int64)  # true cell of each filter's target
        self._fresh = False  # observe_truth was called since the last update
        self._n_true = 0
        # first_detection: true ids not yet tracked and their true cells this step
        self._pending_ids = np.zeros(0, dtype=np.int64)
        self._pending_cells = np.zeros(0, dtype=np.int64)

    def observe_truth(self, states: np.ndarray, ids: np.ndarray) -> None:
        """The truth of the current step (the harness calls this after :meth:`predict`):
        ``states (n, 4)``, ``ids (n,)``. Drops the filters of ids that are gone; under
        ``start="birth"`` starts one at ``N(state, P0)`` for each new id; under
        ``"first_detection"`` remembers the true cells of the ids not yet tracked."""
        states = np.asarray(states, dtype=float).reshape(-1, 4)
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        self._n_true = len(ids)
        alive = np.isin(self._ids, ids)
        self._ids, self._m, self._P = self._ids[alive], self._m[alive], self._P[alive]
        new = ~np.isin(ids, self._ids)
        if self.start == "birth":
            n = int(new.sum())
            self._ids = np.concatenate([self._ids, ids[new]])
            self._m = np.concatenate([self._m, states[new]])
            self._P = np.concatenate([self._P, np.broadcast_to(self._P0, (n, 4, 4))])
            self._pending_ids = np.zeros(0, dtype=np.int64)
            self._pending_cells = np.zeros(0, dtype=np.int64)
        else:
            self._pending_ids = ids[new]
            self._pending_cells = self._grid.cell_of(states[new, 0], states[new, 2])
        # true cell of each tracked target (ids are unique, so the lookup is exact)
        order = np.argsort(ids, kind="stable")
        row = order[np.searchsorted(ids[order], self._ids)]
        self._own = self._grid.cell_of(states[row, 0], states[row, 2])
        self._fresh = True

    def predict(self) -> None:
        # the fold into the workspace (reflect) is applied by the update, with the looks
        self._m, self._P = kalman.predict(self._m, self._P, self._F, self._Q)

    def cell_count_distribution(self) -> CellCounts:
        grid = self._grid
        K = len(self._m)
        if self._reflect:  # the folded prior: the sum of the images' cell masses
            owner, cm, cP = reflection_images(self._m, self._P, grid)
        else:
            owner, cm, cP = np.arange(K), self._m, self._P
        comp, cells, mass = gaussian_cell_mass_sparse(grid, *kalman.position_marginal(cm, cP))
        # sum the images of each target cell by cell, in image order (as the dense rows)
        key, inv = np.unique(owner[comp] * grid.n_cells + cells, return_inverse=True)
        mass = np.bincount(inv, weights=mass, minlength=len(key))
        target, cells = key // grid.n_cells, key % grid.n_cells
        tot = np.bincount(target, weights=mass, minlength=K)
        empty = np.flatnonzero(tot <= 0.0)
        if len(empty):  # no mass on the grid at all: all of it in the nearest cell
            mean_xy = self._m[empty][:, kalman.POSITION]
            ix = np.clip(np.floor(mean_xy[:, 0] / grid.cell_size), 0, grid.nx - 1)
            iy = np.clip(np.floor(mean_xy[:, 1] / grid.cell_size), 0, grid.ny - 1)
            keep = ~np.isin(target, empty)
            target = np.concatenate([target[keep], empty])
            cells = np.concatenate([cells[keep], (iy * grid.nx + ix).astype(np.int64)])
            mass = np.concatenate([mass[keep], np.ones(len(empty))])
            tot[empty] = 1.0
            order = np.argsort(target, kind="stable")
            target, cells, mass = target[order], cells[order], mass[order]
        probs = mass / tot[target]
        # known targets without a state: each uniform over the cells; together one
        # Bernoulli "at least one of them" in every cell (the default row)
        n_pending = len(self._pending_ids)
        p = 1.0 - (1.0 - 1.0 / grid.n_cells) ** n_pending if n_pending else 0.0
        return bernoulli_cell_counts(grid.n_cells, N_COUNTS, cells, probs, last_default=p)

    def update(self, looks: Looks) -> None:
        own = self._own if self.attribution == "truth" and self._fresh else None
        self._fresh = False
        self._m, self._P = known_existence_update(
            self._m, self._P, looks.cells, looks.returns, self._grid, self._model.sensor,
            own_cells=own, workspace="reflect" if self._reflect else "truncate")
        if self.start == "first_detection" and len(self._pending_ids) and len(looks):
            detected_cells = np.unique(looks.cells[looks.returns])
            hit = np.isin(self._pending_cells, detected_cells) & (self._pending_cells >= 0)
            if np.any(hit):
                centres = self._grid.cell_centers(self._pending_cells[hit])
                n = int(hit.sum())
                self._ids = np.concatenate([self._ids, self._pending_ids[hit]])
                self._m = np.concatenate([self._m, kalman.at_rest(centres)])
                self._P = np.concatenate([self._P, np.broadcast_to(self._P_cell, (n, 4, 4))])
                self._pending_ids = self._pending_ids[~hit]
                self._pending_cells = self._pending_cells[~hit]

    def estimate(self) -> Estimate:
        # labels: the true ids its filters were started from (one filter per id)
        return Estimate(float(self._n_true), self._m.copy(), self._P.copy(),
                        self._ids.copy())

    @classmethod
    def resource_terms(cls, params, model, looks_per_step, targets) -> ResourceTerms:
        """A grid filter per target; its update pairs each target's images (``2 T + 16``
        counted) with the looked cells in their boxes (at most ``BOX_CELLS`` each);
        ``P_c(t)`` from their boxes."""
        pairs = gaussian_boxes(targets) * min(float(BOX_CELLS), looks_per_step)
        return ResourceTerms(target_seconds=TARGET_S, update_bytes=pairs * PAIR_BYTES,
                             update_seconds=pairs * PAIR_S,
                             prediction_entries=gaussian_boxes(targets) * BOX_CELLS,
                             prediction_counts=float(N_COUNTS))

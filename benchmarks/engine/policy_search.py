"""``search-track``: looks split between finding undetected targets and refining held ones.

The myopic ``renyi`` policy scores a look at cell ``c`` by the one-step expected Renyi
gain ``G_c`` of the cell's predicted count ``P_c(t)``, whatever the information is about.
But information about a target no track holds and information about a held target's
position are not used for equally long: a target found now is tracked from now on, one
missed now stays missed (each step costing a whole cut-off in OSPA) until a later look
finds it; a held target's position information is spent as the process noise spreads its
prediction over the neighbouring cells. This policy weighs the two by those durations::

    V_c = G_c + (w - 1) D_c,        w = s H_search / H_track

* ``G_c`` -- ``renyi``'s one-step gain of ``P_c(t)`` (held and undetected targets
  together; :func:`~.information.expected_gain`, one binary look);
* ``D_c`` -- the same gain of the undetected component alone: the count of undetected
  targets in ``c``, ``Poisson(lambda_c)`` truncated to ``P_c``'s columns (last column
  "that many or more"), ``lambda_c`` the tracker's undetected-target intensity
  (:meth:`~mttbench.trackers.base.Tracker.undetected_intensity`: pmb's PPP, KF-NN's
  intensity, the GPF's field ``u_c``, a Bernoulli, entering as its mean) or, for a
  tracker that holds none, the model's own (below). It is the existence information of a
  look about a target no track holds; for a cell no track reaches ``G_c = D_c`` and
  ``V_c = w D_c``;
* ``H_search = 1 / (1 - p_s (1 - min(1, M p_d(1) / C)))`` -- the expected number of steps
  a target missed now stays alive and undetected: each step it survives with ``p_s`` and a
  later look finds it with probability about ``M p_d(1) / C`` (``M`` looks spread over
  ``C`` cells; geometric);
* ``H_track`` -- the steps after which the model's process noise alone spreads a held
  target's predicted position by one cell (:func:`track_horizon`: the least ``k`` with
  ``[sum_{j<k} F^j Q F^jT]_xx >= cell^2``; for white-noise acceleration ``q`` on unit
  cells ``ceil((3 / q)^(1/3))``);
* ``s`` -- ``search_scale``, a multiplier (1 by default); ``track_horizon=false`` sets
  ``H_track = 1`` (held information used once, as ``renyi`` counts it).

Why this split: ``G_c`` counts each kind of information once; ``V_c`` counts the
undetected part ``w`` times as much as the rest, ``w`` the ratio of how long each is used.
Everything is read from the model (survival, birth rate and initial count through
``lambda``, dynamics, sensor, look budget) and from the tracker (``P_c``, ``lambda``). When
both last equally (``w = 1``) the policy is ``renyi``: the same values (its random
tie-breaks drawn from its own generator). Measured against ``renyi``:
docs/search_track.md.

Model-derived intensity (a tracker without one, or ``own_field=true``): the policy keeps
its own field, the expected undetected intensity given its own looks: ``lambda = n0 / C``
at first, each step ``lambda <- p_s lambda + birth_rate / C`` before choosing, and
``lambda_c <- lambda_c (1 - p_d(1))`` after a look at ``c`` (a target a look detects
becomes held: the expected intensity of those left undetected whatever the returns, which
the policy does not see). Stored as a :class:`~mttbench.trackers.cells.CellField` (the
cells looked at so far) and updated only at the steps it is used.

Choice: the ``M`` distinct cells of largest ``V_c`` (exact ties in a random order from the
policy's generator), a top-M over a candidate set that a mask can restrict
(:meth:`SearchTrack.choose`). Cost per step: on grids of at most
:data:`~.information.DENSE_CELLS` cells one vectorised pass over the cells; on larger grids
the values are computed once per distinct row (the cells with a row of their own in
``P_c`` or in the field, plus one shared default) and default cells are drawn without
being listed, as ``renyi``'s sparse path does (``O(own cells + looked cells)``).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ...scenarios.model import RayleighGridSensor, TrackingModel
from ...trackers.cells import CellCounts, CellField
from ...trackers.params import Param
from .information import DENSE_CELLS, _top_cells, expected_gain
from .policies import Policy, PolicyTerms, count_distribution_problem, register_policy

#: bytes per cell of the policy's own undetected field (an int64 cell and a float64 value)
FIELD_CELL_BYTES = 16
#: the run length the memory estimate assumes for the fields (one value per looked cell)
DECLARED_STEPS = 1000


def search_horizon(survival: float, n_looks: int, n_cells: int, p_detect: float) -> float:
    """``H = 1 / (1 - p_s (1 - min(1, M p_d / C)))``: the expected number of steps a target
    missed now stays alive and undetected (module docstring)."""
    find = min(1.0, n_looks * p_detect / n_cells)
    return 1.0 / (1.0 - survival * (1.0 - find))


def track_horizon(F: np.ndarray, Q: np.ndarray, cell_size: float, cap: int = 1000) -> int:
    """The steps after which the model's process noise alone spreads a held target's
    predicted position by one cell: the least ``k`` with ``[sum_{j<k} F^j Q F^jT]_xx >=
    cell_size^2`` (at most ``cap``)."""
    S = np.zeros_like(np.asarray(Q, dtype=float))
    for k in range(1, cap + 1):
        S = F @ S @ F.T + Q
        if S[0, 0] >= cell_size**2:
            return k
    return cap


def undetected_rows(intensity: np.ndarray, n_counts: int) -> np.ndarray:
    """``Poisson(lambda)`` truncated to ``n_counts`` columns, the last one "that many or
    more": ``(len(intensity), n_counts)``, rows summing to 1."""
    lam = np.asarray(intensity, dtype=float).reshape(-1, 1)
    t = np.arange(n_counts - 1)[None, :]
    from scipy.stats import poisson  # here: scipy.stats costs most commands 0.8 s to import

    head = poisson.pmf(t, lam)
    return np.hstack([head, poisson.sf(n_counts - 2, lam)])


@register_policy
class SearchTrack(Policy):
    """Top-M cells by ``V_c = G_c + (w - 1) D_c``: the one-step Renyi gain of ``P_c(t)``
    plus the undetected component's gain, weighted by how much longer a missed target
    stays missed than a held target's position information lasts (the module docstring
    states and motivates it)."""

    name = "search-track"
    summary = ("Renyi gain of P_c(t) plus the undetected targets' gain, weighted by how long "
               "a missed target stays missed against how long track information lasts")
    uses_prediction = True
    uses_undetected = True
    parameters: ClassVar[dict[str, Param]] = {
        # at most 100: the gains raise likelihood ratios to the power alpha (overflow)
        "alpha": Param(float, 0, 100, low_open=True, doc="order of the Renyi divergence"),
        "search_scale": Param(float, 0, 1e6, doc="multiplier of the model's search weight"),
        "track_horizon": Param(bool, doc="divide the search horizon by the track horizon"),
        "own_field": Param(bool, doc="use the model-derived field even when the tracker has one"),
    }

    def __init__(self, alpha: float = 0.5, search_scale: float = 1.0,
                 track_horizon: bool = True, own_field: bool = False) -> None:
        self.alpha = alpha
        self.search_scale = search_scale
        self.track_horizon = track_horizon
        self.own_field = own_field

    def reset(self, model: TrackingModel, n_looks: int, rng: np.random.Generator) -> None:
        super().reset(model, n_looks, rng)
        if not isinstance(model.sensor, RayleighGridSensor):
            raise TypeError("the search-track policy needs a grid (Rayleigh) sensor")
        self.validate_params(self.get_params())
        bd = model.birth_death
        self._lik: dict[int, np.ndarray] = {}  # p(z|t) by n_counts
        self._pd1 = float(model.sensor.detection_probability(1))
        self.horizon = search_horizon(bd.survival_probability, self._n_looks, self._n_cells,
                                      self._pd1)
        self.held_horizon = (track_horizon(model.dynamics.F, model.dynamics.Q,
                                           model.grid.cell_size) if self.track_horizon else 1.0)
        self.weight = self.search_scale * self.horizon / self.held_horizon
        #: the model-derived undetected intensity (when the tracker gives none, or own_field)
        self._own = CellField(self._n_cells, bd.initial_count_mean / self._n_cells)

    @classmethod
    def resource_terms(cls, params, model, looks_per_step) -> PolicyTerms:
        """``renyi``'s dense rows on grids of at most ``DENSE_CELLS`` cells, plus two fields
        over the cells looked at (its own and the copy of the tracker's), bounded by the
        grid and by :data:`DECLARED_STEPS` steps of looks."""
        cells = float(model.grid.n_cells)
        looked = min(cells, float(looks_per_step) * DECLARED_STEPS)
        return PolicyTerms(float(looks_per_step), state_bytes=2 * FIELD_CELL_BYTES * looked,
                           dense_rows=cells if cells <= DENSE_CELLS else 0.0)

    # ------------------------------------------------------------------ values
    def values(self, rows: np.ndarray, intensity: np.ndarray) -> np.ndarray:
        """``V = G + (w - 1) D`` of cells with count rows ``rows (n, n_counts)`` and
        undetected intensities ``intensity (n,)``."""
        n_counts = rows.shape[1]
        lik = self._lik.get(n_counts)
        if lik is None:  # one binary look: p(1|t) = p_d(t) at t = 0..n_counts-1
            lik = self._model.sensor.detection_probability(np.arange(n_counts))
            self._lik[n_counts] = lik
        g = expected_gain(rows, lik, self.alpha)
        if self.weight == 1.0:
            return g
        d = expected_gain(undetected_rows(intensity, n_counts), lik, self.alpha)
        return g + (self.weight - 1.0) * d

    def select(self, k, counts=None, truth_cells=None, undetected: CellField | None = None):
        if counts is None:
            raise ValueError("the search-track policy needs the tracker's predicted counts")
        problem = count_distribution_problem(counts, self._n_cells)
        if problem:
            raise ValueError(f"the tracker's predicted cell counts P_c(t) {problem}")
        own = undetected is None or self.own_field
        if own:  # the model-derived field, predicted to this step
            bd = self._model.birth_death
            self._own.affine(bd.survival_probability, bd.birth_rate / self._n_cells)
        field = self._own if own else undetected
        blocked = self.blocked_cells(k)  # the model's blind cells: never chosen
        m = min(self._n_looks, self._n_cells - blocked.size)
        if isinstance(counts, CellCounts) and counts.n_cells > DENSE_CELLS:
            chosen = self._select_sparse(counts, field, m, blocked)
        else:
            P = counts.dense() if isinstance(counts, CellCounts) else np.asarray(counts, float)
            values = self.values(P, field.dense())
            values[blocked] = -np.inf
            chosen = self.choose(values, m)
        if own:
            self._own.multiply(chosen, np.full(len(chosen), 1.0 - self._pd1))
        return chosen.astype(np.int64)

    def choose(self, values: np.ndarray, m: int, allowed: np.ndarray | None = None
               ) -> np.ndarray:
        """The ``m`` distinct cells of largest ``values (n_cells,)``, exact ties in a
        random order (the policy's generator), sorted; ``allowed`` (a boolean mask over the
        cells) restricts the candidates, and fewer than ``m`` come back when fewer are
        allowed."""
        perm = self._rng.permutation(len(values))
        if allowed is not None:
            perm = perm[np.asarray(allowed, dtype=bool)[perm]]
        top = np.argsort(-values[perm], kind="stable")[:m]
        return np.sort(perm[top]).astype(np.int64)

    def _select_sparse(self, counts: CellCounts, field: CellField, m: int,
                       blocked: np.ndarray) -> np.ndarray:
        """Top-``m`` over the distinct rows: the cells with their own row in ``P_c`` or in
        the field, plus the shared default (drawn, never listed); the ``blocked`` cells
        (sorted) are own cells of value ``-inf``."""
        own = np.union1d(np.union1d(counts.cells, field.cells), blocked)
        rows = np.vstack([counts.row_of(own), counts.default[None]])
        lam = np.concatenate([field.at(own), [field.default]])
        v = self.values(rows, lam)
        v[np.searchsorted(own, blocked)] = -np.inf
        merged = CellCounts(counts.n_cells, own, rows[:-1], counts.default)
        return _top_cells(merged, v[:-1], float(v[-1]), m, self._rng)

"""A non-myopic cell-selection policy: the Renyi gain plus a visibility value-to-go.

Kreucher, Hero, Kastella and Chang (CDC 2004, "Efficient methods of non-myopic sensor
management for multitarget tracking") keep the myopic information gain as the reward
and replace Bellman's value-to-go by a cheap function of what the sensor will be able
to see in the coming steps: with time-varying visibility, a target that is about to
become invisible should be measured now, while one that stays visible can wait. This
module applies that idea per cell to the tracker's predicted count distribution
``P_c(t)``, as the myopic ``renyi`` policy does (:mod:`.information`).

The value of one look at cell ``c`` during step ``k``::

    Q_c(k) = G_c(k) * (1 + beta * sum_{h=1..H} gamma^h * b_c(k + h))

* ``G_c(k)``: the expected Renyi alpha-divergence gain of one look at ``c``
  (:func:`~.information.expected_gain` on ``P_c(t)``, the ``renyi`` policy's score);
* ``b_c(j)``: 1 if the model's visibility blinds ``c`` during step ``j``, else 0
  (:meth:`~mttbench.scenarios.model.Visibility.blocked`), steps past the run included
  as visible;
* ``H`` (``horizon``), ``gamma`` (``discount``), ``beta`` (``weight``): parameters.

The value-to-go term is the information this look secures for the steps in which the
cell cannot be looked at: a cell that stays visible can be looked at next step for
about the same gain (term 0), a cell that goes blind for ``n`` of the next ``H`` steps
cannot, and the gain of the look now is counted again, discounted, for each blind step.
The looks of step ``k`` are the ``M`` distinct visible cells of largest ``Q_c(k)``
(``repeats=true``: greedy by ``w_c (G_c(n_c + 1) - G_c(n_c))`` with ``w_c`` the bracket
above), cells blind at step ``k`` never (:func:`~.information.greedy_looks` with
``blocked`` and ``weights``). ``beta = 0`` or ``H = 0``, or a scenario without
visibility: the ``renyi`` policy's choice, bit for bit, given the same generator (in a
sweep each policy's generator is seeded from its own configuration, so tie-breaks differ).

Deviations from the paper:

* the paper scores actions on the joint multitarget density (JMPD) and approximates the
  value-to-go per target; here the gains are per cell on the marginal ``P_c(t)`` (any
  tracker can drive it) and the visibility to come is read at the cell where the
  prediction puts the mass now, i.e. targets are taken not to leave their cell within
  ``H`` steps (the presets move them at most 0.1 cell per step);
* the paper's value-to-go is a function of the gain now and of the gain expected later;
  we use the multiplicative form above with a geometric discount, our choice, as the
  paper's functional form and constants were not available to us;
* the paper's sensor picks one action per step; here ``M`` distinct cells, scored
  independently (as ``renyi``).

Cost per step: the ``renyi`` policy's (``O(cells)`` on the dense path,
``O(own rows + blind cells)`` on a large grid's :class:`~mttbench.trackers.cells.CellCounts`)
plus ``O(H x blind cells per step)`` for the visibility to come (the occlusions are
rectangles: nothing per cell of the grid).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ...scenarios.model import RayleighGridSensor, TrackingModel
from ...trackers.cells import CellCounts
from ...trackers.params import Param
from .information import DENSE_CELLS, expected_gain, greedy_looks
from .policies import Policy, PolicyTerms, count_distribution_problem, register_policy


def future_blindness(model: TrackingModel, k: int, horizon: int,
                     discount: float) -> tuple[np.ndarray, np.ndarray]:
    """``sum_{h=1..H} gamma^h b_c(k + h)`` for the cells where it is not 0: sorted flat
    cells ``(n,)`` int64 and their sums ``(n,)``. ``O(H x blind cells per step)``."""
    parts, values = [], []
    for h in range(1, int(horizon) + 1):
        blind = model.blocked_cells(k + h)
        if blind.size:
            parts.append(blind)
            values.append(np.full(blind.size, discount ** h))
    if not parts:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    cells, inverse = np.unique(np.concatenate(parts), return_inverse=True)
    return cells, np.bincount(inverse, weights=np.concatenate(values), minlength=cells.size)


@register_policy
class Lookahead(Policy):
    """Renyi gain now plus a value-to-go from the visibility of the next ``horizon``
    steps: ``Q_c = G_c (1 + weight * sum_h discount^h [c blind at k + h])`` (module
    docstring: the equation and the deviations from Kreucher et al., CDC 2004)."""

    name = "lookahead"
    summary = ("non-myopic: Renyi gain of each cell times 1 + weight x the discounted number "
               "of the next `horizon` steps in which the cell will be blind")
    uses_prediction = True
    parameters: ClassVar[dict[str, Param]] = {
        "alpha": Param(float, 0, 100, low_open=True, doc="order of the Renyi divergence"),
        "repeats": Param(bool, doc="greedy by marginal gain, a cell may get several looks"),
        "horizon": Param(int, 0, 50, doc="steps of visibility looked ahead H"),
        "weight": Param(float, 0, 1e6, doc="beta: weight of the value-to-go term"),
        "discount": Param(float, 0, 1, low_open=True, doc="gamma: discount per step ahead"),
    }

    def __init__(self, alpha: float = 0.5, repeats: bool = False, horizon: int = 2,
                 weight: float = 1.0, discount: float = 0.8) -> None:
        self.alpha = alpha
        self.repeats = repeats
        self.horizon = horizon
        self.weight = weight
        self.discount = discount

    def reset(self, model: TrackingModel, n_looks: int, rng: np.random.Generator) -> None:
        super().reset(model, n_looks, rng)
        if not isinstance(model.sensor, RayleighGridSensor):
            raise TypeError("the lookahead policy needs a grid (Rayleigh) sensor")
        self.validate_params(self.get_params())
        self._pd_cache: dict[int, np.ndarray] = {}
        self._tables: dict[int, dict[int, np.ndarray]] = {}

    @classmethod
    def resource_terms(cls, params, model, looks_per_step) -> PolicyTerms:
        """``renyi``'s terms, plus the visibility to come: ``H`` lists of at most every
        occlusion's area of cells (int64) and their sums (float64)."""
        cells = float(model.grid.n_cells)
        area = sum(min(o.size[0] * o.size[1], cells) for o in model.visibility.occlusions)
        horizon = float(params.get("horizon", 2))
        return PolicyTerms(float(looks_per_step), repeats=bool(params.get("repeats", False)),
                           state_bytes=16.0 * horizon * min(area, cells),
                           dense_rows=cells if cells <= DENSE_CELLS else 0.0)

    def _p_detect(self, n_counts: int) -> np.ndarray:
        pd = self._pd_cache.get(n_counts)
        if pd is None:  # p_d(t) at the count columns t = 0..n_counts-1
            pd = self._model.sensor.detection_probability(np.arange(n_counts))
            self._pd_cache[n_counts] = pd
        return pd

    def value_weights(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The bracket ``w_c = 1 + beta sum_h gamma^h b_c(k + h)`` where it is not 1:
        sorted cells ``(n,)`` and ``w_c (n,)``."""
        if self.weight == 0.0 or self.horizon == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        cells, blind = future_blindness(self._model, k, self.horizon, self.discount)
        return cells, 1.0 + self.weight * blind

    def values(self, k: int, counts: np.ndarray) -> np.ndarray:
        """``Q_c(k)`` of every cell ``(n_cells,)`` for a dense ``counts`` ``(n_cells,
        n_counts)``, ``-inf`` where blind at step ``k`` (the score :meth:`select`
        maximises; for inspection and tests, ``O(cells)``)."""
        P = np.asarray(counts, dtype=float)
        q = expected_gain(P, self._p_detect(P.shape[1]), self.alpha)
        cells, w = self.value_weights(k)
        q[cells] *= w
        q[self.blocked_cells(k)] = -np.inf
        return q

    def select(self, k, counts=None, truth_cells=None):
        if counts is None:
            raise ValueError("the lookahead policy needs the tracker's predicted counts")
        problem = count_distribution_problem(counts, self._n_cells)
        if problem:
            raise ValueError(f"the tracker's predicted cell counts P_c(t) {problem}")
        n_counts = counts.n_counts if isinstance(counts, CellCounts) else counts.shape[1]
        return greedy_looks(counts, self._p_detect(n_counts), self._n_looks, self.alpha,
                            self.repeats, self._rng, self._tables.setdefault(n_counts, {}),
                            blocked=self.blocked_cells(k),
                            weights=self.value_weights(k))

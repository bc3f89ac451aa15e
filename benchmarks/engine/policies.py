"""Cell-selection policies: which cells the grid sensor looks at each step.

One small interface. The harness calls, every step after the tracker's predict::

    cells = policy.select(k, counts=P, truth_cells=None)   # (M,) int64, repeats allowed

``counts`` is the tracker's predicted ``P_c(t)`` as the tracker returns it: the dense
``(n_cells, n_counts)`` array or a :class:`~mttbench.trackers.cells.CellCounts` (own rows
plus one default row), passed only to policies with ``uses_prediction = True`` so other
policies never pay for it; ``truth_cells`` (flat cells of the true targets) only to
policies with ``uses_truth = True`` (the oracle), which are marked as such in every result.

Visibility: cells the model's :class:`~mttbench.scenarios.model.Visibility` blinds at step
``k`` (:meth:`Policy.blocked_cells`) cannot be looked at; the harness
(:func:`~mttbench.benchmarks.engine.loop.play`) drops such looks, and every policy here
chooses among the visible cells only.

Cost per step: ``raster``, ``random`` and ``oracle`` ``O(looks)`` (plus the true targets)
whatever the grid; ``renyi`` ``O(own rows of P_c + looks log looks)`` on a
:class:`~mttbench.trackers.cells.CellCounts` over more than
:data:`~mttbench.benchmarks.engine.information.DENSE_CELLS` cells
(:func:`~mttbench.benchmarks.engine.information.greedy_looks_sparse`), ``O(cells)`` on a dense
array or a smaller grid; ``all`` looks at every cell, ``O(cells)`` by definition.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ...scenarios.model import RayleighGridSensor, TrackingModel
from ...trackers.cells import CellCounts
from ...trackers.params import Configurable, Param
from ...trackers.registry import Registry
from .information import DENSE_CELLS, greedy_looks


@dataclass(frozen=True)
class PolicyTerms:
    """A policy's part of one run's costs, as :meth:`Policy.resource_terms` declares it
    for the sweep check (:mod:`~mttbench.benchmarks.app.resources`): ``looks`` made per
    step, ``repeats`` (one cell may take every look of a step), ``state_bytes`` of its
    own working memory, and ``dense_rows``: rows of ``P_c(t)`` it builds beyond the
    tracker's own (a dense array of every cell)."""

    looks: float
    repeats: bool = False
    state_bytes: float = 0.0
    dense_rows: float = 0.0


#: ``Generator.choice`` draws without replacement by Floyd's algorithm only when there
#: are more than this many cells per draw; otherwise it shuffles every cell (int64)
CHOICE_SHUFFLE_RATIO = 50


def skip_cells(i: np.ndarray, excluded: np.ndarray) -> np.ndarray:
    """The ``i``-th cells (0-based) among those not in ``excluded`` (sorted, distinct):
    ``i`` plus the excluded cells at or below the answer, by a search over ``excluded``
    (``O(len(i) log len(excluded))``, never a list of the other cells)."""
    excluded = np.asarray(excluded, dtype=np.int64)
    i = np.asarray(i, dtype=np.int64)
    return i + np.searchsorted(excluded - np.arange(excluded.size), i, side="right")


def _choice_bytes(n_cells: float, looks: float) -> float:
    """Bytes of ``Generator.choice(n_cells, looks, replace=False)``'s working array."""
    return min(n_cells, CHOICE_SHUFFLE_RATIO * looks) * 8.0


class Policy(Configurable, ABC):
    """Chooses the looks of each step. Constructors store parameters only.

    Parameters are declared as for trackers (:attr:`parameters`, ``{name: Param}``,
    :mod:`~mttbench.trackers.params`); :func:`make_policy` and the spec resolution check
    values against the declaration before any run.
    """

    kind: ClassVar[str] = "policy"
    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    uses_prediction: ClassVar[bool] = False
    uses_truth: ClassVar[bool] = False
    #: the harness passes ``undetected=tracker.undetected_intensity()`` to ``select``
    #: (a :class:`~mttbench.trackers.cells.CellField` or None) only when this is True
    uses_undetected: ClassVar[bool] = False

    def get_params(self) -> dict[str, Any]:
        """Constructor parameters, as stored under their own names (scikit-learn's rule;
        one not stored that way is left out). They seed the policy's generator."""
        return {n: getattr(self, n) for n in self.param_names() if hasattr(self, n)}

    @classmethod
    def resource_terms(cls, params: Mapping[str, Any], model: TrackingModel,
                       looks_per_step: float) -> PolicyTerms:
        """This policy's costs in one run of ``looks_per_step`` looks per step on
        ``model``'s grid (:class:`PolicyTerms`), for the memory and time check before a
        sweep; ``params`` are every parameter, defaults filled in. The default: the looks
        as given, repeated in one cell when a ``repeats`` parameter is true, nothing of
        its own."""
        return PolicyTerms(float(looks_per_step), repeats=bool(params.get("repeats", False)))

    def reset(self, model: TrackingModel, n_looks: int, rng: np.random.Generator) -> None:
        """Start a run: ``n_looks`` looks per step on ``model.grid``."""
        self._n_cells = model.grid.n_cells
        self._n_looks = int(n_looks)
        self._model = model
        self._rng = rng

    def blocked_cells(self, k: int) -> np.ndarray:
        """Sorted flat cells ``(n,)`` int64 that cannot be looked at during step ``k``
        (the model's visibility; ``O(blind cells)``). The harness drops a look at one of
        them, so a policy that chooses them wastes the look."""
        model = getattr(self, "_model", None)
        if model is None or not model.visibility.occlusions:
            return np.zeros(0, dtype=np.int64)
        return model.blocked_cells(k)

    @abstractmethod
    def select(self, k: int, counts: np.ndarray | CellCounts | None = None,
               truth_cells: np.ndarray | None = None) -> np.ndarray:
        """Flat cell indices ``(n,)`` int64 to look at during step ``k``."""


#: policies by name; other packages add theirs through this entry-point group
ENTRY_POINT_GROUP = "mttbench.policies"
_POLICIES: Registry[type[Policy]] = Registry("policy", Policy, ENTRY_POINT_GROUP, plural="policies")

register_policy = _POLICIES.register
available_policies = _POLICIES.names
get_policy_class = _POLICIES.get
broken_plugins = _POLICIES.broken


def make_policy(name: str, **params: Any) -> Policy:
    """Build a registered policy from checked parameters: unknown names raise
    ``TypeError``, values its declaration refuses raise
    :class:`~mttbench.trackers.params.ParameterError` (a ``ValueError``)."""
    cls = _POLICIES.get(name)
    return cls(**cls.validate_params(params, name=name))


@register_policy
class AllCells(Policy):
    """Every cell once per step (ignores the look budget): the best a sensor can do."""

    name = "all"
    summary = "look at every cell once per step (ignores the look budget)"
    parameters: ClassVar[dict[str, Param]] = {}

    def select(self, k, counts=None, truth_cells=None):
        cells = np.arange(self._n_cells, dtype=np.int64)
        blocked = self.blocked_cells(k)
        return np.setdiff1d(cells, blocked, assume_unique=True) if blocked.size else cells

    @classmethod
    def resource_terms(cls, params, model, looks_per_step) -> PolicyTerms:
        """Every cell once per step: ``M = C`` looks, ``O(cells)`` by definition."""
        return PolicyTerms(float(model.grid.n_cells))


@register_policy
class RandomCells(Policy):
    """``M`` distinct cells drawn uniformly each step (the policy's own generator).

    ``Generator.choice(n_cells, M, replace=False)``: Floyd's algorithm, ``O(M)``, when
    ``M <= n_cells / 50``, a partial shuffle of all cells (``O(cells)``) otherwise, so
    the cost is ``O(looks)`` on any grid with more than 50 cells per look."""

    name = "random"
    summary = "M distinct cells drawn uniformly at random each step"
    parameters: ClassVar[dict[str, Param]] = {}

    def select(self, k, counts=None, truth_cells=None):
        blocked = self.blocked_cells(k)
        n_free = self._n_cells - blocked.size  # drawn among the visible cells
        m = min(self._n_looks, n_free)
        i = self._rng.choice(n_free, size=m, replace=False)
        return np.sort(skip_cells(i, blocked) if blocked.size else i).astype(np.int64)

    @classmethod
    def resource_terms(cls, params, model, looks_per_step) -> PolicyTerms:
        """``Generator.choice``: every cell shuffled when there are fewer than
        :data:`CHOICE_SHUFFLE_RATIO` per look."""
        return PolicyTerms(float(looks_per_step),
                           state_bytes=_choice_bytes(model.grid.n_cells, looks_per_step))


@register_policy
class Raster(Policy):
    """Kreucher's periodic scan: step ``k`` looks at cells ``(k M + i) mod n_cells``,
    ``i = 0, ..., M - 1``.

    A pointer advances ``M`` cells per step through the flat cell order (row by row from
    the bottom row, :class:`~mttbench.scenarios.model.Grid`) and wraps around, so the
    sweep continues across steps. ``M`` is not capped at the cell count: with
    ``M > n_cells`` the pointer wraps within the step and every cell is looked at
    ``floor(M / n_cells)`` or ``ceil(M / n_cells)`` times (e.g. 312 looks on 144 cells:
    each cell 2 or 3 times), each repeat an independent look
    (:class:`~mttbench.scenarios.model.Looks`). That is how periodic scans of more looks
    than cells (Kreucher's 216 and 312 on 12x12) are run.

    With a visibility in the model the sweep skips the blind cells: the pointer walks the
    visible cells of the step (``M`` of them, wrapping) and then stands after the last
    cell looked at, so no look is wasted and the scan resumes where it stopped. Without
    blind cells this is the formula above.
    """

    name = "raster"
    summary = ("raster sweep: M consecutive cells per step, wrapping around the grid (more "
               "looks than cells: some cells are looked at twice or more per step)")
    parameters: ClassVar[dict[str, Param]] = {}

    def reset(self, model: TrackingModel, n_looks: int, rng: np.random.Generator) -> None:
        super().reset(model, n_looks, rng)
        self._pointer = 0  # the next cell of the sweep (a visibility in the model only)

    def select(self, k, counts=None, truth_cells=None):
        m = self._n_looks
        if not self._model.visibility.occlusions:
            start = (k * m) % self._n_cells  # reduced first: k * M stays small
            return ((start + np.arange(m, dtype=np.int64)) % self._n_cells).astype(np.int64)
        blocked = self.blocked_cells(k)
        n_free = self._n_cells - blocked.size
        if n_free == 0 or m == 0:
            return np.zeros(0, dtype=np.int64)
        # rank of the pointer among the visible cells, then M consecutive visible ranks
        first = self._pointer - int(np.searchsorted(blocked, self._pointer))
        cells = skip_cells((first + np.arange(m, dtype=np.int64)) % n_free, blocked)
        self._pointer = (int(cells[-1]) + 1) % self._n_cells
        return cells.astype(np.int64)


@register_policy
class Oracle(Policy):
    """REFERENCE ONLY -- USES THE TRUTH. Looks at the cells holding true targets first.

    Each step: the distinct cells of the true targets (``truth_cells``, flat indices;
    ``-1`` = outside the grid, ignored), in random order if there are more than ``M``,
    then distinct other cells drawn uniformly to fill the ``M`` looks (indices drawn
    among the ``n_cells - T`` other cells and mapped to cells by a search over the
    sorted true cells: ``O(looks + T)``, never a list of the other cells). The harness
    passes ``truth_cells`` only to policies with ``uses_truth = True`` and marks
    their results; a tracker never sees the truth, only the looks this policy made.
    """

    name = "oracle"
    summary = "REFERENCE, USES THE TRUTH: cells of the true targets, then random cells"
    uses_truth = True
    parameters: ClassVar[dict[str, Param]] = {}

    def select(self, k, counts=None, truth_cells=None):
        if truth_cells is None:
            raise ValueError("the oracle policy needs the true targets' cells")
        blocked = self.blocked_cells(k)
        m = min(self._n_looks, self._n_cells - blocked.size)
        truth = np.unique(np.asarray(truth_cells, dtype=np.int64))
        truth = truth[(truth >= 0) & (truth < self._n_cells)]
        if blocked.size:  # a target in a blind cell cannot be looked at
            truth = truth[~np.isin(truth, blocked, assume_unique=True)]
        if truth.size >= m:
            return np.sort(self._rng.choice(truth, size=m, replace=False)).astype(np.int64)
        # the i-th cell neither holding a target nor blind
        taken = np.union1d(truth, blocked) if blocked.size else truth
        i = self._rng.choice(self._n_cells - taken.size, size=m - truth.size, replace=False)
        return np.sort(np.concatenate([truth, skip_cells(i, taken)])).astype(np.int64)

    @classmethod
    def resource_terms(cls, params, model, looks_per_step) -> PolicyTerms:
        """Its random fill as :class:`RandomCells`' draw (``Generator.choice``)."""
        return PolicyTerms(float(looks_per_step),
                           state_bytes=_choice_bytes(model.grid.n_cells, looks_per_step))


#: how far a row of ``P_c(t)`` may sum from 1 (round-off of a tracker's mixture), and
#: how negative an entry may be
COUNTS_SUM_TOL = 1e-6


def count_distribution_problem(counts: Any, n_cells: int) -> str:
    """Why a tracker's ``cell_count_distribution()`` is not a distribution over counts for
    each of the ``n_cells`` cells ("" if it is): a :class:`CellCounts` of that grid or an
    array ``(n_cells, n_counts >= 2)``, every entry finite and >= 0, every row summing to
    1 (within :data:`COUNTS_SUM_TOL`). Checks the rows the tracker gave (its own rows and
    the default one): ``O(rows x n_counts)``, what the gains cost anyway."""
    if isinstance(counts, CellCounts):
        if counts.n_cells != n_cells:
            return f"cover {counts.n_cells} cells, the grid has {n_cells}"
        rows = np.vstack([counts.rows, counts.default[None]])
    else:
        rows = np.asarray(counts) if isinstance(counts, np.ndarray) else None
        if rows is None or rows.ndim != 2 or rows.shape[0] != n_cells or rows.shape[1] < 2:
            shape = getattr(rows, "shape", type(counts).__name__)
            return (f"are {shape}, not (n_cells = {n_cells}, n_counts >= 2) or a "
                    "CellCounts")
        if not np.issubdtype(rows.dtype, np.number) or np.iscomplexobj(rows):
            return f"are of dtype {rows.dtype}, not real numbers"
    if not np.isfinite(rows).all():
        return "are not all finite"
    if (rows < -COUNTS_SUM_TOL).any():
        return f"have a negative entry ({rows.min():g})"
    sums = rows.sum(axis=1)
    worst = int(np.argmax(np.abs(sums - 1.0)))
    if abs(sums[worst] - 1.0) > COUNTS_SUM_TOL:
        return f"have a row summing to {sums[worst]:.6g}, not 1"
    return ""


@register_policy
class RenyiGain(Policy):
    """Looks where the expected Renyi alpha-divergence gain of the count is largest.

    Uses the tracker's predicted ``P_c(t)`` and the scenario's Rayleigh sensor model.
    ``repeats=False`` (default): the top-M distinct cells by single-look gain ``G_c(1)``.
    ``repeats=True``: greedy by marginal gain ``G_c(n_c+1) - G_c(n_c)``, so a cell may
    be looked at several times in one step (Kreucher's managed sensor).

    Top-M distinct cells by default: greedy with repeats piles the looks onto the few
    cells around known targets and starves the search for new ones (measured on
    ``crossing``: docs/policies.md).

    Given a :class:`~mttbench.trackers.cells.CellCounts` on a grid of more than
    :data:`~mttbench.benchmarks.engine.information.DENSE_CELLS` cells, the gains are computed
    once per own row and once for the default row, and default cells are drawn without
    being listed (:func:`~mttbench.benchmarks.engine.information.greedy_looks_sparse`): the
    same rule, other random tie-breaks. A dense array, or a smaller grid, chooses
    exactly as before (the dense path).
    """

    name = "renyi"
    summary = "expected Renyi alpha-divergence gain of each cell's count (tracker's prediction)"
    uses_prediction = True
    parameters: ClassVar[dict[str, Param]] = {
        # at most 100: the gains raise likelihood ratios to the power alpha (overflow)
        "alpha": Param(float, 0, 100, low_open=True, doc="order of the Renyi divergence"),
        "repeats": Param(bool, doc="greedy by marginal gain, a cell may get several looks"),
    }

    def __init__(self, alpha: float = 0.5, repeats: bool = False) -> None:
        self.alpha = alpha
        self.repeats = repeats

    def reset(self, model: TrackingModel, n_looks: int, rng: np.random.Generator) -> None:
        super().reset(model, n_looks, rng)
        if not isinstance(model.sensor, RayleighGridSensor):
            raise TypeError("the renyi policy needs a grid (Rayleigh) sensor")
        self.validate_params(self.get_params())  # the declaration above (built directly)
        self._pd_cache: dict[int, np.ndarray] = {}
        self._tables: dict[int, dict[int, np.ndarray]] = {}  # by n_counts, then by n

    @classmethod
    def resource_terms(cls, params, model, looks_per_step) -> PolicyTerms:
        """The dense path on grids of at most ``DENSE_CELLS`` cells: a row of ``P_c(t)``
        and of gains for every cell."""
        cells = float(model.grid.n_cells)
        return PolicyTerms(float(looks_per_step), repeats=bool(params.get("repeats", False)),
                           dense_rows=cells if cells <= DENSE_CELLS else 0.0)

    def select(self, k, counts=None, truth_cells=None):
        if counts is None:
            raise ValueError("the renyi policy needs the tracker's predicted counts")
        problem = count_distribution_problem(counts, self._n_cells)
        if problem:
            raise ValueError(f"the tracker's predicted cell counts P_c(t) {problem}")
        n_counts = counts.n_counts if isinstance(counts, CellCounts) else counts.shape[1]
        pd = self._pd_cache.get(n_counts)
        if pd is None:  # p_d(t) at the count columns t = 0..n_counts-1
            pd = self._model.sensor.detection_probability(np.arange(n_counts))
            self._pd_cache[n_counts] = pd
        return greedy_looks(counts, pd, self._n_looks, self.alpha, self.repeats, self._rng,
                            self._tables.setdefault(n_counts, {}),
                            blocked=self.blocked_cells(k))

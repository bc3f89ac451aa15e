"""The interface every tracker implements, and the registry of trackers by name.

Life cycle, as the step loop drives it (untimed ``reset``, timed steps)::

    tracker = make("gpf", epsilon=1e-3)     # constructor: store parameters only
    reason = tracker.unsupported_reason(model)   # None, or why it cannot run this model
    tracker.reset(model, rng)               # untimed: build the run state
    for k in range(n_steps):
        tracker.predict()                   # timed
        P = tracker.cell_count_distribution()   # P_c(t), when a policy asks
        tracker.update(looks)               # timed; looks of step k
        est = tracker.estimate()            # timed

``reset`` gives the prior *before* step 0, so ``predict`` is called before every
update, including the first.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..scenarios.model import Looks, TrackingModel
from .cells import CellCounts, CellField
from .params import Budget, Configurable
from .registry import Registry


@dataclass(frozen=True)
class Estimate:
    """A tracker's output at one step.

    ``count`` is the estimated number of targets (float or int, as the tracker
    defines it; never negative). ``states`` is ``(n, 4)`` float64 with rows
    ``[px, vx, py, vy]``; ``n`` need not equal ``count`` (for example the GPF's
    count is ``sum w`` while it reports the ``round(sum w)`` heaviest components).
    ``covariances`` is ``(n, 4, 4)`` or None, used only for plots.

    ``labels`` is ``(n,)`` int64 or None: a persistent track label per reported state,
    unique within a step, equal across steps for the same track (the track-level scores
    of :mod:`~mttbench.benchmarks.engine.track_metrics` read them). None means the
    tracker keeps no track identity; its track-level scores are then empty (NaN).
    """

    count: float
    states: np.ndarray
    covariances: np.ndarray | None = None
    labels: np.ndarray | None = None

    @staticmethod
    def empty() -> Estimate:
        return Estimate(0.0, np.zeros((0, 4)))


# ------------------------------------------------------------------ resource terms
# Measured costs shared by several trackers (benchmarks/app/resources.py and
# docs/resources.md say how they were measured and how the sweep check adds them up).
#: cells of a Gaussian's 6-sd box counted per Gaussian (in P_c(t)'s entries and in the
#: (Gaussian, looked cell) pairs; docs/resources.md)
BOX_CELLS = 256
#: per target and step of the trackers with a Gaussian per target (kfnn, truth-aided,
#: gpf): truth-aided 3 ms per step with 25 targets on 12x12
TARGET_S = 2e-4
#: per cell looked at so far, for the trackers with an undetected field (a value per
#: such cell, inserted with a copy): 25 (kfnn), 27 (ss-gnn), 76 (jmpd-ap) and 96 B
#: (gpf, its box test included) more than null's growth, over 250,000 looked cells
#: (raster, 2,500 looks x 100 steps on 1e5 x 1e5)
LOOKED_CELL_BYTES = 128
#: per cell looked at so far and step (the undetected field's update)
LOOKED_CELL_S = 1e-8
#: per (Gaussian, looked cell) pair of the grid update (``gpf.grid``, gpf and
#: truth-aided): its quadrature's temporaries (16 arrays of up to 24 nodes) and moments
PAIR_BYTES = 3072
#: per (Gaussian, looked cell) pair: its truncated moments (gpf on ``large``: 3-5 ms for
#: 4,000 pairs) or a birth candidate's update
PAIR_S = 1e-6


def param_number(params: Mapping[str, Any], key: str, default: float) -> float:
    """``params[key]`` as a float for a resource estimate; ``default`` when it is missing,
    not a number (booleans included), not finite or negative."""
    v = params.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
        return float(default)
    return float(v)


def gaussian_boxes(targets: float) -> float:
    """Gaussians (or target images) counted at once for a tracker with a Gaussian per
    target: ``2 T + 16`` (docs/resources.md)."""
    return 2.0 * targets + 16.0


@dataclass(frozen=True)
class ResourceTerms:
    """A tracker's own part of one run's memory (bytes) and time (seconds per step), as
    :meth:`Tracker.resource_terms` declares it for the sweep check
    (:mod:`~mttbench.benchmarks.app.resources`). Upper estimates from measurements, not
    predictions; every term defaults to nothing.

    Always counted: ``state_bytes`` (particles, Gaussians), ``step_seconds`` (per step)
    and ``target_seconds`` (per target and step). On a grid sensor, with ``m`` distinct
    cells looked at per step (the ``looks_per_step`` the terms were computed for):
    ``update_bytes`` and ``update_seconds`` (the update's work for those ``m`` cells, as
    a whole) and ``look_bytes`` and ``look_seconds`` (per looked cell, times ``m``);
    ``looked_cell_bytes`` and ``looked_cell_seconds`` per cell looked at so far (an
    undetected field keeping a value per such cell; those cells then also have rows of
    their own in ``P_c(t)``). When the policy reads ``P_c(t)``: ``prediction_entries``
    (the particle slots or box cells it is built from), ``prediction_counts`` (its
    ``n_counts``, count columns) and ``prediction_seconds`` per step beyond its rows.
    """

    state_bytes: float = 0.0
    update_bytes: float = 0.0
    look_bytes: float = 0.0
    looked_cell_bytes: float = 0.0
    step_seconds: float = 0.0
    target_seconds: float = 0.0
    update_seconds: float = 0.0
    look_seconds: float = 0.0
    looked_cell_seconds: float = 0.0
    prediction_entries: float = 0.0
    prediction_counts: float = 2.0
    prediction_seconds: float = 0.0

    @property
    def keeps_looked_cells(self) -> bool:
        """True if the tracker keeps a value for every cell looked at so far."""
        return bool(self.looked_cell_bytes or self.looked_cell_seconds)


class Tracker(Configurable, ABC):
    """Base class of all trackers.

    Subclasses declare their parameters as keyword arguments of ``__init__`` with
    defaults and store each one, unchanged, under the same attribute name
    (scikit-learn's rule); :meth:`get_params` reads them back for the results table.
    What each parameter accepts is declared once in :attr:`parameters`
    (``{name: Param}``, :mod:`~mttbench.trackers.params`), rules between parameters in
    :meth:`param_conflict`; :func:`make`, the command line and the harness check values
    against them before any run. A subclass that only changes defaults sets
    ``defaults_only = True`` and shares its parent's random numbers (``jmpd-ip``).
    """

    kind: ClassVar[str] = "tracker"
    name: ClassVar[str] = ""
    #: one line for ``mttbench trackers``
    summary: ClassVar[str] = ""
    #: a baseline that does not track by design (``null``): the conformance kit
    #: (:mod:`mttbench.testing`) skips its tracking checks
    baseline: ClassVar[bool] = False
    #: checks of the conformance kit this tracker cannot pass: ``{check name: reason}``
    conformance_exceptions: ClassVar[dict[str, str]] = {}
    #: a reference that is given the truth (``truth-aided``): the harness calls its
    #: ``observe_truth(states (n, 4), ids (n,))`` each step after ``predict`` (never for
    #: other trackers) and marks its rows ``tracker_uses_truth``
    uses_truth: ClassVar[bool] = False
    #: a reference computed from the model alone, not a contestant (``grid-bayes``, the
    #: exact single-target Bayes filter): it uses no truth, but rankings, "best tracker"
    #: verdicts and the default tracker list of ``mttbench compare`` should leave it out
    reference: ClassVar[bool] = False
    #: the parameters that buy accuracy with time, each with the range ``mttbench
    #: frontier`` sweeps (:class:`~mttbench.trackers.params.Budget`), the main one first;
    #: ``{}``: no such knob (a frontier's single point); None: not declared
    budget: ClassVar[Mapping[str, Budget] | None] = None

    # ------------------------------------------------------------------ params
    # param_names, param_defaults, validate_params, resolved_params, param_conflict,
    # implementation and canonical_config come from Configurable (trackers/params.py)
    def get_params(self) -> dict[str, Any]:
        """The constructor parameters, as stored."""
        return {n: getattr(self, n) for n in self.param_names()}

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"

    # ------------------------------------------------------------ resource terms
    @classmethod
    def resource_terms(cls, params: Mapping[str, Any], model: TrackingModel,
                       looks_per_step: float, targets: float) -> ResourceTerms:
        """This tracker's costs in one run (:class:`ResourceTerms`), for the memory and
        time check before a sweep (:mod:`~mttbench.benchmarks.app.resources`).

        ``params`` are every parameter (defaults filled in; read them with
        :func:`param_number`), ``looks_per_step`` the distinct cells looked at per step
        (``min(M, C)``; 0 without a grid sensor), ``targets`` the targets of the run
        (initial plus expected births). Override it with the tracker's measured costs.
        The default (a tracker written elsewhere) counts nothing beyond the run's common
        terms, and a ``P_c(t)`` built from ``2 T + 16`` Gaussians' boxes with ``n_counts``
        (or ``t_max + 1``, at least 4) count columns.
        """
        n_counts = max(4.0, param_number(params, "n_counts", 0),
                       param_number(params, "t_max", 0) + 1)
        return ResourceTerms(prediction_entries=gaussian_boxes(targets) * BOX_CELLS,
                             prediction_counts=n_counts)

    # --------------------------------------------------------------- life cycle
    def unsupported_reason(self, model: TrackingModel) -> str | None:
        """None if the tracker can run ``model``, otherwise a one-line reason."""
        return None

    @abstractmethod
    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        """Build the run state (the prior before step 0). All randomness from ``rng``."""

    @abstractmethod
    def predict(self) -> None:
        """Propagate the state one step with the dynamics and the birth/death prior."""

    @abstractmethod
    def cell_count_distribution(self) -> np.ndarray | CellCounts:
        """Predicted per-cell count distribution ``P_c(t)``.

        Each cell's row is a distribution over counts: non-negative, summing to 1;
        column ``t`` is the probability of ``t`` targets in the cell, and the last column
        holds "``n_counts - 1`` or more". ``n_counts >= 2``. Valid between
        :meth:`predict` and :meth:`update`.

        Return either a :class:`~mttbench.trackers.cells.CellCounts` -- the cells with a
        row of their own (for example near a track) plus one default row shared by every
        other cell (for example the untracked-target field), which costs nothing per cell
        of the grid -- or the dense ``(n_cells,
        n_counts)`` array (``O(cells)``: fine on small grids; policies accept both, and
        :func:`~mttbench.trackers.cells.as_cell_counts` turns either into the former).
        """

    def undetected_intensity(self) -> CellField | None:
        """The expected number of targets no track holds, per cell, as predicted for this
        step (valid where :meth:`cell_count_distribution` is), or None if the tracker holds
        no such field (the default; a policy then derives one from the model). Read only:
        the caller never changes it (a tracker may return its own field, as KF-NN does)."""
        return None

    @abstractmethod
    def update(self, looks: Looks) -> None:
        """Condition on the measurements of one step."""

    @abstractmethod
    def estimate(self) -> Estimate:
        """The current estimate (count and states)."""


# ----------------------------------------------------------------------- registry
#: trackers by name; other packages add theirs through this entry-point group
ENTRY_POINT_GROUP = "mttbench.trackers"
_TRACKERS: Registry[type[Tracker]] = Registry("tracker", Tracker, ENTRY_POINT_GROUP)

register = _TRACKERS.register
unregister = _TRACKERS.unregister
available = _TRACKERS.names
broken_plugins = _TRACKERS.broken


def get_class(name: str) -> type[Tracker]:
    """The tracker class of a registered name (shipped or from an entry point), or of a
    class path ``package.module:Class`` (a tracker written elsewhere, not registered)."""
    return _TRACKERS.get(name)


def make(name: str, **params: Any) -> Tracker:
    """Build a tracker by name (see :func:`get_class`) from checked parameters.

    Unknown parameter names raise ``TypeError``; values its declaration refuses raise
    :class:`~mttbench.trackers.params.ParameterError` (a ``ValueError``), in one line.
    The tracker gets the values in their canonical types (``n_particles=1000.0`` is
    stored as ``1000``)."""
    cls = get_class(name)
    return cls(**cls.validate_params(params, name=name))

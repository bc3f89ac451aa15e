"""The interface every tracker implements, and the registry of trackers by name.

Life cycle, as the harness drives it (STYLE.md pattern 1)::

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

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..scenarios.model import Looks, TrackingModel
from .cells import CellCounts
from .params import Configurable
from .registry import Registry


@dataclass(frozen=True)
class Estimate:
    """A tracker's output at one step.

    ``count`` is the estimated number of targets (float or int, as the tracker
    defines it; never negative). ``states`` is ``(n, 4)`` float64 with rows
    ``[px, vx, py, vy]``; ``n`` need not equal ``count`` (for example the GPF's
    count is ``sum w`` while it reports the ``round(sum w)`` heaviest components).
    ``covariances`` is ``(n, 4, 4)`` or None, used only for plots.
    """

    count: float
    states: np.ndarray
    covariances: np.ndarray | None = None

    @staticmethod
    def empty() -> Estimate:
        return Estimate(0.0, np.zeros((0, 4)))


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
    #: other trackers) and marks its rows ``uses_truth``
    uses_truth: ClassVar[bool] = False

    # ------------------------------------------------------------------ params
    # param_names, param_defaults, validate_params, resolved_params, param_conflict,
    # implementation and canonical_config come from Configurable (trackers/params.py)
    def get_params(self) -> dict[str, Any]:
        """The constructor parameters, as stored."""
        return {n: getattr(self, n) for n in self.param_names()}

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"

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

"""The interface every tracker implements, and the registry of trackers by name.

Life cycle, as the harness drives it (STYLE.md pattern 1)::

    tracker = make("gpf", epsilon=1e-3)     # constructor: store parameters only
    reason = tracker.unsupported_reason(model)   # None, or why it cannot run this model
    tracker.reset(model, rng)               # untimed: build the run state
    for k in range(n_steps):
        tracker.predict()                   # timed
        P = tracker.cell_count_distribution()   # (n_cells, n_counts), when a policy asks
        tracker.update(looks)               # timed; looks of step k
        est = tracker.estimate()            # timed

``reset`` gives the prior *before* step 0, so ``predict`` is called before every
update, including the first.
"""

from __future__ import annotations

import importlib
import inspect
from abc import ABC, abstractmethod
from dataclasses import dataclass
from importlib import metadata
from typing import Any, ClassVar

import numpy as np

from ..scenarios.model import Looks, TrackingModel


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


class Tracker(ABC):
    """Base class of all trackers.

    Subclasses declare their parameters as keyword arguments of ``__init__`` with
    defaults and store each one, unchanged, under the same attribute name
    (scikit-learn's rule); :meth:`get_params` reads them back for the results table.
    """

    name: ClassVar[str] = ""
    #: one line for ``mttbench trackers``
    summary: ClassVar[str] = ""
    #: a baseline that does not track by design (``null``): the conformance kit
    #: (:mod:`mttbench.testing`) skips its tracking checks
    baseline: ClassVar[bool] = False
    #: checks of the conformance kit this tracker cannot pass: ``{check name: reason}``
    conformance_exceptions: ClassVar[dict[str, str]] = {}

    # ------------------------------------------------------------------ params
    @classmethod
    def param_names(cls) -> list[str]:
        sig = inspect.signature(cls.__init__)
        kinds = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
        return [p.name for p in sig.parameters.values() if p.name != "self" and p.kind in kinds]

    @classmethod
    def param_defaults(cls) -> dict[str, Any]:
        sig = inspect.signature(cls.__init__)
        return {n: sig.parameters[n].default for n in cls.param_names()}

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
    def cell_count_distribution(self) -> np.ndarray:
        """Predicted per-cell count distribution ``P_c(t)``.

        Returns ``(n_cells, n_counts)`` with non-negative rows summing to 1; column
        ``t`` is the probability of ``t`` targets in the cell, and the last column
        holds "``n_counts - 1`` or more". ``n_counts >= 2``. Valid between
        :meth:`predict` and :meth:`update`.
        """

    @abstractmethod
    def update(self, looks: Looks) -> None:
        """Condition on the measurements of one step."""

    @abstractmethod
    def estimate(self) -> Estimate:
        """The current estimate (count and states)."""


# ----------------------------------------------------------------------- registry
#: entry-point group through which other packages register trackers
ENTRY_POINT_GROUP = "mttbench.trackers"

_REGISTRY: dict[str, type[Tracker]] = {}
#: entry points that failed to load: name -> one-line reason (listed by ``mttbench trackers``)
_BROKEN: dict[str, str] = {}
_plugins_loaded = False


def register(cls: type[Tracker]) -> type[Tracker]:
    """Class decorator: register a tracker under ``cls.name``."""
    if not (isinstance(cls, type) and issubclass(cls, Tracker)):
        raise TypeError(f"{cls!r} is not a subclass of mttbench.trackers.Tracker")
    if not cls.name:
        raise ValueError(f"{cls.__name__} needs a non-empty `name`")
    if cls.name in _REGISTRY and _REGISTRY[cls.name] is not cls:
        raise ValueError(f"tracker name {cls.name!r} is already registered")
    _REGISTRY[cls.name] = cls
    return cls


def load_plugins() -> None:
    """Register the trackers of installed packages' ``mttbench.trackers`` entry points.

    An entry point ``name = "package.module:Class"`` names a :class:`Tracker` subclass
    whose ``name`` is ``name``. One that fails to import or is not such a class is
    left out and its reason kept in :func:`broken_plugins`; it never stops the others.
    Runs once per process, on the first use of the registry.
    """
    global _plugins_loaded
    if _plugins_loaded:
        return
    _plugins_loaded = True
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in _REGISTRY:
            continue
        try:
            cls = ep.load()
            if not (isinstance(cls, type) and issubclass(cls, Tracker)):
                raise TypeError(f"{ep.value} is not a Tracker subclass")
            if cls.name != ep.name:
                raise ValueError(f"{ep.value}.name is {cls.name!r}, not {ep.name!r}")
            register(cls)
        except Exception as exc:  # noqa: BLE001 - a broken plugin must not stop the suite
            _BROKEN[ep.name] = f"{type(exc).__name__}: {exc}".splitlines()[0]


def broken_plugins() -> dict[str, str]:
    """Entry points that failed to load: name -> reason."""
    load_plugins()
    return dict(_BROKEN)


def available() -> list[str]:
    """Registered tracker names (shipped and from entry points), sorted."""
    load_plugins()
    return sorted(_REGISTRY)


def get_class(name: str) -> type[Tracker]:
    """The tracker class of a registered name, or of a class path ``package.module:Class``
    (a tracker written elsewhere, used without registering it)."""
    load_plugins()
    if name in _REGISTRY:
        return _REGISTRY[name]
    if name in _BROKEN:
        raise KeyError(f"tracker {name!r} failed to load: {_BROKEN[name]}")
    module, colon, attr = name.partition(":")
    if not colon:
        raise KeyError(f"unknown tracker {name!r}: registered trackers are {available()}; "
                       "a tracker from elsewhere is named package.module:ClassName")
    try:
        cls = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise KeyError(f"cannot import tracker {name!r}: {exc}") from None
    if not (isinstance(cls, type) and issubclass(cls, Tracker)):
        raise KeyError(f"{name!r} is not a subclass of mttbench.trackers.Tracker")
    return cls


def make(name: str, **params: Any) -> Tracker:
    """Build a tracker by name (see :func:`get_class`); unknown parameters are refused."""
    cls = get_class(name)
    unknown = set(params) - set(cls.param_names())
    if unknown:
        raise TypeError(f"tracker {name!r} has no parameter(s) {sorted(unknown)}; "
                        f"its parameters are {cls.param_defaults()}")
    return cls(**params)

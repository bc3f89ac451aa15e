"""Trackers behind one interface (:class:`~mttbench.trackers.base.Tracker`), registered by name.

Importing this package registers every shipped tracker. Trackers of other packages
register through the entry-point group ``mttbench.trackers`` (loaded on the first use
of the registry), or are named by class path, ``package.module:ClassName``.
"""

from . import gpf, grid_bayes, jmpd, kfnn, null, pmb, stonesoup, truth_aided  # noqa: F401  (importing registers them)
from .base import (
    Estimate,
    Tracker,
    available,
    broken_plugins,
    get_class,
    make,
    register,
    unregister,
)
from .params import Budget, Param, ParameterError, Search

__all__ = ["Budget", "Estimate", "Param", "ParameterError", "Search", "Tracker", "available",
           "broken_plugins", "get_class", "make", "register", "unregister"]

"""Trackers behind one interface (:class:`trackers.base.Tracker`), registered by name.

Importing this package registers every shipped tracker; add a new module's import
below to register it (the conformance suite then tests it automatically).
"""

from . import (
    gpf,  # noqa: F401  (registers "gpf")
    jmpd,  # noqa: F401  (registers "jmpd", "jmpd-ip")
    kfnn,  # noqa: F401  (registers "kfnn")
    null,  # noqa: F401  (registers "null")
)
from .base import Estimate, Tracker, available, get_class, make, register

__all__ = ["Estimate", "Tracker", "available", "get_class", "make", "register"]

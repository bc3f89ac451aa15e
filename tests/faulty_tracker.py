"""Trackers that misbehave at step 1, for the sweep's fault tests (``faulty_tracker:Hang``).

Importable in-process (pytest puts ``tests/`` on ``sys.path``) and in worker processes.
"""

from __future__ import annotations

import os
import signal
import time
from typing import ClassVar

import crashing_tracker
import numpy as np

from mttbench import Estimate
from mttbench.trackers.params import Param, Search

#: the step at which each tracker misbehaves (0-based, counted by ``predict``)
FAULT_STEP = 1


class _Nothing(crashing_tracker._Nothing):
    """Reports no target (crashing_tracker's); calls :meth:`fault` at :data:`FAULT_STEP`."""

    def update(self, looks):
        if self._k == FAULT_STEP:
            self.fault()

    def fault(self):
        pass


class Hang(_Nothing):
    """Never returns from ``update`` at step 1."""

    name = "hang"
    summary = "test tracker: hangs at step 1"

    def fault(self):
        while True:
            time.sleep(0.05)


class Exit(_Nothing):
    """Raises ``SystemExit(0)`` in ``update`` at step 1."""

    name = "exit"
    summary = "test tracker: SystemExit at step 1"

    def fault(self):
        raise SystemExit(0)


class Kill(_Nothing):
    """Kills its own process (SIGKILL, as the kernel's OOM killer would) at step 1."""

    name = "kill"
    summary = "test tracker: SIGKILL at step 1"

    def fault(self):
        os.kill(os.getpid(), signal.SIGKILL)


class NanCount(_Nothing):
    """Estimates a NaN count at step 1."""

    name = "nan-count"
    summary = "test tracker: NaN count at step 1"

    def estimate(self):
        return Estimate(float("nan") if self._k == FAULT_STEP else 0.0, np.zeros((0, 4)))


class NegativeCount(_Nothing):
    """Estimates a count of -1 at step 1."""

    name = "negative-count"
    summary = "test tracker: count -1 at step 1"

    def estimate(self):
        return Estimate(-1.0 if self._k == FAULT_STEP else 0.0, np.zeros((0, 4)))


class NanState(_Nothing):
    """Estimates one target with a NaN state at step 1."""

    name = "nan-state"
    summary = "test tracker: a NaN state at step 1"

    def estimate(self):
        if self._k == FAULT_STEP:
            return Estimate(1.0, np.full((1, 4), np.nan))
        return Estimate.empty()


class Interrupt(_Nothing):
    """Raises ``KeyboardInterrupt`` in ``update`` at step 1 (its own, not a Ctrl-C)."""

    name = "interrupt"
    summary = "test tracker: KeyboardInterrupt at step 1"

    def fault(self):
        raise KeyboardInterrupt


class _BadCounts(_Nothing):
    """Predicts malformed cell counts ``P_c(t)`` at step 1 (:meth:`bad`)."""

    def cell_count_distribution(self):
        P = super().cell_count_distribution()
        return self.bad(P) if self._k == FAULT_STEP else P

    def bad(self, P):
        return P


class CountsUnnormalised(_BadCounts):
    name = "counts-unnormalised"
    summary = "test tracker: P_c(t) rows summing to 2 at step 1"

    def bad(self, P):
        return 2.0 * P


class CountsNan(_BadCounts):
    name = "counts-nan"
    summary = "test tracker: a NaN in P_c(t) at step 1"

    def bad(self, P):
        P[3, 0] = np.nan
        return P


class CountsNegative(_BadCounts):
    name = "counts-negative"
    summary = "test tracker: a negative P_c(t) entry at step 1"

    def bad(self, P):
        P[0] = [1.5, -0.5]
        return P


class CountsShape(_BadCounts):
    name = "counts-shape"
    summary = "test tracker: P_c(t) of one cell too few at step 1"

    def bad(self, P):
        return P[1:]


class HangWhenTold(_Nothing):
    """Hangs at step 1 (as :class:`Hang`) when its searched choice ``mode`` is ``"hang"``,
    else reports nothing: a tune draws trials of both kinds."""

    name = "hang-when-told"
    summary = "test tracker: hangs at step 1 when told to"
    parameters: ClassVar[dict[str, Param]] = {
        "mode": Param(choices=("ok", "hang"), search=Search(choices=("ok", "hang"))),
        "level": Param(float, 0, 1, search=Search(0.0, 1.0)),
    }

    def __init__(self, mode: str = "ok", level: float = 0.5) -> None:
        self.mode, self.level = mode, level

    def fault(self):
        if self.mode == "hang":
            Hang.fault(self)

"""Trackers for the command-line tests, named by class path (``crashing_tracker:Crash``).

Importable in-process (pytest puts ``tests/`` on ``sys.path``) and in subprocesses that
get ``tests/`` on ``PYTHONPATH``.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import ClassVar

import numpy as np

from mttbench import Estimate, Policy, Tracker
from mttbench.trackers.params import Param, Search

#: the step at which :class:`Crash` raises (0-based, counted by ``predict``)
CRASH_STEP = 3
#: seconds :class:`Slow` sleeps per step
SLOW_STEP_S = 0.05
#: environment variable naming a gate file: while it is set and the file does not exist,
#: :class:`Slow` waits at its first step, so a sweep cannot finish before the test that
#: interrupts it has sent its signal (however slow the machine)
SLOW_GATE_ENV = "MTTBENCH_TEST_SLOW_GATE"
#: environment variable: the pid of the test process that opens the gate (:func:`gate_env`)
GATE_OWNER_ENV = "MTTBENCH_TEST_GATE_OWNER"
#: the longest a run waits for its gate when no owner is named
SLOW_GATE_TIMEOUT_S = 120.0


def gate_env(gate: Path) -> dict[str, str]:
    """The variables of a gate file that this process opens: a run waits for the file for
    as long as this process lives (no wall-clock limit that a loaded machine could reach
    before the test opens it; a test that dies leaves no run waiting)."""
    return {SLOW_GATE_ENV: str(gate), GATE_OWNER_ENV: str(os.getpid())}


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, dead but not reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return True
    return state not in ("Z", "X")


def wait_for_gate() -> None:
    """Wait while the gate of :data:`SLOW_GATE_ENV` is set and its file does not exist: as
    long as the owner (:data:`GATE_OWNER_ENV`) lives, else at most
    :data:`SLOW_GATE_TIMEOUT_S`."""
    gate = os.environ.get(SLOW_GATE_ENV)
    if not gate:
        return
    owner = int(os.environ.get(GATE_OWNER_ENV, "0") or 0)
    deadline = time.monotonic() + SLOW_GATE_TIMEOUT_S
    while not Path(gate).exists():
        if owner > 0 and not alive(owner):
            return
        if owner <= 0 and time.monotonic() >= deadline:
            return
        time.sleep(0.01)


class _Nothing(Tracker):
    """Reports no target; counts its steps."""

    def reset(self, model, rng):
        self._n_cells = model.grid.n_cells if model.is_grid else 1
        self._k = -1

    def predict(self):
        self._k += 1

    def cell_count_distribution(self):
        P = np.zeros((self._n_cells, 2))
        P[:, 0] = 1.0
        return P

    def update(self, looks):
        pass

    def estimate(self):
        return Estimate.empty()


class Crash(_Nothing):
    """Raises ``RuntimeError`` at step :data:`CRASH_STEP` of every run."""

    name = "crash"
    summary = "test tracker: raises at step 3"

    def predict(self):
        super().predict()
        if self._k == CRASH_STEP:
            raise RuntimeError(f"deliberate failure at step {self._k}")


class Slow(_Nothing):
    """Reports nothing, slowly: sleeps :data:`SLOW_STEP_S` per step (interrupt tests)."""

    name = "slow"
    summary = "test tracker: sleeps every step"

    def predict(self):
        super().predict()
        if self._k == 0:
            wait_for_gate()
        time.sleep(SLOW_STEP_S)


class FirstCells(Policy):
    """Looks at the first ``M`` cells every step (a policy named by class path)."""

    name = "first-cells"
    summary = "test policy: the first M cells"
    parameters: ClassVar[dict] = {}

    def select(self, k, counts=None, truth_cells=None):
        return np.arange(min(self._n_looks, self._n_cells), dtype=np.int64)


#: environment variable naming a log file: :class:`Counted` appends a line per run
COUNT_LOG_ENV = "MTTBENCH_TEST_COUNT_LOG"
#: environment variable: :class:`Counted` runs past this many lines in its log wait for
#: the gate file of :data:`SLOW_GATE_ENV` (the sweep is then killed by the test)
COUNT_LIMIT_ENV = "MTTBENCH_TEST_COUNT_LIMIT"


class Counted(_Nothing):
    """Reports nothing; logs each run it starts, and waits for the gate file once its
    log holds more than ``MTTBENCH_TEST_COUNT_LIMIT`` lines (how a test counts the runs
    a sweep really ran, and stops one at a known run)."""

    name = "counted"
    summary = "test tracker: logs its runs"

    def reset(self, model, rng):
        super().reset(model, rng)
        log = Path(os.environ[COUNT_LOG_ENV])
        with log.open("a") as f:
            f.write(f"{os.getpid()}\n")
        limit = int(os.environ.get(COUNT_LIMIT_ENV, "0") or 0)
        if limit and len(log.read_text().splitlines()) > limit:
            wait_for_gate()


class Guess(_Nothing):
    """Reports ``count`` targets standing at ``(x, x)`` cells, ``x = 10 level`` (+ 1 with
    ``shift="far"``): a run costs nothing and its OSPA moves with each of its searched
    parameters (a float, an int and a choice), so a tuner's trials tell apart."""

    name = "guess"
    summary = "test tracker: a fixed guess set by its parameters"
    parameters: ClassVar[dict[str, Param]] = {
        "level": Param(float, 0, 1, search=Search(0.0, 1.0)),
        "count": Param(int, 0, search=Search(0, 3)),
        "shift": Param(choices=("near", "far"), search=Search(choices=("near", "far"))),
    }

    def __init__(self, level: float = 0.5, count: int = 1, shift: str = "near") -> None:
        self.level, self.count, self.shift = level, count, shift

    def reset(self, model, rng):
        super().reset(model, rng)
        self._cell = model.grid.cell_size if model.is_grid else 1.0

    def estimate(self):
        x = (10.0 * self.level + (1.0 if self.shift == "far" else 0.0)) * self._cell
        states = np.tile([x, 0.0, x, 0.0], (self.count, 1)).astype(float)
        return Estimate(float(self.count), states)


def shell_like_signals() -> None:
    """``preexec_fn`` of a command a test interrupts: Ctrl-C as a shell's child gets it
    (default disposition, not blocked), whatever the test process has inherited from the
    tests that ran before it in the same worker."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})

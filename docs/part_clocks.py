"""CPU clocks around named functions, for the step-parts scripts of docs/speed.md
(``gpf_step_parts.py``, ``jmpd_ap_step_parts.py``): each wrapped function adds its CPU
time to its label, step by step, and the table lists each label's mean over the fastest
steps."""

from __future__ import annotations

import collections
import functools
import time
from collections.abc import Callable

import numpy as np


class PartClocks:
    """``wrap`` functions by name on their owner (a module, class or kernel module); then
    ``time_steps`` runs the steps and returns ``(CPU s, {label: CPU s})`` per step,
    fastest first."""

    def __init__(self) -> None:
        self.spent: collections.Counter = collections.Counter()

    def wrap(self, owner, name: str, label: str) -> None:
        f = getattr(owner, name)
        spent = self.spent

        @functools.wraps(f)
        def timed(*a, **k):
            t0 = time.process_time()
            try:
                return f(*a, **k)
            finally:
                spent[label] += time.process_time() - t0
        setattr(owner, name, timed)

    def time_steps(self, step: Callable[[], object], n: int,
                   setup: Callable[[], object] | None = None) -> list[tuple[float, dict]]:
        rows = []
        for _ in range(n):
            if setup is not None:
                setup()  # untimed
            self.spent.clear()
            t0 = time.process_time()
            step()
            rows.append((time.process_time() - t0, dict(self.spent)))
        return sorted(rows, key=lambda r: r[0])


def print_parts(best: list[tuple[float, dict]]) -> None:
    """Each label's mean CPU time over the steps ``best``, largest first."""
    parts = {k: np.mean([r[1].get(k, 0.0) for r in best]) for r in best for k in r[1]}
    for label, t in sorted(parts.items(), key=lambda kv: -kv[1]):
        print(f"{t * 1e3:9.3f} ms  {label}")

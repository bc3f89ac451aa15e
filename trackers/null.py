"""The "report nothing" baseline: zero targets, always.

Every accuracy table should beat it; its OSPA is the cut-off ``c`` whenever a
target exists. Its ``P_c(t)`` puts every target prior in no cell: every cell has the
one default row ``(1, 0)`` (a :class:`~trackers.cells.CellCounts` without rows of its
own, ``O(1)`` whatever the grid).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..scenarios.model import Looks, TrackingModel
from .base import Estimate, Tracker, register
from .cells import CellCounts
from .params import Param


@register
class NullTracker(Tracker):
    name = "null"
    summary = "baseline that always reports zero targets"
    baseline = True
    parameters: ClassVar[dict[str, Param]] = {}

    def __init__(self) -> None:
        pass

    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        self._n_cells = model.grid.n_cells

    def predict(self) -> None:
        pass

    def cell_count_distribution(self) -> CellCounts:
        return CellCounts(self._n_cells, np.zeros(0, dtype=np.int64), np.zeros((0, 2)),
                          np.array([1.0, 0.0]))

    def update(self, looks: Looks) -> None:
        pass

    def estimate(self) -> Estimate:
        return Estimate.empty()

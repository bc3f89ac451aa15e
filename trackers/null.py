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
from .base import Estimate, ResourceTerms, Tracker, register
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

    @classmethod
    def resource_terms(cls, params, model, looks_per_step, targets) -> ResourceTerms:
        """Nothing of its own; a ``P_c(t)`` of one default row of 2 count columns."""
        return ResourceTerms(prediction_entries=0.0, prediction_counts=2.0)

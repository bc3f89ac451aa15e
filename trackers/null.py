"""The "report nothing" baseline: zero targets, always.

Every accuracy table should beat it; its OSPA is the cut-off ``c`` whenever a
target exists. Its ``P_c(t)`` puts every target prior in no cell.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..scenarios.model import Looks, TrackingModel
from .base import Estimate, Tracker, register
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

    def cell_count_distribution(self) -> np.ndarray:
        P = np.zeros((self._n_cells, 2))
        P[:, 0] = 1.0
        return P

    def update(self, looks: Looks) -> None:
        pass

    def estimate(self) -> Estimate:
        return Estimate.empty()

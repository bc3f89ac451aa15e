"""Cell-selection policies: which cells the grid sensor looks at each step.

One small interface. The harness calls, every step after the tracker's predict::

    cells = policy.select(k, counts=P, truth_cells=None)   # (M,) int64, repeats allowed

``counts`` is the tracker's predicted ``P_c(t)`` (``(n_cells, n_counts)``), passed
only to policies with ``uses_prediction = True`` so other policies never pay for
it; ``truth_cells`` (flat cells of the true targets) only to policies with
``uses_truth = True`` (the oracle), which are marked as such in every result.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np

from ..scenarios.model import TrackingModel


class Policy(ABC):
    """Chooses the looks of each step. Constructors store parameters only."""

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    uses_prediction: ClassVar[bool] = False
    uses_truth: ClassVar[bool] = False

    def get_params(self) -> dict[str, Any]:
        """Constructor parameters (public attributes)."""
        return {k: v for k, v in vars(self).items() if not k.startswith("_")}

    def reset(self, model: TrackingModel, n_looks: int, rng: np.random.Generator) -> None:
        """Start a run: ``n_looks`` looks per step on ``model.grid``."""
        self._n_cells = model.grid.n_cells
        self._n_looks = int(n_looks)
        self._model = model
        self._rng = rng

    @abstractmethod
    def select(self, k: int, counts: np.ndarray | None = None,
               truth_cells: np.ndarray | None = None) -> np.ndarray:
        """Flat cell indices ``(n,)`` int64 to look at during step ``k``."""


_POLICIES: dict[str, type[Policy]] = {}


def register_policy(cls: type[Policy]) -> type[Policy]:
    if not cls.name or cls.name in _POLICIES:
        raise ValueError(f"policy name {cls.name!r} is empty or already registered")
    _POLICIES[cls.name] = cls
    return cls


def available_policies() -> list[str]:
    return sorted(_POLICIES)


def make_policy(name: str, **params: Any) -> Policy:
    try:
        cls = _POLICIES[name]
    except KeyError:
        raise KeyError(f"unknown policy {name!r}: policies are {available_policies()}") from None
    return cls(**params)


@register_policy
class AllCells(Policy):
    """Every cell once per step (ignores the look budget): the best a sensor can do."""

    name = "all"
    summary = "look at every cell once per step (ignores the look budget)"

    def select(self, k, counts=None, truth_cells=None):
        return np.arange(self._n_cells, dtype=np.int64)


@register_policy
class RandomCells(Policy):
    """``M`` distinct cells drawn uniformly each step (the policy's own generator)."""

    name = "random"
    summary = "M distinct cells drawn uniformly at random each step"

    def select(self, k, counts=None, truth_cells=None):
        m = min(self._n_looks, self._n_cells)
        return np.sort(self._rng.choice(self._n_cells, size=m, replace=False)).astype(np.int64)


@register_policy
class Raster(Policy):
    """A sweep: step ``k`` looks at cells ``kM, ..., kM + M - 1`` (mod ``n_cells``)."""

    name = "raster"
    summary = "raster sweep: M consecutive cells per step, wrapping around the grid"

    def select(self, k, counts=None, truth_cells=None):
        m = min(self._n_looks, self._n_cells)
        return ((k * m + np.arange(m)) % self._n_cells).astype(np.int64)


@register_policy
class Oracle(Policy):
    """REFERENCE ONLY -- USES THE TRUTH. Looks at the cells holding true targets first.

    Each step: the distinct cells of the true targets (``truth_cells``, flat indices;
    ``-1`` = outside the grid, ignored), in random order if there are more than ``M``,
    then distinct other cells drawn uniformly to fill the ``M`` looks. The harness
    passes ``truth_cells`` only to policies with ``uses_truth = True`` and marks
    their results; a tracker never sees the truth, only the looks this policy made.
    """

    name = "oracle"
    summary = "REFERENCE, USES THE TRUTH: cells of the true targets, then random cells"
    uses_truth = True

    def select(self, k, counts=None, truth_cells=None):
        if truth_cells is None:
            raise ValueError("the oracle policy needs the true targets' cells")
        m = min(self._n_looks, self._n_cells)
        truth = np.unique(np.asarray(truth_cells, dtype=np.int64))
        truth = truth[(truth >= 0) & (truth < self._n_cells)]
        if truth.size >= m:
            return np.sort(self._rng.choice(truth, size=m, replace=False)).astype(np.int64)
        others = np.setdiff1d(np.arange(self._n_cells), truth, assume_unique=True)
        fill = self._rng.choice(others, size=m - truth.size, replace=False)
        return np.sort(np.concatenate([truth, fill])).astype(np.int64)


# The information-driven policy lives in its own module, which imports this one for
# the registry; importing it here (after the registry exists) registers "renyi"
# whenever the policies are imported, without a circular-import failure.
from . import information  # noqa: E402, F401

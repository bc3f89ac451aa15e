"""Per-step series of the track-level scores: one value per step, known once the run ends.

A run-level (track) score of :mod:`~mttbench.benchmarks.engine.metrics` is one number per
run, written on every row of the run. Some of them have a natural value per step that
only the whole run defines: the OSPA(2) of the window ending at step ``k`` (a track's
identity is judged over the window), the identity switches that happen at step ``k``
(a switch is relative to the earlier matches). A :class:`RunSeries` declares such a
series in the run-level registry (:func:`~mttbench.benchmarks.engine.metrics.
register_run_metric`): its ``series(run, **params)`` returns ``{column: (T,) array}``
and :func:`~mttbench.benchmarks.engine.loop.run_job` writes ``array[k]`` on the row of
step ``k`` (the registry's own ``fn`` gives the run's mean over steps, so every
consumer of run-level values still gets one float per column). Summaries read these
columns per step (:mod:`~mttbench.benchmarks.app.summary` keeps them out of the
per-run tables: their run values are the run-level scores already there).

The shipped series, registered at import, in this order after the built-in run-level
metrics (their columns follow those in the results table):

* ``ospa2_window``: OSPA(2) of the window of ``window`` steps ending at ``k``
  (:func:`~mttbench.benchmarks.engine.track_metrics.ospa2`'s ``per_step``; its mean over
  the run is the ``ospa2`` column);
* ``id_switches_step``: CLEAR-MOT identity switches at step ``k`` within the gate (its
  sum over the run is the ``id_switches`` column);
* ``crossings`` (+ ``crossings_near``): from the truth alone (``needs_labels=False``),
  the close encounters of two true targets that begin at ``k`` and whether ``k`` is
  within ``window`` steps of a step where two targets are closer than ``distance``
  (:func:`~mttbench.benchmarks.engine.track_metrics.crossings`); the report sums
  ``id_switches_step`` over the ``crossings_near`` steps and over the others.

A tracker without labels gets NaN in the series that need labels, as in the run-level
scores.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from . import metrics, track_metrics
from .metrics import (
    RunData,
    RunMetric,
    ospa2_of,
    register_run_metric,
    registered_run_metrics,
)

__all__ = [
    "CROSSING_DISTANCE",
    "CROSSING_WINDOW",
    "SERIES_METRICS",
    "RunSeries",
    "series_columns",
    "series_values",
]

#: ``series(run: RunData, **params) -> {column: (T,) array}``
SeriesFunction = Callable[..., dict]


@dataclass(frozen=True)
class RunSeries(RunMetric):
    """A run-level metric with one value per step (see the module docstring).

    ``series(run, **params)`` returns ``{column: (T,) float array}`` for exactly
    ``columns``, ``T = len(run.truth)``; it is computed once per run (kept in
    ``run.cache``). ``fn`` is set here: the run's NaN-aware mean over steps of each
    column, the value the run-level registry asks for."""

    fn: Callable | None = field(default=None, compare=False, repr=False)
    series: SeriesFunction | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if not callable(self.series):
            raise TypeError(f"series metric {self.name!r}: series {self.series!r} is not "
                            "callable")
        object.__setattr__(self, "fn", self._run_means)
        super().__post_init__()

    def values(self, run: RunData) -> dict[str, np.ndarray]:
        """``{column: (T,) float64}`` of ``run`` (computed once, then from ``run.cache``);
        ``ValueError`` when ``series`` returns other columns or lengths."""
        key = ("series", self.name)
        if key not in run.cache:
            out = self.series(run, **self.params)
            if set(out) != set(self.columns):
                raise ValueError(f"series metric {self.name!r} returned the columns "
                                 f"{sorted(out)}, not its declared {list(self.columns)}")
            T = len(run.truth)
            arrays = {c: np.asarray(out[c], dtype=np.float64).reshape(-1)
                      for c in self.columns}
            bad = [c for c, v in arrays.items() if len(v) != T]
            if bad:
                raise ValueError(f"series metric {self.name!r}: column {bad[0]!r} has "
                                 f"{len(arrays[bad[0]])} values for {T} steps")
            run.cache[key] = arrays
        return run.cache[key]

    def _run_means(self, run: RunData, **params: float) -> dict[str, float]:
        out = {}
        for c, v in self.values(run).items():
            v = v[~np.isnan(v)]
            out[c] = float(v.mean()) if v.size else math.nan
        return out


def series_values(run: RunData) -> dict[str, np.ndarray]:
    """``{column: (T,) float64}`` of every registered :class:`RunSeries` for one finished
    run; NaN throughout for the series that need labels when ``run.labels`` is None."""
    out: dict[str, np.ndarray] = {}
    for m in registered_run_metrics():
        if not isinstance(m, RunSeries):
            continue
        if m.needs_labels and run.labels is None:
            out.update((c, np.full(len(run.truth), np.nan)) for c in m.columns)
        else:
            out.update(m.values(run))
    return out


def series_columns() -> list[str]:
    """Columns of the registered :class:`RunSeries` (per step), in registration order."""
    return [c for m in registered_run_metrics() if isinstance(m, RunSeries)
            for c in m.columns]


def _ospa2_window(run: RunData, window: float) -> dict[str, np.ndarray]:
    return {"ospa2_window": ospa2_of(run, window).per_step}


def _switch_steps(run: RunData, gate: float) -> dict[str, np.ndarray]:
    # the CLEAR-MOT matching of the run-level id_switches (shared through run.cache)
    return {"id_switches_step": metrics._clear_mot(run, gate).switch_steps}


def _crossings(run: RunData, distance: float, window: float) -> dict[str, np.ndarray]:
    cr = track_metrics.crossings(run.truth, run.truth_ids, distance=distance,
                                 window=int(window))
    return {"crossings": cr.starts, "crossings_near": cr.near}


#: two true targets closer than this (workspace units) are crossing: the CLEAR-MOT gate
CROSSING_DISTANCE = metrics.CLEAR_MOT_GATE
#: steps on either side of a close step that count as "around the crossing"
CROSSING_WINDOW = 5

#: the shipped per-step series, in their order in the results table
SERIES_METRICS: tuple[str, ...] = tuple(register_run_metric(m).name for m in (
    RunSeries("ospa2_window", label="OSPA(2) over time", series=_ospa2_window,
              params={"window": metrics.OSPA2_WINDOW}),
    RunSeries("id_switches_step", label="ID switches at the step", fmt=".2f",
              series=_switch_steps, params={"gate": metrics.CLEAR_MOT_GATE}),
    RunSeries("crossings", columns=("crossings", "crossings_near"), label="crossings",
              fmt=".2f", series=_crossings, needs_labels=False,
              params={"distance": CROSSING_DISTANCE, "window": CROSSING_WINDOW}),
))

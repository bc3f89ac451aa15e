"""Accuracy metrics between the true and the estimated target positions of one step.

All functions take two finite sets of POSITIONS in workspace units::

    truth     (n, 2)   rows (px, py) of the true targets      (callers pass state[:, [0, 2]])
    estimate  (m, 2)   rows (px, py) of the estimated targets

An empty set may be given as shape ``(0,)`` or ``(0, 2)``. Distances are Euclidean,
``d(x, y) = ||x - y||_2``, and ``d_c(x, y) = min(d(x, y), c)`` is the distance cut at ``c``.

Optimal assignments are found with :func:`scipy.optimize.linear_sum_assignment`. The
cut-off and the power are applied to the cost matrix BEFORE assigning (cost ``d_c^p``):
the permutation that minimises ``sum d`` is in general not the one that minimises
``sum d_c^p``, so assigning on raw distances would overstate OSPA/GOSPA.

Metrics are computed outside the timed tracker calls; they are not on the hot path.

**The metric registry.** Every per-step metric of the suite is one :class:`Metric`
declaration passed to :func:`register_metric`: its function, the columns it writes (the
first, named like the metric, is its headline), its label in tables, whether lower is
better, whether it may be a tuning objective and whether the ranking tables show it.
:func:`step_metrics` (so the results table of :func:`~mttbench.benchmarks.engine.loop.
run_job`), the summaries and the report (:mod:`~mttbench.benchmarks.app.summary`,
:mod:`~mttbench.benchmarks.app.report`) and ``mttbench tune --objective`` read it. The
built-ins, in their order in the results table: ``count_error``, ``ospa`` (+ ``_loc``,
``_card``), ``gospa`` (+ ``_loc``, ``_missed``, ``_false``), ``rmse``; a metric
registered later adds its columns after them (in the results table, after the
``param_<name>`` columns). Tables show the metrics in :func:`display_metrics` order.

**Run-level metrics.** A :class:`RunMetric` (:func:`register_run_metric`) scores a whole
run once it has finished: its function takes a :class:`RunData` (per step the true
positions and ids, the estimated positions and the tracker's labels) and its declared
``params``. The built-ins are the track-level scores of
:mod:`~mttbench.benchmarks.engine.track_metrics` (``tgospa``, ``ospa2``, ``id_switches``,
``fragmentations``, ``mostly_tracked``, ``mostly_lost``); a tracker without labels gets
NaN. :func:`~mttbench.benchmarks.engine.loop.run_job` writes their columns on every row
of the run (after the ``param_<name>`` columns, before the columns of per-step metrics
registered later).

The registry is module state of each process. A sweep's forked worker processes inherit
the metrics registered before the sweep started; processes that are not forked (Dask
workers, spawned processes) only know the metrics registered when they import their
modules, so a metric meant for them is registered at import of a module they import
(as trackers are, through their package's entry points).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from . import track_metrics

__all__ = [
    "BUILTIN_METRICS",
    "BUILTIN_RUN_METRICS",
    "GOSPA",
    "OSPA",
    "STEP_COUNTS",
    "Metric",
    "RunData",
    "RunMetric",
    "assigned_rmse",
    "builtin_run_columns",
    "column_label",
    "count_error",
    "display_metrics",
    "get_metric",
    "gospa",
    "metric_columns",
    "metric_names",
    "objective_names",
    "ospa",
    "register_metric",
    "register_run_metric",
    "registered_metrics",
    "registered_run_metrics",
    "run_level_metrics",
    "run_metric_columns",
    "run_metric_params",
    "step_metrics",
    "unregister_metric",
    "unregister_run_metric",
]


@dataclass(frozen=True)
class OSPA:
    """OSPA distance and its two parts (same units as the positions).

    ``total ** p == localisation ** p + cardinality ** p``.
    """

    total: float
    localisation: float
    cardinality: float


@dataclass(frozen=True)
class GOSPA:
    """GOSPA distance (alpha = 2) and its parts.

    ``total`` is in position units; ``localisation``, ``missed`` and ``false`` are COSTS in
    the p-th-power domain (units ** p), so ``localisation + missed + false == total ** p``.
    ``missed`` and ``false`` are ``c**p / 2`` times the number of missed true targets and of
    false estimates, not the counts themselves.
    """

    total: float
    localisation: float
    missed: float
    false: float


def _as_positions(points: np.ndarray, name: str) -> np.ndarray:
    """``(k, 2)`` float64 array of positions; accepts ``(0,)`` for the empty set."""
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim == 1 and arr.size == 0:
        return arr.reshape(0, 2)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (k, 2) of positions (px, py), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite positions")
    return arr


#: the default OSPA/GOSPA cut-off, in cells: ``c = CUTOFF_CELLS * cell_size`` world units
#: (a miss costs as much as an estimate two cells off, on any grid)
CUTOFF_CELLS = 2.0


def cutoff(c: float | None, cell_size: float) -> float:
    """The cut-off in world units: ``c`` as given, or :data:`CUTOFF_CELLS` cells of
    ``cell_size`` when ``c`` is None."""
    return CUTOFF_CELLS * float(cell_size) if c is None else float(c)


def describe_cutoff(c: float, cell_size: float) -> str:
    """``c`` with its units: ``"2 (2 cells of 1)"``, ``"100 (2 cells of 50)"``."""
    return f"{c:g} ({c / cell_size:g} cells of {cell_size:g})"


def _check_order_cutoff(c: float, p: float) -> None:
    if not (np.isfinite(c) and c > 0):
        raise ValueError(f"cut-off c must be positive and finite, got {c}")
    if not (np.isfinite(p) and p >= 1):
        raise ValueError(f"order p must be >= 1 (metric) and finite, got {p}")


def _cut_cost_assignment(
    truth: np.ndarray, estimate: np.ndarray, c: float, p: float
) -> tuple[np.ndarray, np.ndarray]:
    """Optimal assignment of ``min(n, m)`` pairs on the cost ``d_c^p``.

    Returns ``(distances (k,), costs (k,))`` of the assigned pairs, ``k = min(n, m)``:
    raw distances ``d`` and cut costs ``min(d, c) ** p``.
    """
    d = cdist(truth, estimate)  # (n, m)
    cost = np.minimum(d, c) ** p
    rows, cols = linear_sum_assignment(cost)
    return d[rows, cols], cost[rows, cols]


def ospa(truth: np.ndarray, estimate: np.ndarray, c: float = 2.0, p: float = 2.0) -> OSPA:
    """OSPA metric of order ``p`` with cut-off ``c`` (Schuhmacher, Vo & Vo, 2008).

    With ``X = truth`` (n points), ``Y = estimate`` (m points) and, without loss of
    generality, ``n <= m`` (the metric is symmetric; the smaller set is permuted into
    the larger one)::

        d_c(x, y) = min(||x - y||, c)
        D         = min over injections pi of sum_{i=1..n} d_c(x_i, y_pi(i)) ** p
        OSPA      = ( (D + c**p * (m - n)) / m ) ** (1/p)
        loc       = ( D / m ) ** (1/p)
        card      = ( c**p * (m - n) / m ) ** (1/p)

    so ``OSPA**p = loc**p + card**p`` and ``0 <= OSPA <= c``. Both sets empty gives 0
    (all parts 0); exactly one empty gives ``OSPA = card = c``, ``loc = 0``.

    Args:
        truth: ``(n, 2)`` true positions.
        estimate: ``(m, 2)`` estimated positions.
        c: cut-off distance (> 0), position units.
        p: order (>= 1).
    """
    _check_order_cutoff(c, p)
    x = _as_positions(truth, "truth")
    y = _as_positions(estimate, "estimate")
    if len(x) > len(y):
        x, y = y, x
    n, m = len(x), len(y)
    if m == 0:
        return OSPA(0.0, 0.0, 0.0)
    _, costs = _cut_cost_assignment(x, y, c, p)
    loc_p = float(costs.sum()) / m
    card_p = c**p * (m - n) / m
    return OSPA(
        total=(loc_p + card_p) ** (1.0 / p),
        localisation=loc_p ** (1.0 / p),
        cardinality=card_p ** (1.0 / p),
    )


def gospa(
    truth: np.ndarray,
    estimate: np.ndarray,
    c: float = 2.0,
    p: float = 2.0,
    alpha: float = 2.0,
) -> GOSPA:
    """GOSPA metric with ``alpha = 2`` (Rahmathullah, Garcia-Fernandez & Svensson, 2017).

    With ``X = truth`` (n points), ``Y = estimate`` (m points) and ``gamma`` ranging over
    partial assignments (sets of disjoint pairs ``(i, j)``)::

        GOSPA = ( min_gamma [ sum_{(i,j) in gamma} d(x_i, y_j) ** p
                              + c**p / 2 * (#missed + #false) ] ) ** (1/p)
        #missed = n - |gamma|,   #false = m - |gamma|

    Leaving a pair unassigned costs ``c**p / 2 + c**p / 2 = c**p``, so only pairs with
    ``d < c`` are worth assigning and the minimum equals an ordinary assignment of
    ``min(n, m)`` pairs on the cost ``min(d, c) ** p`` plus ``c**p / 2 * |n - m|``; we
    solve that and then count an assigned pair with ``d >= c`` as one missed and one
    false target (at ``d == c`` both readings give the same total).

    Parts, in the p-th-power domain so that ``localisation + missed + false == total**p``::

        localisation = sum over assigned pairs with d < c of d ** p
        missed       = c**p / 2 * #missed
        false        = c**p / 2 * #false

    Both sets empty gives all zeros. Only ``alpha = 2`` is supported: it is the value for
    which the distance splits into localisation, missed and false costs.

    Args:
        truth: ``(n, 2)`` true positions.
        estimate: ``(m, 2)`` estimated positions.
        c: cut-off distance (> 0), position units.
        p: order (>= 1).
        alpha: must be 2.
    """
    _check_order_cutoff(c, p)
    if alpha != 2:
        raise ValueError(f"only alpha = 2 is supported (missed/false split), got {alpha}")
    x = _as_positions(truth, "truth")
    y = _as_positions(estimate, "estimate")
    n, m = len(x), len(y)
    if n == 0 or m == 0:
        n_assigned = 0
        loc = 0.0
    else:
        d, _ = _cut_cost_assignment(x, y, c, p)
        kept = d < c
        n_assigned = int(kept.sum())
        loc = float(np.sum(d[kept] ** p))
    missed = c**p / 2 * (n - n_assigned)
    false = c**p / 2 * (m - n_assigned)
    return GOSPA(
        total=(loc + missed + false) ** (1.0 / p),
        localisation=loc,
        missed=missed,
        false=false,
    )


def assigned_rmse(truth: np.ndarray, estimate: np.ndarray) -> float:
    """Root-mean-square position error over the optimal assignment.

    The ``k = min(n, m)`` pairs minimise the total squared distance (no cut-off)::

        RMSE = sqrt( (1/k) * min over injections pi of sum_i ||x_i - y_pi(i)||**2 )

    Unassigned points are ignored (cardinality errors are in OSPA/GOSPA and the count
    error). Returns ``nan`` when either set is empty. Position units.
    """
    x = _as_positions(truth, "truth")
    y = _as_positions(estimate, "estimate")
    if len(x) == 0 or len(y) == 0:
        return float("nan")
    sq = cdist(x, y, "sqeuclidean")
    rows, cols = linear_sum_assignment(sq)
    return float(np.sqrt(np.mean(sq[rows, cols])))


def count_error(estimated_count: float, true_count: int) -> float:
    """Absolute error of the estimated number of targets, ``|estimated - true|``."""
    return float(abs(float(estimated_count) - float(true_count)))


# ------------------------------------------------------------------------ registry
#: ``fn(truth (n, 2), estimate (m, 2), estimated_count, c, p) -> {column: value}``
MetricFunction = Callable[[np.ndarray, np.ndarray, float, float, float], Mapping[str, float]]

#: keys :func:`step_metrics` adds after the metrics' columns (the step's two counts);
#: no metric may write them
STEP_COUNTS = ("true_count", "n_estimated")


@dataclass(frozen=True)
class Metric:
    """One per-step metric, declared once and registered with :func:`register_metric`.

    ``fn(truth, estimate, estimated_count, c, p)`` gets the step's true and estimated
    positions as ``(n, 2)`` and ``(m, 2)`` float arrays (checked finite), the tracker's
    count estimate and the cut-off ``c`` and order ``p`` of the run, and returns
    ``{column: value}`` for exactly ``columns``. ``columns`` defaults to ``(name,)``; the
    first, the headline, must be ``name`` (the name is the column that objectives,
    rankings and paired differences read). ``label`` names the headline in tables
    (default ``name``); a column ``<name>_<part>`` is labelled ``"<label> <part>"``.
    ``lower_is_better`` orients rankings; ``objective`` lets ``mttbench tune`` minimise
    the headline (so it needs ``lower_is_better``); ``ranked`` puts it in the report's
    paired differences and baseline checks; tables show ``value * scale`` formatted
    with ``fmt``.
    """

    name: str
    fn: MetricFunction
    columns: tuple[str, ...] = ()
    label: str = ""
    lower_is_better: bool = True
    objective: bool = False
    ranked: bool = False
    scale: float = 1.0
    fmt: str = ".3f"

    def __post_init__(self) -> None:
        columns = (self.columns,) if isinstance(self.columns, str) else tuple(self.columns)
        object.__setattr__(self, "columns", columns or (self.name,))
        object.__setattr__(self, "label", self.label or self.name)
        if not (isinstance(self.name, str) and self.name.isidentifier()):
            raise ValueError(f"a metric name must be an identifier, got {self.name!r}")
        if not callable(self.fn):
            raise TypeError(f"metric {self.name!r}: fn {self.fn!r} is not callable")
        bad = [c for c in self.columns if not (isinstance(c, str) and c.isidentifier())]
        if bad or len(set(self.columns)) != len(self.columns):
            raise ValueError(f"metric {self.name!r}: columns {self.columns} must be distinct "
                             "identifiers")
        if self.columns[0] != self.name:
            raise ValueError(f"metric {self.name!r}: the first column (the headline) must be "
                             f"{self.name!r}, got {self.columns[0]!r}")
        if self.objective and not self.lower_is_better:
            raise ValueError(f"metric {self.name!r}: a tuning objective is minimised, so it "
                             "must be lower_is_better (declare the negated quantity)")

    def column_label(self, column: str) -> str:
        """Table label of one of :attr:`columns` (``ospa_loc`` -> ``OSPA loc``)."""
        if column == self.name:
            return self.label
        return f"{self.label} {column.removeprefix(self.name + '_')}"


@dataclass(frozen=True)
class RunData:
    """One whole run, as the run-level metrics read it: per step ``k`` the true positions
    ``truth[k] (n_k, 2)`` and ids ``truth_ids[k] (n_k,)`` (the simulator's), the estimated
    positions ``estimate[k] (m_k, 2)`` and the tracker's labels ``labels[k] (m_k,)`` (None
    when the tracker gives no labels), and the run's cut-off ``c`` and order ``p``."""

    truth: Sequence[np.ndarray]
    truth_ids: Sequence[np.ndarray]
    estimate: Sequence[np.ndarray]
    labels: Sequence[np.ndarray] | None
    c: float = 2.0
    p: float = 2.0
    #: results shared by several metrics of the same run (e.g. the CLEAR-MOT matching)
    cache: dict = field(default_factory=dict, compare=False, repr=False)


#: ``fn(run: RunData, **params) -> {column: value}``
RunMetricFunction = Callable[..., Mapping[str, float]]


@dataclass(frozen=True)
class RunMetric(Metric):
    """One run-level metric (a track-level score), registered with
    :func:`register_run_metric`: like :class:`Metric` (columns, label, orientation,
    ``objective``, display), but ``fn(run, **params)`` takes the whole run
    (:class:`RunData`) once at its end and returns ``{column: value}``; the values are
    written to every row of the run (constant over the run), so per-run summaries read
    them as they are. ``params`` are the metric's own parameters (a switching cost, a
    window, a gate), passed to ``fn`` and recorded in ``compare``'s manifest.
    ``needs_labels``: a run whose tracker gives no labels gets NaN (no identity to
    score)."""

    params: Mapping[str, float] = field(default_factory=dict)
    needs_labels: bool = True


_REGISTRY: dict[str, Metric] = {}
_RUN_REGISTRY: dict[str, RunMetric] = {}


def register_metric(metric: Metric) -> Metric:
    """Add ``metric`` after the registered ones; returns it. A name or a column already
    taken is refused (registering the same object again does nothing)."""
    if not isinstance(metric, Metric) or isinstance(metric, RunMetric):
        raise TypeError(f"{metric!r} is not a per-step Metric (a RunMetric goes to "
                        "register_run_metric)")
    return _add(_REGISTRY, metric)


def _add(registry: dict, metric: Metric) -> Metric:
    """Put ``metric`` into ``registry`` (the per-step or the run-level one) unless its
    name or one of its columns is taken by a metric of either kind."""
    if registry.get(metric.name) is metric:
        return metric
    if metric.name in _REGISTRY or metric.name in _RUN_REGISTRY:
        raise ValueError(f"metric name {metric.name!r} is already registered")
    owner = {c: m.name for m in (*_REGISTRY.values(), *_RUN_REGISTRY.values())
             for c in m.columns}
    owner.update(dict.fromkeys(STEP_COUNTS, "step_metrics"))
    taken = [f"{c!r} (of {owner[c]})" for c in metric.columns if c in owner]
    if taken:
        raise ValueError(f"metric {metric.name!r}: column {', '.join(taken)} is already "
                         "written")
    registry[metric.name] = metric
    return metric


def unregister_metric(name: str) -> None:
    """Remove the metric ``name`` (for tests that register temporary ones); the
    built-ins stay."""
    if name in BUILTIN_METRICS:
        raise ValueError(f"the built-in metric {name!r} cannot be unregistered")
    _REGISTRY.pop(name, None)


def get_metric(name: str) -> Metric:
    """The metric registered as ``name``; ``KeyError`` naming the known ones otherwise."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown metric {name!r}: the metrics are {metric_names()}") from None


def registered_metrics() -> tuple[Metric, ...]:
    """The registered metrics in registration order (their columns' order in the results
    table)."""
    return tuple(_REGISTRY.values())


def display_metrics() -> tuple[Metric, ...]:
    """The registered metrics in table order: the tuning objectives first (the headline
    accuracy metrics), then the others, each in registration order."""
    ms = registered_metrics()
    return tuple(m for m in ms if m.objective) + tuple(m for m in ms if not m.objective)


def metric_names() -> list[str]:
    """Names of the registered metrics, in registration order."""
    return list(_REGISTRY)


def objective_names() -> list[str]:
    """Names of the metrics ``mttbench tune`` may minimise (``objective=True``): the
    per-step ones, then the run-level ones."""
    return [m.name for m in (*_REGISTRY.values(), *_RUN_REGISTRY.values()) if m.objective]


def metric_columns(names: Iterable[str] | None = None, *, display: bool = False) -> list[str]:
    """Columns of the metrics ``names`` (default: all registered), in registration order
    (``display``: in :func:`display_metrics` order)."""
    ms = display_metrics() if display else registered_metrics()
    if names is not None:
        wanted = set(names)
        ms = tuple(m for m in ms if m.name in wanted)
    return [c for m in ms for c in m.columns]


def column_label(column: str) -> str:
    """Table label of a registered metric column (``gospa_missed`` -> ``GOSPA missed``);
    any other column as it is (run-level metrics' columns included)."""
    for m in (*_REGISTRY.values(), *_RUN_REGISTRY.values()):
        if column in m.columns:
            return m.column_label(column)
    return column


def _count_error_columns(truth: np.ndarray, estimate: np.ndarray, estimated_count: float,
                         c: float, p: float) -> dict[str, float]:
    # the states the tracker reports: what OSPA and GOSPA score, and what a user sees
    return {"count_error": count_error(len(estimate), len(truth))}


def _own_count_error_columns(truth: np.ndarray, estimate: np.ndarray,
                             estimated_count: float, c: float, p: float) -> dict[str, float]:
    # the tracker's own count (a weight sum may differ from the states it reports)
    return {"own_count_error": count_error(estimated_count, len(truth))}


def _ospa_columns(truth: np.ndarray, estimate: np.ndarray, estimated_count: float,
                  c: float, p: float) -> dict[str, float]:
    o = ospa(truth, estimate, c=c, p=p)
    return {"ospa": o.total, "ospa_loc": o.localisation, "ospa_card": o.cardinality}


def _gospa_columns(truth: np.ndarray, estimate: np.ndarray, estimated_count: float,
                   c: float, p: float) -> dict[str, float]:
    g = gospa(truth, estimate, c=c, p=p, alpha=2.0)
    return {"gospa": g.total, "gospa_loc": g.localisation, "gospa_missed": g.missed,
            "gospa_false": g.false}


def _rmse_columns(truth: np.ndarray, estimate: np.ndarray, estimated_count: float,
                  c: float, p: float) -> dict[str, float]:
    return {"rmse": assigned_rmse(truth, estimate)}


#: the shipped metrics, in their order in the results table
BUILTIN_METRICS: tuple[str, ...] = tuple(register_metric(m).name for m in (
    Metric("count_error", _count_error_columns, label="count error", ranked=True),
    Metric("ospa", _ospa_columns, ("ospa", "ospa_loc", "ospa_card"), "OSPA",
           objective=True, ranked=True),
    Metric("gospa", _gospa_columns, ("gospa", "gospa_loc", "gospa_missed", "gospa_false"),
           "GOSPA", objective=True, ranked=True),
    Metric("rmse", _rmse_columns, label="RMSE"),
    Metric("own_count_error", _own_count_error_columns, label="own count error"),
))


def _builtin_step_columns(x: np.ndarray, y: np.ndarray, estimated_count: float, c: float,
                          p: float) -> dict[str, float]:
    """The columns of the built-in per-step metrics of one step (:func:`builtin_run_columns`
    of a one-step run), as floats."""
    cols = builtin_run_columns([x], [y], [estimated_count], c, p)
    return {name: float(v[0]) for name, v in cols.items()}


def builtin_run_columns(truth: Sequence[np.ndarray], estimate: Sequence[np.ndarray],
                        estimated_count: Sequence[float], c: float = 2.0, p: float = 2.0
                        ) -> dict[str, np.ndarray]:
    """The built-in per-step metrics' columns of a whole run at once: ``{column: (T,)
    float64}`` with, at ``k``, exactly the number :func:`step_metrics` gives for
    ``truth[k] (n_k, 2)``, ``estimate[k] (m_k, 2)`` and ``estimated_count[k]``
    (positions already checked: finite, two columns).

    The numbers of :func:`count_error`, :func:`ospa`, :func:`gospa` and
    :func:`assigned_rmse`, with the work they would repeat done once:

    * the distances of every step come from one vectorised pass over all the run's
      ``sum_k n_k m_k`` pairs, ``d = sqrt(dx*dx + dy*dy)`` and ``d**2 = dx*dx + dy*dy``,
      the floating-point operations of ``cdist``'s ``euclidean`` and ``sqeuclidean``
      (tests/test_metrics.py checks them equal);
    * OSPA and GOSPA minimise the same cost ``min(d, c) ** p``, so one assignment
      (``linear_sum_assignment`` on the truth x estimate matrix) serves both; OSPA's sum
      runs over the pairs in the order of the smaller set, as :func:`ospa` takes it (the
      estimates' order when ``n > m``);
    * with one point on a side (``min(n, m) == 1``) the assignment is the cheapest pair,
      ``argmin`` (any cheapest pair gives the same numbers);
    * RMSE assigns on the squared distances, as :func:`assigned_rmse`.
    """
    _check_order_cutoff(c, p)
    T = len(truth)
    n = np.fromiter((len(x) for x in truth), np.int64, T)
    m = np.fromiter((len(y) for y in estimate), np.int64, T)
    counts = np.asarray(estimated_count, dtype=np.float64)
    names = ("ospa", "ospa_loc", "ospa_card", "gospa", "gospa_loc", "gospa_missed",
             "gospa_false", "rmse")
    out = {name: np.empty(T) for name in names}
    out["count_error"] = np.abs(m.astype(np.float64) - n.astype(np.float64))
    out["own_count_error"] = np.abs(counts - n.astype(np.float64))
    cp = c**p
    # every step's pairs (i, j), truth-major, in one flat array
    nm = n * m
    start = np.concatenate([[0], np.cumsum(nm)])
    if start[-1]:
        X = np.concatenate([np.asarray(x, dtype=np.float64).reshape(-1, 2) for x in truth])
        Y = np.concatenate([np.asarray(y, dtype=np.float64).reshape(-1, 2) for y in estimate])
        step = np.repeat(np.arange(T), nm)
        r = np.arange(start[-1]) - start[step]
        xi = (np.cumsum(n) - n)[step] + r // m[step]
        yj = (np.cumsum(m) - m)[step] + r % m[step]
        dx = X[xi, 0] - Y[yj, 0]
        dy = X[xi, 1] - Y[yj, 1]
        sq_all = dx * dx + dy * dy
        d_all = np.sqrt(sq_all)
        cost_all = np.minimum(d_all, c) ** p
    for k in range(T):
        nk, mk = int(n[k]), int(m[k])
        small, big = min(nk, mk), max(nk, mk)
        if small == 0:
            card_p = cp * (big - small) / big if big else 0.0
            values = (card_p ** (1.0 / p), 0.0, card_p ** (1.0 / p),
                      (0.0 + cp / 2 * nk + cp / 2 * mk) ** (1.0 / p), 0.0, cp / 2 * nk,
                      cp / 2 * mk, math.nan)
        else:
            a, b = start[k], start[k + 1]
            d = d_all[a:b].reshape(nk, mk)
            cost = cost_all[a:b].reshape(nk, mk)
            sq = sq_all[a:b].reshape(nk, mk)
            if small == 1:
                if nk == 1:
                    rows, cols = np.zeros(1, np.intp), np.array([np.argmin(cost[0])])
                    rr, rc = rows, np.array([np.argmin(sq[0])])
                else:
                    rows, cols = np.array([np.argmin(cost[:, 0])]), np.zeros(1, np.intp)
                    rr, rc = np.array([np.argmin(sq[:, 0])]), cols
            else:
                rows, cols = linear_sum_assignment(cost)
                rr, rc = linear_sum_assignment(sq)
            pair_cost = cost[rows, cols]
            if nk > mk:
                pair_cost = pair_cost[np.argsort(cols)]
            loc_p = float(pair_cost.sum()) / big
            card_p = cp * (big - small) / big
            pair_d = d[rows, cols]
            kept = pair_d < c
            n_assigned = int(kept.sum())
            loc = float(np.sum(pair_d[kept] ** p))
            missed = cp / 2 * (nk - n_assigned)
            false = cp / 2 * (mk - n_assigned)
            values = ((loc_p + card_p) ** (1.0 / p), loc_p ** (1.0 / p), card_p ** (1.0 / p),
                      (loc + missed + false) ** (1.0 / p), loc, missed, false,
                      float(np.sqrt(np.mean(sq[rr, rc]))))
        for name, v in zip(names, values, strict=True):
            out[name][k] = v
    return out


#: the built-in metrics' functions, whose columns :func:`_builtin_step_columns` computes
_BUILTIN_FNS = frozenset((_count_error_columns, _own_count_error_columns, _ospa_columns,
                          _gospa_columns, _rmse_columns))


def step_metrics(
    truth: np.ndarray,
    estimate: np.ndarray,
    estimated_count: float,
    c: float = 2.0,
    p: float = 2.0,
    *,
    builtins: bool = True,
) -> dict[str, float]:
    """All per-step metrics as one flat dict (the metric columns of one row of the results
    table): the columns of every registered metric (:func:`registered_metrics`), then
    :data:`STEP_COUNTS`. ``builtins=False`` leaves out the built-ins' columns (a caller
    that takes them for a whole run from :func:`builtin_run_columns`).

    ``estimated_count`` is the tracker's count estimate (may be fractional, e.g. a
    posterior mean), which may differ from the number of estimated positions ``m``.
    GOSPA uses ``alpha = 2``; its ``gospa_*`` parts are in the p-th-power domain.

    ``count_error`` is ``|m - n|`` for the ``m`` states reported, ``own_count_error``
    ``|estimated_count - n|``: a tracker whose count is a weight sum may report fewer or
    more states than it counts, and only the states are scored.

    Keys of the built-ins: ``count_error, ospa, ospa_loc, ospa_card, gospa, gospa_loc,
    gospa_missed, gospa_false, rmse, own_count_error, true_count, n_estimated``. The
    built-ins' columns come from one shared computation (:func:`builtin_run_columns`,
    the same numbers as their functions).
    """
    _check_order_cutoff(c, p)
    x = _as_positions(truth, "truth")
    y = _as_positions(estimate, "estimate")
    row: dict[str, float] = {}
    builtin: dict[str, float] | None = None
    for metric in _REGISTRY.values():
        if metric.fn in _BUILTIN_FNS:
            if not builtins:
                continue
            if builtin is None:
                builtin = _builtin_step_columns(x, y, float(estimated_count), c, p)
            row.update((col, builtin[col]) for col in metric.columns)
            continue
        values = metric.fn(x, y, estimated_count, c, p)
        if set(values) != set(metric.columns):
            raise ValueError(f"metric {metric.name!r} returned the columns {sorted(values)}, "
                             f"not its declared {list(metric.columns)}")
        row.update((col, float(values[col])) for col in metric.columns)
    row["true_count"] = float(len(x))
    row["n_estimated"] = float(len(y))
    return row


# ---------------------------------------------------------------- run-level registry
def register_run_metric(metric: RunMetric) -> RunMetric:
    """Add a run-level metric after the registered ones; returns it. A name or column
    taken (by a per-step or run-level metric) is refused."""
    if not isinstance(metric, RunMetric):
        raise TypeError(f"{metric!r} is not a RunMetric")
    return _add(_RUN_REGISTRY, metric)


def unregister_run_metric(name: str) -> None:
    """Remove the run-level metric ``name`` (built-ins included: the step loop then
    computes none of its columns)."""
    _RUN_REGISTRY.pop(name, None)


def registered_run_metrics() -> tuple[RunMetric, ...]:
    """The registered run-level metrics, in registration order."""
    return tuple(_RUN_REGISTRY.values())


def run_metric_columns() -> list[str]:
    """Columns of the registered run-level metrics, in registration order."""
    return [c for m in _RUN_REGISTRY.values() for c in m.columns]


def run_metric_params() -> dict[str, dict[str, float]]:
    """``{metric: its parameters}`` of the registered run-level metrics (the manifest)."""
    return {m.name: dict(m.params) for m in _RUN_REGISTRY.values()}


def run_level_metrics(run: RunData) -> dict[str, float]:
    """The columns of every registered run-level metric for one finished run; NaN for
    the metrics that need labels when ``run.labels`` is None."""
    out: dict[str, float] = {}
    for metric in _RUN_REGISTRY.values():
        if metric.needs_labels and run.labels is None:
            out.update(dict.fromkeys(metric.columns, math.nan))
            continue
        values = metric.fn(run, **metric.params)
        if set(values) != set(metric.columns):
            raise ValueError(f"run metric {metric.name!r} returned the columns "
                             f"{sorted(values)}, not its declared {list(metric.columns)}")
        out.update((col, float(values[col])) for col in metric.columns)
    return out


def _dense(run: RunData) -> tuple:
    """The run's truth and estimates as :func:`~.track_metrics.dense_pair` gives them,
    converted once for all its track scores."""
    if "dense" not in run.cache:
        run.cache["dense"] = track_metrics.dense_pair(run.truth, run.truth_ids,
                                                      run.estimate, run.labels)
    return run.cache["dense"]


def _clear_mot(run: RunData, gate: float) -> track_metrics.ClearMOT:
    key = ("clear_mot", float(gate))
    if key not in run.cache:
        run.cache[key] = track_metrics.clear_mot(run.truth, run.truth_ids, run.estimate,
                                                 run.labels, gate=gate, dense=_dense(run))
    return run.cache[key]


def _tgospa_columns(run: RunData, gamma: float) -> dict[str, float]:
    g = track_metrics.trajectory_gospa(run.truth, run.truth_ids, run.estimate, run.labels,
                                       c=run.c, p=run.p, gamma=gamma, dense=_dense(run))
    return {"tgospa": g.total, "tgospa_loc": g.localisation, "tgospa_missed": g.missed,
            "tgospa_false": g.false, "tgospa_switch": g.switch}


def ospa2_of(run: RunData, window: float) -> track_metrics.OSPA2:
    """The run's OSPA(2) for ``window``, computed once per run (the run-level columns and
    the per-step series of :mod:`.track_series` share it through ``run.cache``)."""
    key = ("ospa2", float(run.c), float(run.p), int(window))
    if key not in run.cache:
        run.cache[key] = track_metrics.ospa2(run.truth, run.truth_ids, run.estimate,
                                             run.labels, c=run.c, p=run.p,
                                             window=int(window), dense=_dense(run))
    return run.cache[key]


def _ospa2_columns(run: RunData, window: float) -> dict[str, float]:
    o = ospa2_of(run, window)
    return {"ospa2": o.total, "ospa2_loc": o.localisation, "ospa2_card": o.cardinality}


def _id_switch_columns(run: RunData, gate: float) -> dict[str, float]:
    return {"id_switches": float(_clear_mot(run, gate).id_switches)}


def _fragmentation_columns(run: RunData, gate: float) -> dict[str, float]:
    return {"fragmentations": float(_clear_mot(run, gate).fragmentations)}


def _mostly_tracked_columns(run: RunData, gate: float, threshold: float) -> dict[str, float]:
    cover = _clear_mot(run, gate).coverage
    return {"mostly_tracked": float(np.mean(cover >= threshold)) if len(cover) else 0.0}


def _mostly_lost_columns(run: RunData, gate: float, threshold: float) -> dict[str, float]:
    cover = _clear_mot(run, gate).coverage
    return {"mostly_lost": float(np.mean(cover <= threshold)) if len(cover) else 0.0}


#: the CLEAR-MOT gate of the shipped track scores (workspace units: the default OSPA
#: cut-off c = 2, beyond which OSPA too counts a miss), the trajectory GOSPA switching
#: cost and the OSPA(2) window (steps)
CLEAR_MOT_GATE = 2.0
TGOSPA_GAMMA = 2.0
OSPA2_WINDOW = 10

#: the shipped run-level (track-level) metrics, in their order in the results table
BUILTIN_RUN_METRICS: tuple[str, ...] = tuple(register_run_metric(m).name for m in (
    RunMetric("tgospa", _tgospa_columns, ("tgospa", "tgospa_loc", "tgospa_missed",
                                          "tgospa_false", "tgospa_switch"),
              "TGOSPA", params={"gamma": TGOSPA_GAMMA}),
    RunMetric("ospa2", _ospa2_columns, ("ospa2", "ospa2_loc", "ospa2_card"), "OSPA(2)",
              params={"window": OSPA2_WINDOW}),
    RunMetric("id_switches", _id_switch_columns, label="ID switches", fmt=".1f",
              params={"gate": CLEAR_MOT_GATE}),
    RunMetric("fragmentations", _fragmentation_columns, label="fragmentations", fmt=".1f",
              params={"gate": CLEAR_MOT_GATE}),
    RunMetric("mostly_tracked", _mostly_tracked_columns, label="mostly tracked",
              lower_is_better=False, fmt=".2f",
              params={"gate": CLEAR_MOT_GATE, "threshold": 0.8}),
    RunMetric("mostly_lost", _mostly_lost_columns, label="mostly lost", fmt=".2f",
              params={"gate": CLEAR_MOT_GATE, "threshold": 0.2}),
))

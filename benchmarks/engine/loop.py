"""The harness: run trackers on scenarios and record one tidy row per step.

A **job** is one Monte Carlo run: ``(scenario, tracker spec, policy spec,
looks_per_step, seed)``. :func:`play` is the one step loop of the suite (the rows of
:func:`run_job`, the traces of :mod:`~mttbench.benchmarks.engine.snapshot`, the warm states
of the runtime benchmarks and the conformance kit all come from it); it yields a
:class:`StepRecord` per step::

    run = simulate(scenario, seed)          # the world: depends on (scenario, seed) only
    tracker.reset(model, rng_tracker)       # rng from (scenario, seed, tracker config)
    policy.reset(model, looks, rng_policy)  # rng from (scenario, seed, policy config)
    for k in range(n_steps):
        tracker.predict()                                   # timed (tracker)
        tracker.observe_truth(states, ids)  # untimed; only if tracker.uses_truth
        P = tracker.cell_count_distribution()               # timed (selection), if needed
        cells = policy.select(k, counts=P, truth_cells=...) # timed (selection)
        cells = cells[visible]          # a look at a cell the model blinds is not made
        looks = run.look(k, cells)      # or run.measure(k) for the superposition sensor
        tracker.update(looks)                               # timed (tracker)
        est = tracker.estimate()                            # timed (tracker)
        metrics(truth positions, est.states[:, [0, 2]])     # untimed (the built-ins for
                                                            # the whole run at its end)

The policy's generator does not depend on the tracker, so a random policy looks
at the same cells for every tracker of a run (common random numbers). The
policy gets ``counts`` only if it ``uses_prediction``, ``undetected`` (the tracker's
:meth:`~mttbench.trackers.base.Tracker.undetected_intensity`, in the selection's time)
only if it ``uses_undetected``, and ``truth_cells`` only if it ``uses_truth`` (the
oracle). A tracker sees the truth only if its class sets ``uses_truth = True`` (the
``truth-aided`` reference): then, and only then, the loop calls its
``observe_truth(states (n, 4), ids (n,))`` with the current step's truth, after
``predict`` and before the cell selection and ``update`` (so its ``P_c(t)`` knows the
count too); that call is in neither timing. Each side's use of the truth is
recorded from its own class attribute: ``tracker_uses_truth`` and ``policy_uses_truth``.

Results table (one row per scenario x tracker x policy x looks x seed x step):

=================  ==========================================================
column             meaning
=================  ==========================================================
scenario           scenario name
tracker            registered tracker name
tracker_label      ``name`` or ``name(k=v,...)`` with the parameters given
tracker_params     JSON of all constructor parameters (defaults included), sorted keys
policy             policy name; ``"none"`` for the superposition sensor (no cells)
policy_label       like ``tracker_label``; ``"none"`` for the superposition sensor
policy_params      JSON of the policy's parameters
tracker_uses_truth True if the tracker was given the truth (``Tracker.uses_truth``:
                   the truth-aided reference)
policy_uses_truth  True if the policy was given the truth (``Policy.uses_truth``: the
                   oracle); False for the superposition sensor (no policy)
looks_per_step     look budget ``M`` given to the policy; 0 for superposition
seed               the run's seed
step               step ``k`` (0-based); -1 on the single row of an unsupported
                   job or of a job that failed before its first step
true_count         true number of targets (float; NaN when unknown)
est_count          tracker's estimated count (float)
count_error        ``|est_count - true_count|``
ospa, ospa_loc,    OSPA with cut-off ``c`` and order ``p`` and its localisation
ospa_card          and cardinality parts (positions only)
gospa, gospa_loc,  GOSPA (alpha = 2) and its localisation, missed and false parts
gospa_missed,
gospa_false
rmse               RMSE of the optimally assigned pairs (NaN if none)
n_looks            looks made this step (``len(looks.cells)``)
n_positive         positive returns this step
tracker_wall_s     wall time of predict + update + estimate (``time.perf_counter``)
tracker_cpu_s      CPU time of the same (``time.process_time``)
select_wall_s      wall time of the cell selection (``cell_count_distribution`` when
                   the policy uses it, plus ``policy.select``)
select_cpu_s       CPU time of the same
status             ``"ok"``, ``"error"`` (the tracker or policy raised) or ``"unsupported"``
error              ``"ExceptionType: message"``, or the unsupported reason; ``""`` if ok
ospa_c, ospa_p     the metric parameters ``c`` and ``p``
peak_rss_mb        peak resident memory of the worker process at the end of the job
                   (``getrusage`` high-water mark: it never goes down, so it bounds
                   this job's peak from above and includes earlier jobs of the worker)
param_<name>       one column per tracker parameter (all of them, defaults included)
<run metrics>      the run-level (track) scores of
                   :func:`~mttbench.benchmarks.engine.metrics.register_run_metric`
                   (``tgospa``, ``ospa2``, ``id_switches``, ``fragmentations``,
                   ``mostly_tracked``, ``mostly_lost`` and parts), computed once at the
                   end of the run from its truth ids and the estimate's labels and
                   written on every row of the run (constant over it); NaN for a run
                   that failed or whose tracker gives no labels; the per-step series
                   of :mod:`~mttbench.benchmarks.engine.track_series` (``ospa2_window``,
                   ``id_switches_step``, ``crossings``, ``crossings_near``) are computed
                   at the end too but written one value per step
<metric columns>   the columns of every metric registered beyond the built-ins
                   (:func:`~mttbench.benchmarks.engine.metrics.register_metric`), in
                   registration order
=================  ==========================================================

A job whose tracker raises at step ``k`` keeps its rows ``0..k-1`` (status
``"ok"``) and gets one row at step ``k`` with ``status = "error"`` and NaN metrics;
the other jobs of the sweep are unaffected.

Tracker and policy specifications are described in :mod:`~mttbench.benchmarks.engine.specs`.
"""

from __future__ import annotations

import hashlib
import json
import math
import resource
import signal
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from ...scenarios.model import Looks, RayleighGridSensor
from ...scenarios.simulator import simulate, tracker_seed
from ...scenarios.spec import Scenario, dumps
from ...trackers.base import Estimate, Tracker
from ...trackers.cells import CellCounts
from .metrics import (
    BUILTIN_METRICS,
    RunData,
    _check_order_cutoff,
    builtin_run_columns,
    cutoff,
    metric_columns,
    metric_names,
    run_level_metrics,
    run_metric_columns,
    run_metric_params,
    step_metrics,
)
from .policies import Policy, Raster
from .specs import PolicySpec, TrackerSpec
from .track_series import series_values

if TYPE_CHECKING:
    pass

#: the built-in metrics' columns (their place in the table; the registry's order)
METRIC_COLUMNS = metric_columns(BUILTIN_METRICS)
TIMING_COLUMNS = ["tracker_wall_s", "tracker_cpu_s", "select_wall_s", "select_cpu_s"]
#: whether the tracker and the policy were given the truth (each from its own class)
TRUTH_COLUMNS = ["tracker_uses_truth", "policy_uses_truth"]
#: the fixed columns, in order; ``param_<name>`` columns follow, sorted
COLUMNS = [
    "scenario", "tracker", "tracker_label", "tracker_params", "policy", "policy_label",
    "policy_params", *TRUTH_COLUMNS, "looks_per_step", "seed", "step", "true_count",
    "est_count",
    *METRIC_COLUMNS, "n_looks", "n_positive", *TIMING_COLUMNS, "status", "error", "ospa_c",
    "ospa_p", "peak_rss_mb",
]
#: columns that identify a run (one Monte Carlo replicate)
RUN_KEYS = ["scenario", "tracker_label", "policy_label", "looks_per_step", "seed"]
_INT_COLUMNS = ["looks_per_step", "seed", "step", "n_looks", "n_positive"]
_FLOAT_COLUMNS = ["true_count", "est_count", *METRIC_COLUMNS, *TIMING_COLUMNS, "ospa_c", "ospa_p",
                  "peak_rss_mb"]
NO_POLICY = "none"


@dataclass(frozen=True)
class Job:
    """One Monte Carlo run. Normalised on construction.

    On a grid-sensor scenario ``policy`` defaults to raster and ``looks_per_step``
    to the scenario's ``sensor.looks_per_step``; on the superposition sensor both
    are set to None (there are no cells to choose).
    """

    scenario: Scenario
    tracker: TrackerSpec
    policy: PolicySpec | None = None
    looks_per_step: int | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        sensor = self.scenario.model.sensor
        if isinstance(sensor, RayleighGridSensor):
            if self.policy is None:
                object.__setattr__(self, "policy", PolicySpec("raster"))
            if self.looks_per_step is None:
                object.__setattr__(self, "looks_per_step", int(sensor.looks_per_step))
        else:
            object.__setattr__(self, "policy", None)
            object.__setattr__(self, "looks_per_step", None)

    @property
    def policy_label(self) -> str:
        return self.policy.label if self.policy is not None else NO_POLICY

    def key(self, c: float | None, p: float) -> str:
        """A stable hash of everything that determines the job's results (``c`` None:
        :data:`~mttbench.benchmarks.engine.metrics.CUTOFF_CELLS` cells of the scenario's
        grid, hashed as the number it resolves to)."""
        c = cutoff(c, self.scenario.grid.cell_size)
        ident = {
            "scenario": dumps(self.scenario),
            "tracker": [self.tracker.name, self.tracker.params],
            "policy": None if self.policy is None else [self.policy.name, self.policy.params],
            "looks": self.looks_per_step,
            "seed": int(self.seed),
            "c": float(c),
            "p": float(p),
        }
        extra_metrics = [n for n in metric_names() if n not in BUILTIN_METRICS]
        if extra_metrics:  # their columns are part of the results
            ident["metrics"] = extra_metrics
        run_level = run_metric_params()
        if run_level:  # the track-level columns and their parameters
            ident["run_metrics"] = run_level
        text = json.dumps(ident, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:24]


def build_jobs(scenarios: list[Scenario], tracker_specs: list[TrackerSpec],
               policy_specs: list[PolicySpec] | None, looks: list[int] | None,
               seeds: list[int]) -> list[Job]:
    """The sweep scenarios x trackers x policies x looks x seeds.

    ``policy_specs`` None means raster; ``looks`` None means each scenario's own
    ``looks_per_step``. A superposition scenario gets one job per tracker x seed.
    """
    jobs: list[Job] = []
    for sc in scenarios:
        if isinstance(sc.model.sensor, RayleighGridSensor):
            pols: list[PolicySpec | None] = list(policy_specs or [PolicySpec("raster")])
            lks: list[int | None] = list(looks) if looks else [None]
        else:
            pols, lks = [None], [None]
        for tr in tracker_specs:
            for pol in pols:
                for m in lks:
                    for seed in seeds:
                        jobs.append(Job(sc, tr, pol, m, int(seed)))
    return jobs


# ------------------------------------------------------------------------ one job
def _peak_rss_mb() -> float:
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    # kilobytes on Linux, bytes on macOS
    return rss / (1024.0 * 1024.0) if sys.platform == "darwin" else rss / 1024.0


def _param_value(v: Any) -> Any:
    """Scalars as they are; anything else as JSON text (Parquet needs one type per column)."""
    if v is None or isinstance(v, bool | int | float | str):
        return v
    if isinstance(v, np.generic):
        return v.item()
    return json.dumps(v, default=str)


def _params_json(params: dict[str, Any]) -> str:
    return json.dumps(params, sort_keys=True, default=str)


def _nan_metrics() -> dict[str, float]:
    return dict.fromkeys(metric_columns(), math.nan)


def _frame(rows: list[dict[str, Any]] | dict[str, list[Any]]) -> pd.DataFrame:
    """Rows (a list of dicts, or a dict of equal-length column lists) -> DataFrame with the
    fixed columns in order and stable dtypes."""
    if isinstance(rows, dict):
        return _frame_of_columns(rows)
    df = pd.DataFrame(rows)
    params = sorted(c for c in df.columns if c.startswith("param_"))
    # the run-level (track) metrics' columns, then those of metrics registered later
    track = [c for c in run_metric_columns() if c in df.columns]
    extra = [c for c in df.columns if c not in COLUMNS and c not in params and c not in track]
    df = df[COLUMNS + params + track + extra]
    df[_INT_COLUMNS] = df[_INT_COLUMNS].astype("int64")
    floats = _FLOAT_COLUMNS + track + [c for c in metric_columns() if c in extra]
    df[floats] = df[floats].astype("float64")
    df[TRUTH_COLUMNS] = df[TRUTH_COLUMNS].astype(bool)
    return df


def _frame_of_columns(cols: dict[str, list[Any]]) -> pd.DataFrame:
    """:func:`_frame` of column lists: the same columns, order, dtypes and values, each
    typed column made once with numpy instead of table-wide ``astype`` calls on a table
    built from a dict per row (docs/result_store.md: ``run_job`` of the null tracker in
    0.79x the time)."""
    params = sorted(c for c in cols if c.startswith("param_"))
    track = [c for c in run_metric_columns() if c in cols]
    extra = [c for c in cols if c not in COLUMNS and c not in params and c not in track]
    typed = dict.fromkeys(_INT_COLUMNS, np.int64)
    typed.update(dict.fromkeys(
        [*_FLOAT_COLUMNS, *track, *(c for c in metric_columns() if c in extra)], np.float64))
    typed.update(dict.fromkeys(TRUTH_COLUMNS, bool))
    return pd.DataFrame({c: np.asarray(cols[c], dtype=typed[c]) if c in typed else cols[c]
                         for c in [*COLUMNS, *params, *track, *extra]})


@dataclass(frozen=True)
class StepRecord:
    """What happened at step ``k`` of a run (yielded by :func:`play`).

    ``truth (n, 4)`` true states and ``truth_ids (n,)`` their ids; ``looks`` the
    looks made (cells and returns, or the superposition measurement); ``estimate``
    the tracker's output; ``counts`` the predicted ``P_c(t)`` as the tracker returned it
    (the dense ``(n_cells, n_counts)`` array or a :class:`~mttbench.trackers.cells.
    CellCounts`) if the policy asked for it, else None. Times in seconds: the tracker's
    predict + update + estimate, and the cell selection (including ``counts``).
    """

    k: int
    truth: np.ndarray
    truth_ids: np.ndarray
    looks: Looks
    estimate: Estimate
    counts: np.ndarray | CellCounts | None
    tracker_wall_s: float
    tracker_cpu_s: float
    select_wall_s: float
    select_cpu_s: float


class Playback:
    """One run in progress: iterate it for one :class:`StepRecord` per step (see :func:`play`).

    ``world`` is the simulated run (truth and sensor randomness); ``step`` is the
    step being computed (-1 before the first), so a caller that catches a failure
    knows where it happened. ``tracker_config`` and ``policy_config`` (None without
    cells) are the canonical configurations that seeded the tracker's and the policy's
    generators; ``tracker_label`` and ``policy_label`` name the run (messages) and
    change no number.
    """

    def __init__(self, scenario: Scenario, tracker: Tracker, seed: int, policy: Policy | None,
                 looks_per_step: int | None, tracker_label: str | None,
                 policy_label: str | None, n_steps: int | None) -> None:
        model = scenario.model
        reason = tracker.unsupported_reason(model)
        if reason:
            who = tracker_label or tracker.name or type(tracker).__name__
            raise ValueError(f"tracker {who!r} cannot run {scenario.name!r}: {reason}")
        grid_sensor = isinstance(model.sensor, RayleighGridSensor)
        if grid_sensor and policy is None:
            policy = Raster()
        self.scenario, self.tracker = scenario, tracker
        self.policy = policy if grid_sensor else None
        self.tracker_label = tracker_label or tracker.name or type(tracker).__name__
        self.policy_label = (None if self.policy is None else
                             policy_label or self.policy.name or type(self.policy).__name__)
        self.step = -1
        # seeds from the canonical resolved configurations (implementation and every
        # parameter, validated here), never from a label's spelling
        self.tracker_config = type(tracker).canonical_config(tracker.get_params())
        self.policy_config = (None if self.policy is None else
                              type(self.policy).canonical_config(self.policy.get_params()))
        self.world = simulate(scenario, int(seed))
        tracker.reset(model, np.random.default_rng(
            tracker_seed(scenario.name, seed, self.tracker_config)))
        if self.policy is not None:
            m = int(model.sensor.looks_per_step if looks_per_step is None else looks_per_step)
            # the policy's stream ignores the tracker: every tracker sees the same random cells
            self.policy.reset(model, m, np.random.default_rng(
                tracker_seed(scenario.name, seed, self.policy_config)))
        n = self.world.n_steps
        self.n_steps = n if n_steps is None else min(int(n_steps), n)

    def __iter__(self) -> Iterator[StepRecord]:
        tracker, policy, run = self.tracker, self.policy, self.world
        grid = self.scenario.model.grid
        given_truth = bool(getattr(tracker, "uses_truth", False))
        visibility = self.scenario.model.visibility
        for k in range(self.n_steps):
            self.step = k
            truth = run.states[k]
            counts = None
            w0, c0 = time.perf_counter(), time.process_time()
            tracker.predict()
            w1, c1 = time.perf_counter(), time.process_time()
            if given_truth:  # a reference told the truth (untimed)
                tracker.observe_truth(truth.copy(), run.ids[k].copy())
                w1s, c1s = time.perf_counter(), time.process_time()
            else:
                w1s, c1s = w1, c1
            if policy is not None:
                counts = tracker.cell_count_distribution() if policy.uses_prediction else None
                truth_cells = None
                if policy.uses_truth:
                    flat = grid.cell_of(truth[:, 0], truth[:, 2])
                    truth_cells = flat[flat >= 0]
                extra = ({"undetected": tracker.undetected_intensity()}
                         if getattr(policy, "uses_undetected", False) else {})
                cells = policy.select(k, counts=counts, truth_cells=truth_cells, **extra)
                w2, c2 = time.perf_counter(), time.process_time()
                if visibility.occlusions:  # a look at a blind cell is not made
                    cells = np.asarray(cells, dtype=np.int64).reshape(-1)
                    cells = cells[~visibility.is_blocked(k, cells, grid)]
                looks = run.look(k, cells)
            else:
                w2, c2 = w1s, c1s
                looks = run.measure(k)
            w3, c3 = time.perf_counter(), time.process_time()
            tracker.update(looks)
            est = tracker.estimate()
            w4, c4 = time.perf_counter(), time.process_time()
            yield StepRecord(k, truth, run.ids[k], looks, est, counts,
                             (w1 - w0) + (w4 - w3), (c1 - c0) + (c4 - c3), w2 - w1s, c2 - c1s)


def play(scenario: Scenario, tracker: Tracker, seed: int, *, policy: Policy | None = None,
         looks_per_step: int | None = None, tracker_label: str | None = None,
         policy_label: str | None = None, n_steps: int | None = None) -> Playback:
    """Start ``tracker`` on ``scenario``'s world ``seed``; iterate the result for one
    :class:`StepRecord` per step. The suite's only step loop::

        tracker.predict()                                  # timed (tracker)
        tracker.observe_truth(states, ids)    # untimed, only if tracker.uses_truth
        P = tracker.cell_count_distribution()              # timed (selection), if asked
        cells = policy.select(k, counts=P, truth_cells=...)   # timed (selection)
        # P as the tracker returns it: a dense array or a CellCounts (never converted)
        cells = cells[visible at step k]   # the model's visibility: blind cells get no look
        looks = world.look(k, cells)       # world.measure(k) on the superposition sensor
        tracker.update(looks); est = tracker.estimate()    # timed (tracker)

    The world (truth and the uniforms behind every look) depends only on
    ``(scenario, seed)``. The tracker's generator is seeded from ``(scenario.name,
    seed, tracker configuration)`` and the policy's from ``(scenario.name, seed, policy
    configuration)``: the canonical resolved configuration
    (:meth:`~mttbench.trackers.params.Configurable.canonical_config`: implementation and
    every parameter, defaults filled in, validated; kept as
    :attr:`Playback.tracker_config` / :attr:`Playback.policy_config`), so equal
    configurations give equal numbers however they are spelled (``jmpd-ip``,
    ``jmpd:proposal=ip``), and a random policy looks at the same cells for every
    tracker. ``tracker_label`` and ``policy_label`` only name the run (messages,
    :class:`Playback` attributes); they change no number. Parameters the declaration
    refuses raise :class:`~mttbench.trackers.params.ParameterError` (a ``ValueError``).
    On a grid sensor the
    policy defaults to :class:`~mttbench.benchmarks.engine.policies.Raster` and
    ``looks_per_step`` to the sensor's budget; the superposition sensor takes
    neither. ``n_steps`` stops early (default: the scenario's length). The tracker is
    used as given, not copied: after the loop it holds the last state.

    The setup (simulation, ``reset``) runs here; raises ``ValueError`` if the tracker
    declares the scenario unsupported. A failing tracker or policy raises from the
    iteration, with :attr:`Playback.step` naming the step.
    """
    return Playback(scenario, tracker, seed, policy, looks_per_step, tracker_label,
                    policy_label, n_steps)


def spec_uses_truth(spec: TrackerSpec | PolicySpec) -> bool:
    """True if the spec's tracker or policy class is given the truth (its ``uses_truth``;
    False if the class cannot be found: that job fails with its own message)."""
    try:
        return bool(getattr(spec.target(), "uses_truth", False))
    except Exception:  # noqa: BLE001 - an unknown class is reported by run_job
        return False


def _base_row(job: Job, c: float | None, p: float) -> dict[str, Any]:
    """The columns that identify a job's rows (tracker and policy parameters as given;
    :func:`run_job` replaces them with the resolved ones once the objects are built)."""
    c = cutoff(c, job.scenario.grid.cell_size)
    return {
        "scenario": job.scenario.name,
        "tracker": job.tracker.name,
        "tracker_label": job.tracker.label,
        "tracker_params": _params_json(job.tracker.params),
        "policy": job.policy.name if job.policy is not None else NO_POLICY,
        "policy_label": job.policy_label,
        "policy_params": "{}",
        "tracker_uses_truth": spec_uses_truth(job.tracker),
        "policy_uses_truth": job.policy is not None and spec_uses_truth(job.policy),
        "looks_per_step": job.looks_per_step or 0,
        "seed": int(job.seed),
        "ospa_c": float(c),
        "ospa_p": float(p),
    }


def _special_row(base: dict[str, Any], step: int, status: str, message: str,
                 true_count: float) -> dict[str, Any]:
    """A row without metrics: an unsupported job (step -1) or the step that failed."""
    return {**base, "step": step, "true_count": true_count, "est_count": math.nan,
            **_nan_metrics(), "n_looks": 0, "n_positive": 0,
            **dict.fromkeys(TIMING_COLUMNS, math.nan), "status": status, "error": message}


def _check_estimate(count: Any, states: np.ndarray) -> None:
    """A tracker's estimate must have a finite count >= 0 and finite states; else
    ``ValueError`` (the run's error row)."""
    try:
        n = float(count)
    except (TypeError, ValueError):
        raise ValueError(f"the estimate's count {count!r} is not a number") from None
    if not (math.isfinite(n) and n >= 0):
        raise ValueError(f"the estimate's count {n} is not a finite number >= 0")
    if not np.isfinite(states).all():
        raise ValueError("the estimate's states are not all finite")


def _labels_of(est: Estimate, n: int) -> np.ndarray | None:
    """The estimate's track labels as ``(n,)`` int64, or None; ``ValueError`` (the run's
    error row) when they do not match the states or repeat within the step."""
    if est.labels is None:
        return None
    labels = np.asarray(est.labels)
    if labels.shape != (n,) or not (labels.size == 0 or np.issubdtype(labels.dtype, np.integer)):
        raise ValueError(f"the estimate's labels (shape {labels.shape}, {labels.dtype}) are "
                         f"not {n} integers, one per state")
    if len(np.unique(labels)) != n:
        raise ValueError("the estimate's labels repeat within the step")
    return labels.astype(np.int64)


def _sigint_ignored() -> bool:
    try:
        return signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    except (ValueError, TypeError):
        return False


def run_job(job: Job, c: float | None = None, p: float = 2.0) -> pd.DataFrame:
    """Play one job (:func:`play`); returns its rows (see the module docstring). ``c``
    None: the cut-off is :data:`~mttbench.benchmarks.engine.metrics.CUTOFF_CELLS` cells of
    the scenario's grid (``ospa_c`` records it in world units).

    Never raises for a failing tracker or policy: the failure becomes a row with
    ``status = "error"``. An unsupported scenario gives one row with ``step = -1``.
    """
    sc, model = job.scenario, job.scenario.model
    c = cutoff(c, sc.grid.cell_size)
    base = _base_row(job, c, p)
    rows: list[dict[str, Any]] = []

    # the whole run, for the run-level (track) metrics; NaN unless the run finishes
    track_run: list[list[np.ndarray]] = [[], [], [], []]
    labelled = True
    run_values = dict.fromkeys(run_metric_columns(), math.nan)
    # the per-step series of the track scores (track_series.RunSeries): row k gets [k]
    run_series: dict[str, np.ndarray] = {}

    # the ok steps' own columns, one list each (the job's constant columns, ``base``,
    # are broadcast once in finish: no dict per step, one table built column-wise)
    step_cols: dict[str, list[Any]] = {}

    def finish() -> pd.DataFrame:
        rss = _peak_rss_mb()
        n_ok = len(step_cols.get("step", ()))
        if n_ok:  # the built-in metrics of the ok steps, for the whole run at once
            cols = builtin_run_columns(track_run[0][:n_ok], track_run[2][:n_ok],
                                       step_cols["est_count"], c=c, p=p)
            step_cols.update((k, v.tolist()) for k, v in cols.items())
        table: dict[str, list[Any]] = {k: [v] * n_ok for k, v in base.items()} if n_ok else {}
        table.update(step_cols)
        for r in rows:  # the special row: unsupported, or the step that failed
            for k, v in r.items():
                table.setdefault(k, []).append(v)
        n = n_ok + len(rows)
        table["peak_rss_mb"] = [rss] * n
        table.update((k, [v] * n) for k, v in run_values.items())
        table.update((col, [float(v[k]) for k in range(n)]) for col, v in run_series.items())
        return _frame(table)

    playback = None
    try:
        tracker = job.tracker.make()
        params = tracker.get_params()
        base["tracker_params"] = _params_json(params)
        base.update({f"param_{n}": _param_value(v) for n, v in params.items()})
        policy = job.policy.make() if job.policy is not None else None
        base["tracker_uses_truth"] = bool(getattr(tracker, "uses_truth", False))
        if policy is not None:
            base["policy_params"] = _params_json(policy.get_params())
            base["policy_uses_truth"] = bool(policy.uses_truth)

        reason = tracker.unsupported_reason(model)
        if reason:
            rows.append(_special_row(base, -1, "unsupported", str(reason), math.nan))
            return finish()

        playback = play(sc, tracker, job.seed, policy=policy,
                        looks_per_step=job.looks_per_step, tracker_label=job.tracker.label,
                        policy_label=job.policy_label)
        m_cols = metric_columns()  # the registry does not change during a run
        # the built-ins' columns are filled in by finish; the others' step by step
        step_cols.update((k, []) for k in (
            "step", "true_count", "est_count", *m_cols, "n_looks", "n_positive",
            *TIMING_COLUMNS, "status", "error"))
        extra_cols = [name for name in m_cols if name not in METRIC_COLUMNS]
        col = step_cols
        for rec in playback:
            est = rec.estimate
            states = np.asarray(est.states, dtype=float).reshape(-1, 4)
            _check_estimate(est.count, states)
            if rec.k == 0:  # a bad c or p fails the first step, as the metrics would
                _check_order_cutoff(c, p)
            if extra_cols:
                m = step_metrics(rec.truth[:, [0, 2]], states[:, [0, 2]], float(est.count),
                                 c=c, p=p, builtins=False)
            labels = _labels_of(est, len(states))
            labelled = labelled and labels is not None
            for acc, v in zip(track_run, (rec.truth[:, [0, 2]], rec.truth_ids, states[:, [0, 2]],
                                          labels), strict=True):
                acc.append(v)
            col["step"].append(rec.k)
            col["true_count"].append(float(len(rec.truth)))
            col["est_count"].append(float(est.count))
            for name in extra_cols:
                col[name].append(float(m[name]))
            col["n_looks"].append(len(rec.looks.cells))
            col["n_positive"].append(int(np.count_nonzero(rec.looks.returns)))
            col["tracker_wall_s"].append(rec.tracker_wall_s)
            col["tracker_cpu_s"].append(rec.tracker_cpu_s)
            col["select_wall_s"].append(rec.select_wall_s)
            col["select_cpu_s"].append(rec.select_cpu_s)
            col["status"].append("ok")
            col["error"].append("")
        if run_values:  # the run finished: its track-level scores, on every row
            t, ids, e, lab = track_run
            try:
                whole = RunData(t, ids, e, lab if labelled else None, c=c, p=p)
                values = run_level_metrics(whole)
                run_series.update(series_values(whole))  # one row per step: rows[k] is k
                run_values.update(values)
            except Exception:  # noqa: BLE001 - a score that fails stays NaN; the run is ok
                run_series.clear()
    except BaseException as exc:  # noqa: BLE001 - any failure of a tracker is a result
        # SystemExit too is the tracker's failure; so is a KeyboardInterrupt where Ctrl-C
        # is ignored (a pool or Dask worker: Ctrl-C is the main process's), which only
        # the tracker's own code can raise
        if isinstance(exc, KeyboardInterrupt) and not _sigint_ignored():
            raise
        message = f"{type(exc).__name__}: {exc}".replace("\n", " ")
        k = playback.step if playback is not None else -1
        true_count = float(len(playback.world.states[k])) if k >= 0 else math.nan
        rows.append(_special_row(base, k, "error", message, true_count))
    return finish()

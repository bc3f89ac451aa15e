"""Summary statistics of a results table: per-run averages, means over seeds with
95% confidence intervals, paired differences against a reference tracker.

Convention (used everywhere here): a statistic ``m`` is reported as two columns,
``m_mean`` (the mean over seeds of the per-run values) and ``m_ci95``, the
half-width of the two-sided 95% Student-t interval::

    m_ci95 = t_{0.975, n-1} * sd / sqrt(n),    sd with ddof = 1

so the interval is ``m_mean +- m_ci95``. With ``n = 1`` the half-width is NaN.
The seeds are the independent replicates: every step of one run is averaged
first (:func:`per_run`), so the interval reflects run-to-run variation only.

Only runs whose every step has ``status == "ok"`` enter the means; runs that
failed or were unsupported are counted in ``n_errors`` / ``n_unsupported`` and
described in ``note``.

``looks_per_step`` is the look budget asked for; ``looks_made`` the mean number of
looks actually made per step (``n_looks``): a policy makes fewer when the budget
exceeds the grid's cells, and ``all`` looks at every cell whatever the budget. The
Markdown table shows the budget as ``200 (144 made)`` where the two differ.

**Floor, ceiling and the share of the gap closed** (:func:`gap_closed`). In each
``(scenario, policy_label, looks_per_step)`` the floor is the ``null`` tracker (it
reports nothing) and the ceiling the ``truth-aided`` tracker (told the count and which
look belongs to which target: it uses the truth). With ``F_i``, ``C_i`` and ``X_i`` the
per-run mean OSPA of floor, ceiling and a tracker in seed ``i`` (the seeds are paired:
the three runs share the world), over the ``n`` seeds where all three runs are ok::

    A_i = F_i - X_i,  B_i = F_i - C_i,  share = mean(A) / mean(B)

a ratio of means (1 = as good as the ceiling, 0 = no better than reporting nothing).
Its 95% interval is the **delta method** (no resampling, so no random numbers)::

    d_i = (A_i - share * B_i) / mean(B)
    share_ci95 = t_{0.975, n-1} * sd(d) / sqrt(n)          (sd with ddof = 1)

The gap is ``mean(B)`` with the paired t half-width of the ``B_i``. A scenario whose
gap is below :data:`MIN_GAP` (0.15 OSPA) or whose gap interval reaches 0 cannot rank
trackers, nor one where no contestant (neither floor, ceiling nor a tracker or policy that
uses the truth) beats the floor, its paired difference's 95% interval above 0: its row
says so (``rankable``, ``reason``). Rows of trackers or policies that
use the truth are marked `` (uses truth)`` in the tables (:func:`truth_labels`).

**Track-level scores.** The run-level (track) metrics are one value per run
(:func:`track_metrics_of`), summarised like the others; ``summary.md`` shows their
headlines in a table of their own (:func:`track_markdown`), without the trackers that
give no labels. The per-step series of :mod:`~mttbench.benchmarks.engine.track_series`
stay out of the per-run tables; :func:`crossing_switches` sums the switches per step
near the truth's crossings and elsewhere.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..engine.metrics import (
    column_label,
    describe_cutoff,
    display_metrics,
    metric_columns,
    registered_run_metrics,
    run_metric_columns,
)
from ..engine.track_series import series_columns

#: per-run statistics of the run time, summarised over seeds after the metrics
RUN_TIMES = ["tracker_wall_s", "tracker_wall_p95_s", "tracker_wall_max_s", "tracker_cpu_s",
             "select_wall_s", "peak_rss_mb"]
RUN_KEYS = ["scenario", "tracker_label", "policy_label", "looks_per_step", "seed"]
DEFAULT_BY = ("scenario", "tracker_label", "policy_label", "looks_per_step")
# descriptive columns carried along when present (constant within a run)
_CARRY = ["tracker", "policy", "tracker_uses_truth", "policy_uses_truth"]


def step_metrics_of(table: pd.DataFrame) -> list[str]:
    """The registered metrics' columns (:mod:`~mttbench.benchmarks.engine.metrics`) that
    ``table`` has, in display order: averaged over the steps of a run (nanmean: rmse is
    NaN when nothing is assigned)."""
    return [c for c in metric_columns(display=True) if c in table.columns]


def track_metrics_of(table: pd.DataFrame) -> list[str]:
    """The registered run-level (track) metrics' columns that ``table`` has, in
    registration order: constant over a run's rows, taken once per run. The per-step
    series (:func:`~mttbench.benchmarks.engine.track_series.series_columns`) are left
    out: their run values are the track scores already listed (``ospa2``,
    ``id_switches``); :func:`crossing_switches` and the figures read them per step."""
    series = set(series_columns())
    return [c for c in run_metric_columns() if c in table.columns and c not in series]


def unlabelled_trackers(runs: pd.DataFrame) -> list[str]:
    """Tracker labels of ``runs`` (:func:`per_run`) with ok runs but no track-level
    score in any of them: the tracker gives no labels (``Estimate.labels`` None)."""
    heads = [m.name for m in registered_run_metrics() if m.needs_labels and m.name in runs]
    if not heads or not len(runs):
        return []
    ok = runs[runs["status"] == "ok"]
    empty = ok[heads].isna().all(axis=1).groupby(ok["tracker_label"]).all()
    return sorted(str(t) for t in empty[empty].index)


def run_metrics(table: pd.DataFrame) -> list[str]:
    """Per-run statistics of ``table`` summarised over seeds, in display order: the step
    metrics, the run-level (track) metrics, the times."""
    return [*step_metrics_of(table), *track_metrics_of(table), *RUN_TIMES]


def _nanmean(x: pd.Series) -> float:
    return _nanmean_of(x.to_numpy(dtype=float))


def _nanmean_of(v: np.ndarray) -> float:
    """The mean of the values of ``v`` that are not NaN (NaN if none)."""
    v = v[~np.isnan(v)]
    return float(v.mean()) if v.size else math.nan


def per_run(results: pd.DataFrame) -> pd.DataFrame:
    """One row per run ``(scenario, tracker_label, policy_label, looks_per_step, seed)``.

    Step metrics are averaged over the run's ``"ok"`` steps (NaN-aware); run-level
    (track) metrics are the run's value (the same on each of its rows; NaN for a run that
    failed or whose tracker gives no labels);
    ``tracker_wall_s`` and ``tracker_cpu_s`` are the median per-step times,
    ``tracker_wall_p95_s`` and ``tracker_wall_max_s`` the 95th percentile and the slowest
    step (a median hides single slow steps),
    ``select_wall_s`` the mean per-step selection time, ``peak_rss_mb`` the maximum.
    ``status`` is ``"ok"`` if every step was ok, else ``"unsupported"`` or
    ``"error"``; ``error`` holds the first message; ``n_steps`` counts ok steps;
    ``looks_made`` is the mean number of looks made per ok step (when the table has
    ``n_looks``).

    The columns are read into arrays once and each run is a slice of them, its rows in
    table order (pandas per run cost 7 ms, a report of 480 runs 3 s): the same numbers
    as the statistics of each run's own rows (numpy's mean and median of the same values
    in the same order; pandas' NaN-skipping median and mean where the definition is
    theirs).
    """
    carry = [c for c in _CARRY if c in results.columns]
    steps = step_metrics_of(results)
    track = track_metrics_of(results)
    cols = [*RUN_KEYS, *carry, "status", "error", "n_steps", *steps, *track, *RUN_TIMES]
    cols += ["looks_made"] if "n_looks" in results.columns else []
    grouped = results.groupby(RUN_KEYS, sort=True)
    run_of = grouped.ngroup().to_numpy()  # -1: a row whose key holds a NaN (no run)
    keys = list(grouped.size().index)
    order = np.argsort(run_of, kind="stable")  # each run's rows together, in table order
    bounds = np.searchsorted(run_of[order], np.arange(len(keys) + 1))
    status = results["status"].to_numpy(dtype=object)
    error = results["error"].to_numpy(dtype=object)
    floats = {c: results[c].to_numpy(dtype=float) for c in
              {*steps, *track, "tracker_wall_s", "tracker_cpu_s", "select_wall_s",
               "peak_rss_mb", *(["n_looks"] if "n_looks" in results.columns else [])}}
    firsts = order[bounds[:-1]]
    carried = {c: results[c].iloc[firsts].tolist() for c in carry}
    out = []
    for r, (key, start, stop) in enumerate(zip(keys, bounds[:-1], bounds[1:], strict=True)):
        rows = order[start:stop]
        st = status[rows]
        is_ok = st == "ok"
        ok = rows[is_ok]
        all_ok = bool(is_ok.all())
        row = dict(zip(RUN_KEYS, key, strict=True))
        for c in carry:
            row[c] = carried[c][r]
        row["status"] = ("ok" if all_ok
                         else "unsupported" if (st == "unsupported").any() else "error")
        row["error"] = "" if all_ok else str(error[rows[~is_ok][0]])
        row["n_steps"] = len(ok)
        for m in steps:
            row[m] = _nanmean_of(floats[m][ok])
        for m in track:  # constant over the run's rows
            row[m] = float(floats[m][ok[0]]) if all_ok else math.nan
        wall = floats["tracker_wall_s"][ok]
        row["tracker_wall_s"] = float(np.median(wall)) if len(ok) else math.nan
        row["tracker_wall_p95_s"] = float(np.quantile(wall, 0.95)) if len(ok) else math.nan
        row["tracker_wall_max_s"] = float(wall.max()) if len(ok) else math.nan
        row["tracker_cpu_s"] = (float(pd.Series(floats["tracker_cpu_s"][ok]).median())
                                if len(ok) else math.nan)
        row["select_wall_s"] = (float(pd.Series(floats["select_wall_s"][ok]).mean())
                                if len(ok) else math.nan)
        rss = floats["peak_rss_mb"][rows]
        rss = rss[~np.isnan(rss)]
        row["peak_rss_mb"] = float(rss.max()) if rss.size else math.nan
        if "n_looks" in floats:
            row["looks_made"] = _nanmean_of(floats["n_looks"][ok]) if len(ok) else math.nan
        out.append(row)
    return pd.DataFrame(out, columns=cols)


@functools.cache
def t_975(df: int) -> float:
    """Student's t 0.975 quantile with ``df`` degrees of freedom (scipy.stats, imported
    here: it costs a command that never summarises 0.8 s; kept per ``df``, as a report
    asks for the same few thousands of times)."""
    from scipy import stats

    return float(stats.t.ppf(0.975, df))


def mean_ci95(values: np.ndarray) -> tuple[float, float]:
    """Mean and 95% Student-t half-width of ``values (n,)``; NaN half-width if ``n < 2``."""
    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    n = v.size
    if n == 0:
        return math.nan, math.nan
    if n == 1:
        return float(v[0]), math.nan
    half = t_975(n - 1) * v.std(ddof=1) / math.sqrt(n)
    return float(v.mean()), float(half)


def _as_runs(results: pd.DataFrame) -> pd.DataFrame:
    return per_run(results) if "step" in results.columns else results


def summarize(results: pd.DataFrame, by: Sequence[str] = DEFAULT_BY,
              metrics: Sequence[str] | None = None) -> pd.DataFrame:
    """Mean over seeds with 95% t half-widths, one row per group ``by``.

    ``results`` is the step-level table (or the output of :func:`per_run`).
    Columns: ``by``, the carried descriptive columns, ``n_seeds`` (ok runs),
    ``n_errors``, ``n_unsupported``, ``note``, ``looks_made`` (mean looks made per
    step over the ok runs, when known), then ``<m>_mean`` and ``<m>_ci95`` for each
    metric (default: :func:`run_metrics`).
    """
    runs = _as_runs(results)
    metrics = run_metrics(runs) if metrics is None else metrics
    by = list(by)
    carry = [c for c in _CARRY if c in runs.columns and c not in by]
    out = []
    for key, g in runs.groupby(by, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        row = dict(zip(by, key, strict=True))
        for c in carry:
            row[c] = g[c].iloc[0]
        ok = g[g["status"] == "ok"]
        row["n_seeds"] = len(ok)
        row["n_errors"] = int((g["status"] == "error").sum())
        row["n_unsupported"] = int((g["status"] == "unsupported").sum())
        notes = []
        if row["n_unsupported"]:
            notes.append("unsupported: " + g.loc[g["status"] == "unsupported", "error"].iloc[0])
        if row["n_errors"]:
            first = g.loc[g["status"] == "error", "error"].iloc[0]
            notes.append(f"failed in {row['n_errors']} of {len(g)} runs: {first}")
        row["note"] = "; ".join(notes)
        if "looks_made" in runs.columns:
            row["looks_made"] = _nanmean(ok["looks_made"]) if len(ok) else math.nan
        for m in metrics:
            row[f"{m}_mean"], row[f"{m}_ci95"] = mean_ci95(ok[m].to_numpy(dtype=float))
        out.append(row)
    cols = [*by, *carry, "n_seeds", "n_errors", "n_unsupported", "note"]
    cols += ["looks_made"] if "looks_made" in runs.columns else []
    cols += [f"{m}_{s}" for m in metrics for s in ("mean", "ci95")]
    return pd.DataFrame(out, columns=cols)


def paired_difference(results: pd.DataFrame, reference_label: str,
                      metric: str) -> pd.DataFrame:
    """Per ``(scenario, policy_label, looks_per_step)`` and tracker: mean over seeds of
    ``metric(tracker) - metric(reference)`` of the per-run values, paired by seed.

    Only seeds where both runs are ok are paired. Columns: ``scenario,
    policy_label, looks_per_step, tracker_label, reference_label, metric, diff_mean,
    diff_ci95, n_seeds`` (``diff_ci95`` the 95% t half-width of the differences).
    """
    runs = _as_runs(results)
    runs = runs[runs["status"] == "ok"]
    group = ["scenario", "policy_label", "looks_per_step"]
    ref = runs[runs["tracker_label"] == reference_label][[*group, "seed", metric]]
    if ref.empty:
        raise ValueError(f"no ok runs of reference tracker {reference_label!r}")
    others = runs[runs["tracker_label"] != reference_label][
        [*group, "tracker_label", "seed", metric]]
    pairs = others.merge(ref, on=[*group, "seed"], suffixes=("", "_ref"))
    out = []
    for key, g in pairs.groupby([*group, "tracker_label"], sort=True):
        d = (g[metric] - g[f"{metric}_ref"]).to_numpy(dtype=float)
        mean, half = mean_ci95(d)
        out.append({**dict(zip([*group, "tracker_label"], key, strict=True)),
                    "reference_label": reference_label, "metric": metric,
                    "diff_mean": mean, "diff_ci95": half,
                    "n_seeds": int(np.count_nonzero(~np.isnan(d)))})
    return pd.DataFrame(out, columns=[*group, "tracker_label", "reference_label", "metric",
                                      "diff_mean", "diff_ci95", "n_seeds"])


def run_failures(results: pd.DataFrame) -> tuple[int, int, str]:
    """``(k, n, first)``: ``k`` runs of ``n`` failed (a row with ``status == "error"``);
    ``first`` describes the first failed run in the table's order as
    ``scenario/tracker/seed S: message (step k)`` (policy and looks added when the
    table has several), ``""`` if none failed."""
    if results.empty:
        return 0, 0, ""
    n = len(results.drop_duplicates(RUN_KEYS))
    bad = results[results["status"] == "error"].drop_duplicates(RUN_KEYS)
    if bad.empty:
        return 0, n, ""
    r = bad.iloc[0]
    where = f"{r['scenario']}/{r['tracker_label']}"
    if results["policy_label"].nunique() > 1 or results["looks_per_step"].nunique() > 1:
        where += f"/{r['policy_label']}/{r['looks_per_step']} looks"
    where += f"/seed {r['seed']}"
    step = int(r["step"]) if "step" in r.index else -1
    message = str(r["error"]) + (f" (step {step})" if step >= 0 else "")
    return len(bad), n, f"{where}: {message}"


# ---------------------------------------------------- switches around the crossings
#: per-run statistics of :func:`crossing_switches`, as ``(column, header, scale, format)``
CROSSING_STATS = [
    ("switches_near", "switches near crossings", 1.0, ".2f"),
    ("switches_elsewhere", "switches elsewhere", 1.0, ".2f"),
    ("near_rate", "per 100 steps near", 100.0, ".2f"),
    ("elsewhere_rate", "per 100 steps elsewhere", 100.0, ".2f"),
]
_CROSSING_SERIES = ("id_switches_step", "crossings", "crossings_near")


def crossing_switches(results: pd.DataFrame) -> pd.DataFrame:
    """The identity switches of each run around the truth's crossings and elsewhere.

    From the per-step series of :mod:`~mttbench.benchmarks.engine.track_series`: with
    ``s_k`` the CLEAR-MOT switches at step ``k`` (``id_switches_step``) and ``near_k``
    whether ``k`` is within the window of a step where two true targets are closer than
    the crossing distance (``crossings_near``), per run::

        switches_near      = sum_k s_k near_k      near_steps = sum_k near_k
        switches_elsewhere = sum_k s_k (1 - near_k)
        near_rate          = switches_near / near_steps          (NaN if no near step)
        elsewhere_rate     = switches_elsewhere / (n_steps - near_steps)

    and ``crossings`` the close encounters that began in the run. One row per ok run of
    a labelled tracker (a tracker without labels has NaN switches and no row), with
    ``RUN_KEYS``, the carried columns, ``status`` ("ok"), ``error`` (""), ``n_steps`` and
    the columns above; empty (same columns) when the table has no such series.
    """
    carry = [c for c in _CARRY if c in results.columns]
    cols = [*RUN_KEYS, *carry, "status", "error", "n_steps", "crossings", "near_steps",
            *(c for c, *_ in CROSSING_STATS)]
    if not set(_CROSSING_SERIES) <= set(results.columns) or results.empty:
        return pd.DataFrame(columns=cols)
    df = results[[*RUN_KEYS, *carry, "status", *_CROSSING_SERIES]].copy()
    bad = df.groupby(RUN_KEYS, sort=False)["status"].transform(lambda s: (s != "ok").any())
    df = df[~bad]
    sw = df["id_switches_step"].to_numpy(float)
    near = df["crossings_near"].to_numpy(float) > 0
    df = df.assign(_sw_near=np.where(near, sw, 0.0), _sw_far=np.where(near, 0.0, sw),
                   _near=near.astype(float), _n=1.0,
                   _labelled=np.isfinite(sw).astype(float))
    agg = {"_sw_near": "sum", "_sw_far": "sum", "_near": "sum", "_n": "sum",
           "_labelled": "min", "crossings": "sum", **{c: "first" for c in carry}}
    runs = df.groupby(RUN_KEYS, sort=True).agg(agg).reset_index()
    runs = runs[runs["_labelled"] > 0]
    out = runs[[*RUN_KEYS, *carry]].assign(status="ok", error="")
    out["n_steps"] = runs["_n"].astype(int)
    out["crossings"] = runs["crossings"]
    out["near_steps"] = runs["_near"]
    out["switches_near"] = runs["_sw_near"]
    out["switches_elsewhere"] = runs["_sw_far"]
    far = runs["_n"] - runs["_near"]
    with np.errstate(invalid="ignore", divide="ignore"):
        out["near_rate"] = np.where(runs["_near"] > 0, runs["_sw_near"] / runs["_near"],
                                    math.nan)
        out["elsewhere_rate"] = np.where(far > 0, runs["_sw_far"] / far, math.nan)
    return out[cols].reset_index(drop=True)


def crossing_summary(results: pd.DataFrame) -> pd.DataFrame:
    """:func:`summarize` of :func:`crossing_switches` (means over seeds with 95% t
    half-widths of ``crossings``, ``near_steps``, ``n_steps`` and :data:`CROSSING_STATS`)
    for the scenario groups where some run has a crossing; empty otherwise."""
    runs = crossing_switches(results)
    stats_ = ["crossings", "near_steps", "n_steps", *(c for c, *_ in CROSSING_STATS)]
    if runs.empty:
        return summarize(runs, metrics=stats_).iloc[0:0]
    has = runs.groupby(GAP_GROUP)["crossings"].transform("max") > 0
    return summarize(runs[has], metrics=stats_)


# ------------------------------------------------------------------ uses the truth
#: appended to a tracker or policy cell whose runs were given the truth
TRUTH_MARK = " (uses truth)"


def tracker_name(label: str) -> str:
    """The registered name in a tracker label (``gpf(n=3)`` -> ``gpf``)."""
    return str(label).split("(", 1)[0]


def _flagged(table: pd.DataFrame, labels: str, flag: str) -> set[str]:
    """The values of column ``labels`` on the rows of ``table`` whose ``flag`` is true."""
    if labels not in table.columns or flag not in table.columns:
        return set()
    flags = table[flag].astype("boolean").fillna(False).astype(bool)
    return set(table.loc[flags, labels].astype(str))


def truth_labels(table: pd.DataFrame) -> tuple[set[str], set[str]]:
    """``(tracker labels, policy labels)`` of ``table`` (results, per-run or summary rows)
    whose tracker or policy used the truth: the rows' ``tracker_uses_truth`` and
    ``policy_uses_truth`` columns, written by the step loop from each side's class
    (``Tracker.uses_truth``, e.g. ``truth-aided``; ``Policy.uses_truth``, the ``oracle``).
    A table without them marks nothing."""
    return (_flagged(table, "tracker_label", "tracker_uses_truth"),
            _flagged(table, "policy_label", "policy_uses_truth"))


def reference_labels(table: pd.DataFrame) -> set[str]:
    """Tracker labels of ``table`` that are references without the truth, not
    contestants: the stored Bayes reference (:data:`BAYES_TRACKER`) and every tracker
    whose class sets ``Tracker.reference`` (``grid-bayes``)."""
    if "tracker_label" not in table.columns or not len(table):
        return set()
    from ... import trackers

    names = (table["tracker"].astype(str) if "tracker" in table.columns
             else table["tracker_label"].astype(str).map(tracker_name))
    out = set()
    for name, label in set(zip(names, table["tracker_label"].astype(str), strict=True)):
        if name == BAYES_TRACKER:
            out.add(label)
            continue
        try:
            if getattr(trackers.get_class(name), "reference", False):
                out.add(label)
        except Exception:  # noqa: BLE001 - a tracker unknown here (outside:NAME) is none
            pass
    return out


def mark_truth(label: object, users: set[str]) -> str:
    """``label`` with :data:`TRUTH_MARK` appended when it is one of ``users``."""
    return f"{label}{TRUTH_MARK}" if str(label) in users else str(label)


# ------------------------------------------------- floor, ceiling, share of the gap
#: registered name of the floor: reports nothing
FLOOR_TRACKER = "null"
#: registered name of the ceiling: told the count and the association (uses the truth)
CEILING_TRACKER = "truth-aided"
#: label of the converged Bayes reference (:mod:`~mttbench.benchmarks.app.bayes`): no
#: truth, the best achievable on average; a reference, not a contestant
BAYES_TRACKER = "bayes"
#: where the Bayes reference closes less than this share of the floor-to-ceiling gap,
#: the problem (not the trackers) limits accuracy
PROBLEM_LIMITED_SHARE = 0.5
#: a floor-to-ceiling gap below this (OSPA, cells) is too small to rank trackers
MIN_GAP = 0.15
GAP_GROUP = ["scenario", "policy_label", "looks_per_step"]


def ratio_ci95(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """``mean(a) / mean(b)`` and its 95% half-width by the delta method, for paired
    samples ``a, b (n,)``: ``t_{0.975, n-1} * sd(d) / sqrt(n)`` with
    ``d = (a - r b) / mean(b)``. NaN ratio when ``mean(b) <= 0`` (no gap to share),
    NaN half-width when ``n < 2``."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    n = a.size
    if n == 0 or not b.mean() > 0:
        return math.nan, math.nan
    r = float(a.mean() / b.mean())
    if n < 2:
        return r, math.nan
    d = (a - r * b) / b.mean()
    return r, float(t_975(n - 1) * d.std(ddof=1) / math.sqrt(n))


@dataclass(frozen=True)
class GapClosed:
    """Result of :func:`gap_closed`.

    ``gaps``: one row per ``(scenario, policy_label, looks_per_step)`` with
    ``floor_label, ceiling_label, n_pairs, floor_mean, floor_ci95, ceiling_mean,
    ceiling_ci95, gap_mean, gap_ci95, rankable, reason`` (means over the paired seeds;
    ``reason`` is ``""`` or one line starting "this scenario cannot rank trackers: " or
    saying why there is no gap there). ``shares``: one row per group and tracker
    (floor and ceiling included, ``role`` "floor"/"ceiling"/"") with ``n_pairs``,
    ``<metric>_mean``, ``<metric>_ci95`` over its pairs and ``share_mean``,
    ``share_ci95``; only groups where floor and ceiling both have ok runs.
    ``absent`` is ``""`` when floor and ceiling both ran, else the sentence saying
    which did not (and then both tables are empty).

    Where the converged Bayes reference ``bayes`` has rows (attached by
    :func:`~mttbench.benchmarks.app.bayes.attach`), ``gaps`` also has ``bayes_mean,
    bayes_ci95`` (its metric over the seeds it shares with floor and ceiling),
    ``achievable_mean, achievable_ci95`` (``F - B``, the achievable gap),
    ``bayes_share_mean, bayes_share_ci95`` (the share of the floor-to-ceiling gap the
    Bayes filter closes) and ``problem_limited`` (that share below
    :data:`PROBLEM_LIMITED_SHARE`: accuracy is limited by the problem, not by the
    trackers); ``shares`` has ``achievable_mean, achievable_ci95`` (``(F - X) / (F -
    B)``, a tracker's share of the achievable gap, delta-method interval) and
    ``vs_bayes_mean, vs_bayes_ci95`` (``X - B`` paired: a contestant below 0 beyond
    its interval beats the Bayes reference, a finding to explain), NaN elsewhere;
    ``bayes_label`` names it (None when it did not run)."""

    metric: str
    floor_label: str | None
    ceiling_label: str | None
    gaps: pd.DataFrame
    shares: pd.DataFrame
    absent: str
    bayes_label: str | None = None

    @property
    def available(self) -> bool:
        return not self.absent


def _pick_label(runs: pd.DataFrame, name: str) -> str | None:
    """The label of tracker ``name`` used as floor or ceiling: the bare name (default
    parameters) if it ran, else the first of its labels in sorted order."""
    names = (runs["tracker"].astype(str) if "tracker" in runs.columns
             else runs["tracker_label"].astype(str).map(tracker_name))
    labels = sorted(set(runs.loc[names == name, "tracker_label"].astype(str)))
    if not labels:
        return None
    return name if name in labels else labels[0]


def _gap_reason(gap: float, half: float, n: int, min_gap: float, metric: str) -> str:
    """``""`` if the gap can rank trackers, else the one-line reason why not."""
    problems = []
    if gap < min_gap:
        problems.append(f"is below {min_gap:g}")
    if n < 2 or math.isnan(half):
        problems.append("has no interval (one seed)")
    elif gap - half <= 0:
        problems.append("has a 95% interval that reaches 0")
    if not problems:
        return ""
    half_text = "n/a" if math.isnan(half) else f"{half:.3f}"
    return (f"this scenario cannot rank trackers: the {metric} gap between floor and "
            f"ceiling, {gap:.3f} ± {half_text}, " + " and ".join(problems) + ".")


def gap_closed(results: pd.DataFrame, metric: str = "ospa", floor: str = FLOOR_TRACKER,
               ceiling: str = CEILING_TRACKER, min_gap: float = MIN_GAP) -> GapClosed:
    """Floor, ceiling and each tracker's share of the gap closed (see the module
    docstring): ``(F - X) / (F - C)`` of the per-seed means of ``metric`` (lower is
    better), paired by seed, with delta-method 95% intervals (:func:`ratio_ci95`).

    ``results`` is the step table or its :func:`per_run` table. ``floor`` and
    ``ceiling`` are registered tracker names; when one did not run at all, both tables
    are empty and :attr:`GapClosed.absent` says why; a group where one has no ok run
    gets a ``gaps`` row with ``n_pairs = 0`` and the reason, and no shares.
    """
    runs = _as_runs(results)
    name = column_label(metric)
    f_label, c_label = _pick_label(runs, floor), _pick_label(runs, ceiling)
    missing = [f"the {role} `{n}`" for role, n, lab in (("floor", floor, f_label),
                                                         ("ceiling", ceiling, c_label))
               if lab is None]
    gap_cols = [*GAP_GROUP, "floor_label", "ceiling_label", "n_pairs", "floor_mean",
                "floor_ci95", "ceiling_mean", "ceiling_ci95", "gap_mean", "gap_ci95",
                "rankable", "reason", "bayes_mean", "bayes_ci95", "achievable_mean",
                "achievable_ci95", "bayes_share_mean", "bayes_share_ci95", "problem_limited"]
    share_cols = [*GAP_GROUP, "tracker_label", "role", "n_pairs", f"{metric}_mean",
                  f"{metric}_ci95", "share_mean", "share_ci95", "achievable_mean",
                  "achievable_ci95", "vs_bayes_mean", "vs_bayes_ci95"]
    b_label = _pick_label(runs, BAYES_TRACKER)
    if missing:
        absent = (" and ".join(missing) + " did not run, so no tracker's share of the "
                  f"{name} gap between floor and ceiling can be computed (run `{floor}` and "
                  f"`{ceiling}` among the trackers to see it).")
        absent = absent[0].upper() + absent[1:]
        return GapClosed(metric, f_label, c_label, pd.DataFrame(columns=gap_cols),
                         pd.DataFrame(columns=share_cols), absent)

    ok = runs[runs["status"] == "ok"]
    truth_users = set().union(*truth_labels(runs)) if len(runs) else set()
    # references without the truth (bayes, grid-bayes) never count as contestants
    truth_users |= reference_labels(runs)
    wide_all = ok.pivot_table(index=[*GAP_GROUP, "seed"], columns="tracker_label",
                              values=metric, aggfunc="first")
    gaps, shares = [], []
    for key, g in runs.groupby(GAP_GROUP, sort=True):
        key_d = dict(zip(GAP_GROUP, key, strict=True))
        try:
            wide = wide_all.xs(key, level=GAP_GROUP) if len(wide_all) else pd.DataFrame()
        except KeyError:
            wide = pd.DataFrame()
        row = {**key_d, "floor_label": f_label, "ceiling_label": c_label, "n_pairs": 0,
               **dict.fromkeys(["floor_mean", "floor_ci95", "ceiling_mean", "ceiling_ci95",
                                "gap_mean", "gap_ci95", "bayes_mean", "bayes_ci95",
                                "achievable_mean", "achievable_ci95", "bayes_share_mean",
                                "bayes_share_ci95"], math.nan), "rankable": False,
               "problem_limited": False}
        absent_here = [f"the {role} `{lab}`" for role, lab in (("floor", f_label),
                                                               ("ceiling", c_label))
                       if lab not in wide.columns or wide[lab].notna().sum() == 0]
        if absent_here:
            row["reason"] = (f"no {name} gap here: " + " and ".join(absent_here)
                             + (" have" if len(absent_here) > 1 else " has") + " no ok run")
            gaps.append(row)
            continue
        both = wide[[f_label, c_label]].dropna()
        fl, ce = both[f_label].to_numpy(float), both[c_label].to_numpy(float)
        n = len(both)
        row["n_pairs"] = n
        row["floor_mean"], row["floor_ci95"] = mean_ci95(fl)
        row["ceiling_mean"], row["ceiling_ci95"] = mean_ci95(ce)
        row["gap_mean"], row["gap_ci95"] = mean_ci95(fl - ce)
        row["reason"] = _gap_reason(row["gap_mean"], row["gap_ci95"], n, min_gap, name)
        has_bayes = b_label is not None and b_label in wide.columns and \
            wide[b_label].notna().sum() >= 1
        if has_bayes:
            trio = wide[[f_label, c_label, b_label]].dropna()
            fl_b, b = trio[f_label].to_numpy(float), trio[b_label].to_numpy(float)
            row["bayes_mean"], row["bayes_ci95"] = mean_ci95(b)
            row["achievable_mean"], row["achievable_ci95"] = mean_ci95(fl_b - b)
            row["bayes_share_mean"], row["bayes_share_ci95"] = ratio_ci95(
                fl_b - b, fl_b - trio[c_label].to_numpy(float))
            row["problem_limited"] = bool(row["bayes_share_mean"] < PROBLEM_LIMITED_SHARE)
        gaps.append(row)
        beats_floor = False
        for lab in sorted(set(g["tracker_label"].astype(str))):
            if lab not in wide.columns:
                continue
            if lab not in (f_label, c_label, b_label) and lab not in truth_users:
                # a contestant beats the floor when its paired difference's 95% interval
                # lies above 0 (lower is better)
                pair = wide[[f_label]].assign(_x=wide[lab]).dropna()
                d_mean, d_half = mean_ci95(pair[f_label].to_numpy(float)
                                           - pair["_x"].to_numpy(float))
                beats_floor |= bool(len(pair) >= 2 and d_mean - d_half > 0)
            trio = wide[[f_label, c_label]].assign(_x=wide[lab]).dropna()
            x = trio["_x"].to_numpy(float)
            a = trio[f_label].to_numpy(float) - x
            b = trio[f_label].to_numpy(float) - trio[c_label].to_numpy(float)
            share, half = ratio_ci95(a, b)
            mean, mhalf = mean_ci95(x)
            achievable = dict.fromkeys(["achievable_mean", "achievable_ci95", "vs_bayes_mean",
                                        "vs_bayes_ci95"], math.nan)
            if has_bayes:
                quad = wide[[f_label, c_label, b_label]].assign(_x=wide[lab]).dropna()
                xb, fb = quad["_x"].to_numpy(float), quad[f_label].to_numpy(float)
                bb = quad[b_label].to_numpy(float)
                achievable["achievable_mean"], achievable["achievable_ci95"] = ratio_ci95(
                    fb - xb, fb - bb)
                achievable["vs_bayes_mean"], achievable["vs_bayes_ci95"] = mean_ci95(xb - bb)
            shares.append({**key_d, "tracker_label": lab,
                           "role": ("floor" if lab == f_label else
                                    "ceiling" if lab == c_label else
                                    "bayes" if lab == b_label else ""),
                           "n_pairs": len(trio), f"{metric}_mean": mean,
                           f"{metric}_ci95": mhalf, "share_mean": share, "share_ci95": half,
                           **achievable})
        if not row["reason"] and not beats_floor:
            row["reason"] = (f"this scenario cannot rank trackers: no contestant's {name} "
                             f"beats the floor `{f_label}` within its 95% interval.")
        row["rankable"] = not row["reason"]
    return GapClosed(metric, f_label, c_label, pd.DataFrame(gaps, columns=gap_cols),
                     pd.DataFrame(shares, columns=share_cols), "", b_label)


# ------------------------------------------------------------------------ markdown
def md_cell(value: object) -> str:
    """Text of one Markdown table cell: ``|`` escaped, line breaks as spaces."""
    text = str(value).replace("\r", " ").replace("\n", " ")
    return text.replace("|", "\\|")


def looks_text(budget: object, made: object) -> str:
    """The looks cell: the budget, with the looks made per step when they differ
    (``200 (144 made)``)."""
    text = str(budget)
    try:
        m = float(made)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return text
    if math.isnan(m) or abs(m - float(budget)) < 1e-9:  # type: ignore[arg-type]
        return text
    return f"{text} ({m:.4g} made)"



def markdown_metrics() -> list[tuple[str, str, float, str]]:
    """``(column stem, header, scale, format)`` of the default markdown table: the
    headline of every registered metric (display order), time per step, gap closed."""
    return [*((m.name, m.label, m.scale, m.fmt) for m in display_metrics()),
            ("tracker_wall_s", "ms/step", 1e3, ".3g"), ("gap_closed", "gap closed", 1.0, ".2f"),
            ("achievable_closed", "of achievable", 1.0, ".2f")]


def _pm(mean: float, half: float, scale: float, fmt: str) -> str:
    if mean is None or (isinstance(mean, float) and math.isnan(mean)):
        return "–"
    text = format(mean * scale, fmt)
    if half is None or math.isnan(half):
        return text + " ± n/a"
    return f"{text} ± {format(half * scale, fmt)}"


def to_markdown(summary: pd.DataFrame,
                metrics: Sequence[tuple[str, str, float, str]] | None = None) -> str:
    """A Markdown table of a :func:`summarize` output, cells as ``mean ± half-width``.

    ``metrics`` lists ``(stem, header, scale, format)`` (default
    :func:`markdown_metrics`); stems missing from the summary are skipped. Times are
    shown in milliseconds per step (median per run, mean over seeds). A ``note`` column
    appears when any row has one.
    """
    keys = [c for c in ("scenario", "tracker_label", "policy_label", "looks_per_step")
            if c in summary.columns]
    headers = {"scenario": "scenario", "tracker_label": "tracker", "policy_label": "policy",
               "looks_per_step": "looks"}
    metrics = markdown_metrics() if metrics is None else metrics
    shown = [m for m in metrics if f"{m[0]}_mean" in summary.columns]
    with_note = "note" in summary.columns and (summary["note"].astype(str) != "").any()
    head = [headers[k] for k in keys] + ["seeds"] + [m[1] for m in shown]
    head += ["note"] if with_note else []
    align = ["---"] * len(keys) + ["---:"] * (1 + len(shown)) + (["---"] if with_note else [])
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(align) + "|"]
    truth_trackers, truth_policies = truth_labels(summary)
    for _, r in summary.iterrows():
        cells = [str(r[k]) for k in keys] + [str(r.get("n_seeds", ""))]
        if "tracker_label" in keys:
            cells[keys.index("tracker_label")] = mark_truth(r["tracker_label"], truth_trackers)
        if "policy_label" in keys:
            cells[keys.index("policy_label")] = mark_truth(r["policy_label"], truth_policies)
        if "looks_per_step" in keys and r.get("policy_label") == "none":
            cells[keys.index("looks_per_step")] = "–"  # superposition: no looks
        elif "looks_per_step" in keys and "looks_made" in summary.columns:
            cells[keys.index("looks_per_step")] = looks_text(r["looks_per_step"],
                                                             r["looks_made"])
        cells += [_pm(r[f"{s}_mean"], r[f"{s}_ci95"], scale, fmt) for s, _, scale, fmt in shown]
        if with_note:
            cells.append(str(r["note"]))
        lines.append("| " + " | ".join(md_cell(c) for c in cells) + " |")
    lines.append("")
    lines.append("Mean over seeds ± half-width of the 95% Student-t interval; "
                 "ms/step = median tracker time per step (predict + update + estimate); "
                 "looks = the budget per step, with the looks made when fewer or more.")
    if any(m[0] == "gap_closed" for m in shown):
        lines.append(f"gap closed = (OSPA_{FLOOR_TRACKER} - OSPA) / (OSPA_{FLOOR_TRACKER} - "
                     f"OSPA_{CEILING_TRACKER}) over the seeds where all three runs are ok "
                     "(1 = as good as the ceiling, 0 = no better than reporting nothing), "
                     "± its 95% delta-method half-width.")
    if any(m[0] == "achievable_closed" for m in shown):
        lines.append(f"of achievable = (OSPA_{FLOOR_TRACKER} - OSPA) / (OSPA_{FLOOR_TRACKER} - "
                     f"OSPA_{BAYES_TRACKER}): the share of the gap to the converged Bayes "
                     "reference (no truth; `mttbench bayes`, docs/bayes.md), where it is "
                     "stored.")
    if truth_trackers or truth_policies:
        lines.append(f"`{TRUTH_MARK.strip()}`: the tracker or policy was given the truth "
                     "(a reference, not a competitor).")
    return "\n".join(lines) + "\n"


def with_gap_closed(summ: pd.DataFrame, gc: GapClosed) -> pd.DataFrame:
    """``summ`` (a :func:`summarize` output) with ``gap_closed_mean`` and
    ``gap_closed_ci95`` (each tracker's share of the floor-to-ceiling gap of
    :func:`gap_closed`) when floor and ceiling ran; unchanged otherwise."""
    if not gc.available or gc.shares.empty or "tracker_label" not in summ.columns:
        return summ
    keys = [*GAP_GROUP, "tracker_label"]
    if not set(keys) <= set(summ.columns):
        return summ
    cols = {"share_mean": "gap_closed_mean", "share_ci95": "gap_closed_ci95"}
    if gc.bayes_label is not None and gc.shares["achievable_mean"].notna().any():
        cols |= {"achievable_mean": "achievable_closed_mean",
                 "achievable_ci95": "achievable_closed_ci95"}
    add = gc.shares[[*keys, *cols]].rename(columns=cols)
    return summ.merge(add, on=keys, how="left")


def group_text(scenario: object, policy: object, looks: object) -> str:
    """```paper` (raster, 24 looks)``; ```superposition` (no looks)`` without cells."""
    if str(policy) == "none":
        return f"`{scenario}` (no looks)"
    return f"`{scenario}` ({policy}, {looks} looks)"


def gap_notes(gc: GapClosed) -> list[str]:
    """One line per group that cannot rank trackers (or has no gap), or the sentence
    saying why floor and ceiling are missing."""
    if not gc.available:
        return [gc.absent]
    out = []
    for r in gc.gaps.itertuples(index=False):
        if r.reason:
            out.append(f"{group_text(r.scenario, r.policy_label, r.looks_per_step)}: "
                       f"{r.reason}")
    return out


def track_markdown_metrics() -> list[tuple[str, str, float, str]]:
    """``(column stem, header, scale, format)`` of the track-level table of
    ``summary.md``: the headline of every registered run-level metric but the per-step
    series (registration order)."""
    series = set(series_columns())
    return [(m.name, m.label, m.scale, m.fmt) for m in registered_run_metrics()
            if m.name not in series]


def track_markdown(runs: pd.DataFrame, summ: pd.DataFrame,
                   crossings: pd.DataFrame | None = None) -> str:
    """The track-level sections of ``summary.md`` (``""`` when ``summ``, a
    :func:`summarize` output, has no track score): the headline of each track score per
    labelled tracker, the trackers without labels, and (``crossings``, a
    :func:`crossing_summary`) the switches around the crossings."""
    shown = [m for m in track_markdown_metrics() if f"{m[0]}_mean" in summ.columns]
    if not shown:
        return ""
    unlabelled = unlabelled_trackers(runs)
    labelled = summ[~summ["tracker_label"].astype(str).isin(unlabelled)]
    params = "; ".join(f"{m.label}: " + ", ".join(f"{k} = {v:g}" for k, v in m.params.items())
                       for m in registered_run_metrics() if m.params)
    text = ("\n## Track-level scores\n\nWhole runs scored on the trackers' track labels "
            "against the true ids (trajectory GOSPA in workspace units, OSPA(2) the mean "
            "over steps of its sliding window, ID switches and fragmentations counts per "
            "run, mostly tracked / lost shares of the targets); parameters: "
            f"{params}.\n\n" + to_markdown(labelled, shown))
    if unlabelled:
        text += ("\nNo track-level scores for " + ", ".join(f"`{t}`" for t in unlabelled)
                 + ": no persistent track labels, so no identity to score.\n")
    if crossings is not None and not crossings.empty:
        text += ("\n## Identity switches around the crossings\n\nCLEAR-MOT switches per "
                 "run at the steps within the window of two true targets closer than the "
                 "crossing distance, and at the other steps; and per 100 such steps.\n\n"
                 + to_markdown(crossings, [(c, h, s, f) for c, h, s, f in CROSSING_STATS]))
    return text


def cutoff_text(results: pd.DataFrame) -> str:
    """The OSPA/GOSPA cut-off ``c`` of the rows with its units, per scenario when they
    differ: ``"c = 2 (2 cells of 1), p = 2"``; the cells where the scenario is a preset
    or a readable file (its cell size), else world units."""
    from ...scenarios import spec

    cp = (results[["scenario", "ospa_c", "ospa_p"]].dropna().drop_duplicates("scenario")
          if {"ospa_c", "ospa_p"} <= set(results.columns) else pd.DataFrame())
    if not len(cp):
        return "c and p not recorded"
    texts = {}
    for sc, c, p in cp.itertuples(index=False):
        try:
            size = spec.get(str(sc)).grid.cell_size
            text = describe_cutoff(float(c), size)
        except Exception:  # noqa: BLE001  (an outside scenario: its cell size is unknown)
            text = f"{float(c):g} world units"
        texts[sc] = f"c = {text}, p = {float(p):g}"
    if len(set(texts.values())) == 1:
        return next(iter(texts.values()))
    return "; ".join(f"{sc}: {t}" for sc, t in texts.items())


def write_summary(results: pd.DataFrame, out_dir: str | Path, title: str,
                  notes: Sequence[str] = (), sections: Sequence[str] = (), *,
                  runs: pd.DataFrame | None = None, summ: pd.DataFrame | None = None,
                  gc: GapClosed | None = None) -> str:
    """Write ``summary.csv`` and ``summary.md`` (headed ``title``) of ``results`` into
    ``out_dir``, each all or nothing; return the Markdown text. ``notes``: more lines
    listed under the table (``compare``: which parameters each tracker ran).
    ``summary.md`` then has the track-level sections of :func:`track_markdown` (the
    switches around the crossings only from a step table with the per-step series), then
    ``sections`` (Markdown; ``compare`` and ``run``: the tracker x policy tables).
    ``runs``, ``summ``, ``gc``: :func:`per_run`, :func:`summarize` and :func:`gap_closed`
    of ``results`` when the caller has them already (computed here when None)."""
    from ..engine.store import write_text_atomic

    out_dir = Path(out_dir)
    runs = _as_runs(results) if runs is None else runs
    summ = summarize(runs) if summ is None else summ
    table = with_gap_closed(summ, gc := gap_closed(runs) if gc is None else gc)
    write_text_atomic(out_dir / "summary.csv", table.to_csv(index=False))
    text = f"# {title}\n\n" + to_markdown(table)
    extra = [f"OSPA/GOSPA cut-off and order: {cutoff_text(results)} (the default c is "
             "2 cells)", *gap_notes(gc), *notes]
    if extra:
        text += "\n" + "\n".join(f"- {line}" for line in extra) + "\n"
    text += track_markdown(runs, table, crossing_summary(results))
    for section in sections:
        text += "\n" + section.rstrip("\n") + "\n"
    write_text_atomic(out_dir / "summary.md", text)
    return text

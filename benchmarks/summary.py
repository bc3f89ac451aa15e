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
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

#: per-step metrics averaged over the steps of a run (nanmean: rmse is NaN when
#: nothing is assigned)
STEP_METRICS = [
    "ospa", "ospa_loc", "ospa_card", "gospa", "gospa_loc", "gospa_missed", "gospa_false",
    "count_error", "rmse",
]
#: per-run statistics summarised over seeds, in display order
RUN_METRICS = [*STEP_METRICS, "tracker_wall_s", "tracker_cpu_s", "select_wall_s", "peak_rss_mb"]
RUN_KEYS = ["scenario", "tracker_label", "policy_label", "looks_per_step", "seed"]
DEFAULT_BY = ("scenario", "tracker_label", "policy_label", "looks_per_step")
# descriptive columns carried along when present (constant within a run)
_CARRY = ["tracker", "policy", "uses_truth"]


def _nanmean(x: pd.Series) -> float:
    v = x.to_numpy(dtype=float)
    v = v[~np.isnan(v)]
    return float(v.mean()) if v.size else math.nan


def per_run(results: pd.DataFrame) -> pd.DataFrame:
    """One row per run ``(scenario, tracker_label, policy_label, looks_per_step, seed)``.

    Step metrics are averaged over the run's ``"ok"`` steps (NaN-aware);
    ``tracker_wall_s`` and ``tracker_cpu_s`` are the median per-step times,
    ``select_wall_s`` the mean per-step selection time, ``peak_rss_mb`` the maximum.
    ``status`` is ``"ok"`` if every step was ok, else ``"unsupported"`` or
    ``"error"``; ``error`` holds the first message; ``n_steps`` counts ok steps;
    ``looks_made`` is the mean number of looks made per ok step (when the table has
    ``n_looks``).
    """
    carry = [c for c in _CARRY if c in results.columns]
    out = []
    for key, g in results.groupby(RUN_KEYS, sort=True):
        ok = g[g["status"] == "ok"]
        row = dict(zip(RUN_KEYS, key, strict=True))
        for c in carry:
            row[c] = g[c].iloc[0]
        statuses = set(g["status"])
        row["status"] = ("ok" if statuses == {"ok"}
                         else "unsupported" if "unsupported" in statuses else "error")
        bad = g.loc[g["status"] != "ok", "error"]
        row["error"] = str(bad.iloc[0]) if len(bad) else ""
        row["n_steps"] = len(ok)
        for m in STEP_METRICS:
            row[m] = _nanmean(ok[m])
        row["tracker_wall_s"] = float(ok["tracker_wall_s"].median()) if len(ok) else math.nan
        row["tracker_cpu_s"] = float(ok["tracker_cpu_s"].median()) if len(ok) else math.nan
        row["select_wall_s"] = float(ok["select_wall_s"].mean()) if len(ok) else math.nan
        row["peak_rss_mb"] = float(g["peak_rss_mb"].max())
        if "n_looks" in g.columns:
            row["looks_made"] = _nanmean(ok["n_looks"]) if len(ok) else math.nan
        out.append(row)
    cols = [*RUN_KEYS, *carry, "status", "error", "n_steps", *RUN_METRICS]
    cols += ["looks_made"] if "n_looks" in results.columns else []
    return pd.DataFrame(out, columns=cols)


def mean_ci95(values: np.ndarray) -> tuple[float, float]:
    """Mean and 95% Student-t half-width of ``values (n,)``; NaN half-width if ``n < 2``."""
    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    n = v.size
    if n == 0:
        return math.nan, math.nan
    if n == 1:
        return float(v[0]), math.nan
    half = stats.t.ppf(0.975, n - 1) * v.std(ddof=1) / math.sqrt(n)
    return float(v.mean()), float(half)


def _as_runs(results: pd.DataFrame) -> pd.DataFrame:
    return per_run(results) if "step" in results.columns else results


def summarize(results: pd.DataFrame, by: Sequence[str] = DEFAULT_BY,
              metrics: Sequence[str] = RUN_METRICS) -> pd.DataFrame:
    """Mean over seeds with 95% t half-widths, one row per group ``by``.

    ``results`` is the step-level table (or the output of :func:`per_run`).
    Columns: ``by``, the carried descriptive columns, ``n_seeds`` (ok runs),
    ``n_errors``, ``n_unsupported``, ``note``, ``looks_made`` (mean looks made per
    step over the ok runs, when known), then ``<m>_mean`` and ``<m>_ci95`` for each
    metric.
    """
    runs = _as_runs(results)
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



#: (column stem, header, scale, format) of the default markdown table
MARKDOWN_METRICS = [
    ("ospa", "OSPA", 1.0, ".3f"),
    ("gospa", "GOSPA", 1.0, ".3f"),
    ("count_error", "count err", 1.0, ".3f"),
    ("rmse", "RMSE", 1.0, ".3f"),
    ("tracker_wall_s", "ms/step", 1e3, ".3g"),
]


def _pm(mean: float, half: float, scale: float, fmt: str) -> str:
    if mean is None or (isinstance(mean, float) and math.isnan(mean)):
        return "–"
    text = format(mean * scale, fmt)
    if half is None or math.isnan(half):
        return text + " ± n/a"
    return f"{text} ± {format(half * scale, fmt)}"


def to_markdown(summary: pd.DataFrame,
                metrics: Sequence[tuple[str, str, float, str]] = MARKDOWN_METRICS) -> str:
    """A Markdown table of a :func:`summarize` output, cells as ``mean ± half-width``.

    ``metrics`` lists ``(stem, header, scale, format)``; stems missing from the
    summary are skipped. Times are shown in milliseconds per step (median per run,
    mean over seeds). A ``note`` column appears when any row has one.
    """
    keys = [c for c in ("scenario", "tracker_label", "policy_label", "looks_per_step")
            if c in summary.columns]
    headers = {"scenario": "scenario", "tracker_label": "tracker", "policy_label": "policy",
               "looks_per_step": "looks"}
    shown = [m for m in metrics if f"{m[0]}_mean" in summary.columns]
    with_note = "note" in summary.columns and (summary["note"].astype(str) != "").any()
    head = [headers[k] for k in keys] + ["seeds"] + [m[1] for m in shown]
    head += ["note"] if with_note else []
    align = ["---"] * len(keys) + ["---:"] * (1 + len(shown)) + (["---"] if with_note else [])
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(align) + "|"]
    for _, r in summary.iterrows():
        cells = [str(r[k]) for k in keys] + [str(r.get("n_seeds", ""))]
        truth = r.get("uses_truth", False)
        if "policy_label" in keys and isinstance(truth, bool | np.bool_) and truth:
            cells[keys.index("policy_label")] += " (uses truth)"
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
    return "\n".join(lines) + "\n"


def write_summary(results: pd.DataFrame, out_dir: str | Path, title: str) -> str:
    """Write ``summary.csv`` and ``summary.md`` (headed ``title``) of ``results`` into
    ``out_dir``, each all or nothing; return the Markdown text."""
    from .harness import write_text_atomic

    out_dir = Path(out_dir)
    table = summarize(results)
    write_text_atomic(out_dir / "summary.csv", table.to_csv(index=False))
    text = f"# {title}\n\n" + to_markdown(table)
    write_text_atomic(out_dir / "summary.md", text)
    return text

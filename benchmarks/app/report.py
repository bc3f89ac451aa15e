"""Report builder: tables with 95% intervals, paired differences, figures, Markdown + HTML.

:func:`build_report` turns a results table (one row per scenario x tracker x policy x
looks x seed x step, see :mod:`benchmarks.engine.loop`) into a report folder::

    report.md       the verdict (:mod:`.verdict`: who leads where, the gaps, what cannot
                    be ranked, the costs, the share of the gap closed as a figure), then
                    tables and links to figures/*.png, the settings last
    report.html     the same, self-contained (figures embedded as base64 PNG)
    figures/*.png   OSPA and count error over time, OSPA(2) over time (when the
                    results have track labels), runtime per step, accuracy against
                    runtime, and (if a trace is given) a snapshot of one run

Every number is a mean over seeds of per-run values (each run's steps averaged
first; times are the run's median per-step time) with the half-width of the 95%
Student-t interval, ``t_{0.975, n-1} * sd / sqrt(n)`` (:func:`benchmarks.app.summary.mean_ci95`).
Paired differences subtract the reference tracker's per-run value from the same seed's
run of each other tracker before averaging (common random numbers make the pairs
strongly correlated, so paired intervals are much narrower than the difference of
two unpaired ones).

When the floor ``null`` and the ceiling ``truth-aided`` ran, a section puts them side
by side with every tracker and gives each tracker's share of the OSPA gap closed,
``(OSPA_null - OSPA) / (OSPA_null - OSPA_truth-aided)``, with a delta-method 95%
interval over the paired seeds (:func:`benchmarks.app.summary.gap_closed`), and flags every
scenario whose gap is too small to rank trackers (below 0.15, or its interval reaching
0). Without them the section says which did not run. Trackers and policies given the
truth are marked `` (uses truth)`` in every table.

When a scenario ran under several policies, the verdict names the best tracker-policy
pair per scenario and a section gives the tracker x policy table with the paired
differences between policies (:mod:`benchmarks.app.policy_axis`); the figures then have
one panel per scenario and policy.

Check a report in a real browser (headless Debian chromium; writes ``screenshot.png``
into the report folder)::

    mttbench screenshot reports/compare-<timestamp>
"""

from __future__ import annotations

import base64
import html
import math
import multiprocessing
import shutil
import signal
import subprocess
import tempfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from ... import trackers
from ..engine.executors import stop_pool
from ..engine.metrics import (
    Metric,
    column_label,
    display_metrics,
    get_metric,
    registered_run_metrics,
)
from ..engine.store import write_text_atomic
from . import figures, policy_axis, summary, verdict

#: metrics shown in a table of their own (GOSPA: its parts are p-th-power costs)
_OWN_TABLE = ("gospa",)


def metric_table_columns(metric: Metric) -> list[tuple[str, str, float, str]]:
    """``(column stem, header, scale, format)`` of every column of ``metric``."""
    return [(c, metric.column_label(c), metric.scale, metric.fmt) for c in metric.columns]


def accuracy_columns() -> list[tuple[str, str, float, str]]:
    """The accuracy table's columns: those of every registered metric (display order)
    but the ones with a table of their own."""
    return [col for m in display_metrics() if m.name not in _OWN_TABLE
            for col in metric_table_columns(m)]


def paired_columns() -> list[tuple[str, str, float, str]]:
    """``(metric, header, scale, format)`` of the paired-difference table: the headline
    of every ranked metric (display order), then the tracker time."""
    return [*((m.name, f"Δ {m.label}", m.scale, m.fmt) for m in display_metrics() if m.ranked),
            ("tracker_wall_s", "Δ ms/step", 1e3, ".3g")]


#: (column stem, header, scale, format) of the accuracy table (the built-ins';
#: :func:`accuracy_columns` adds the metrics registered later)
ACCURACY_COLUMNS = accuracy_columns()
#: (column stem, header, scale, format) of the GOSPA table
GOSPA_COLUMNS = metric_table_columns(get_metric("gospa"))
def track_columns() -> list[tuple[str, str, float, str]]:
    """``(column stem, header, scale, format)`` of the track-level table: every column of
    every registered run-level metric but the per-step series (registration order)."""
    series = set(summary.series_columns())
    return [col for m in registered_run_metrics() for col in metric_table_columns(m)
            if col[0] not in series]


def _track_section(doc: Document, runs: pd.DataFrame, summ: pd.DataFrame,
                   tuned_on: dict[str, frozenset[str]] | None,
                   crossings: pd.DataFrame | None = None) -> None:
    """The track-level scores: one table per scenario, a line naming the trackers
    without labels (no track identity, so no track-level score), and per scenario with
    crossings the switches around them (``crossings``: a
    :func:`benchmarks.app.summary.crossing_summary`)."""
    metrics = registered_run_metrics()
    cols = [c for c in track_columns() if f"{c[0]}_mean" in summ.columns]
    if not cols:
        return
    doc.add("h2", "Track-level scores")
    params = "; ".join(f"{m.label}: " + ", ".join(f"{k} = {v:g}" for k, v in m.params.items())
                       for m in metrics if m.params)
    doc.add("p", "Scores of whole runs that see identities: the tracker's persistent track "
                 "labels against the true target ids; mean over seeds of each run's value, "
                 "± 95% t half-width. Trajectory GOSPA (Garcia-Fernandez, Rahmathullah & "
                 "Svensson 2020; alpha = 2, cut-off c and order p of the run, switching cost "
                 "gamma; the LP metric solved with HiGHS) is in workspace units, its parts "
                 "(localisation, missed, false, switch) are costs in the p-th-power domain "
                 "summed over the run. OSPA(2) (Beard, Vo & Vo 2020) is the mean over steps of "
                 "OSPA between the tracks in a sliding window, with the time-averaged distance "
                 "of two tracks as base distance. ID switches and fragmentations are counts per "
                 "run from CLEAR-MOT correspondences within the gate (Bernardin & "
                 "Stiefelhagen 2008); mostly tracked / mostly lost are the shares of the "
                 "targets covered on >= 80% / <= 20% of their lifetime. Parameters: "
                 f"{params}.")
    unlabelled = summary.unlabelled_trackers(runs)
    shown = summ[~summ["tracker_label"].astype(str).isin(unlabelled)]
    for sc in sorted(shown["scenario"].astype(str).unique()):
        doc.add("h3", sc)
        table = summary_table(shown[shown["scenario"].astype(str) == sc], cols)
        doc.add("table", mark_out_of_sample(table, tuned_on).drop(columns=["scenario"],
                                                                   errors="ignore"))
    if unlabelled:
        doc.add("p", "No track-level scores for " + ", ".join(f"`{t}`" for t in unlabelled)
                + ": these trackers report no persistent track labels (a Gaussian mixture "
                  "or a weighted field without track identity, or no estimate at all), so "
                  "there is no identity to score.")
    _crossing_section(doc, crossings, tuned_on)


def crossing_table(crossings: pd.DataFrame) -> pd.DataFrame:
    """Display table of :func:`benchmarks.app.summary.crossing_summary` rows: the
    switches per run near the crossings and elsewhere, and per 100 steps of each."""
    return summary_table(crossings, summary.CROSSING_STATS)


def crossing_sentence(crossings: pd.DataFrame) -> str:
    """What the truth of one scenario's rows holds: crossings per run and the steps
    near them (the same worlds for every tracker; the first tracker's seeds)."""
    r = crossings.iloc[0]
    return (f"`{r['scenario']}`: {fmt_pm(r['crossings_mean'], r['crossings_ci95'], 1, '.1f')} "
            f"crossings per run, {fmt_pm(r['near_steps_mean'], r['near_steps_ci95'], 1, '.1f')}"
            f" of {r['n_steps_mean']:.0f} steps near one.")


def _crossing_section(doc: Document, crossings: pd.DataFrame | None,
                      tuned_on: dict[str, frozenset[str]] | None) -> None:
    if crossings is None or crossings.empty:
        return
    spec = next((m for m in registered_run_metrics() if m.name == "crossings"), None)
    if spec is None:
        return
    doc.add("h3", "Identity switches around the crossings")
    doc.add("p", "A crossing: two true targets closer than "
                 f"{spec.params['distance']:g} (the CLEAR-MOT gate: a track within the gate of "
                 "one is then within reach of the other); a step is near a crossing when it is "
                 f"within {spec.params['window']:g} steps of such a step. Per run, the "
                 "CLEAR-MOT identity switches at the steps near a crossing and at the other "
                 "steps, and per 100 steps of each; mean over seeds ± 95% t half-width. A "
                 "tracker that keeps identities through crossings has few switches near them; "
                 "switches elsewhere come from lost and re-acquired targets.")
    for sc in sorted(crossings["scenario"].astype(str).unique()):
        here = crossings[crossings["scenario"].astype(str) == sc]
        doc.add("p", crossing_sentence(here))
        doc.add("table", mark_out_of_sample(crossing_table(here), tuned_on)
                .drop(columns=["scenario"], errors="ignore"))


#: (column stem, header, scale, format) of the runtime table
RUNTIME_COLUMNS = [
    ("tracker_wall_s", "tracker ms/step", 1e3, ".3g"),
    ("tracker_wall_p95_s", "95th pct ms", 1e3, ".3g"),
    ("tracker_wall_max_s", "slowest step ms", 1e3, ".3g"),
    ("tracker_cpu_s", "tracker CPU ms/step", 1e3, ".3g"),
    ("select_wall_s", "selection ms/step", 1e3, ".3g"),
    ("peak_rss_mb", "peak RSS MB", 1.0, ".0f"),
]
#: (metric, header, scale, format) of the paired-difference table (the built-ins';
#: :func:`paired_columns` adds the metrics registered later)
PAIRED_COLUMNS = paired_columns()
_KEY_HEADERS = {"scenario": "scenario", "tracker_label": "tracker", "policy_label": "policy",
                "looks_per_step": "looks"}


def fmt_pm(mean: float, half: float, scale: float = 1.0, fmt: str = ".3f") -> str:
    """``mean ± half`` (scaled), ``–`` for a missing mean and ``± n/a`` for one seed."""
    if mean is None or (isinstance(mean, float) and math.isnan(mean)):
        return "–"
    text = _num(mean * scale, fmt)
    if half is None or (isinstance(half, float) and math.isnan(half)):
        return text + " ± n/a"
    # rounding noise of a constant (e.g. 4.99e-16) reads better as 0
    small = abs(half * scale) <= 1e-9 * max(abs(mean * scale), 1e-300)
    return f"{text} ± {'0' if small else _num(half * scale, fmt)}"


def _num(x: float, fmt: str) -> str:
    """``format(x, fmt)``; ``g`` formats keep their significant trailing zeros (1.00)."""
    if fmt.endswith("g"):
        return format(x, "#" + fmt).rstrip(".")
    return format(x, fmt)


# ----------------------------------------------------------------------- tables
def _keys(df: pd.DataFrame) -> list[str]:
    return [k for k in _KEY_HEADERS if k in df.columns]


def summary_table(summ: pd.DataFrame, columns: list[tuple[str, str, float, str]]) -> pd.DataFrame:
    """Display table of a :func:`benchmarks.app.summary.summarize` output: key columns,
    ``seeds`` and one ``mean ± half-width`` text column per ``columns`` entry. Trackers
    and policies that use the truth are marked (:func:`benchmarks.app.summary.truth_labels`)."""
    keys = _keys(summ)
    out = summ[keys].rename(columns=_KEY_HEADERS).copy()
    truth_trackers, truth_policies = summary.truth_labels(summ)
    if "tracker" in out.columns:
        out["tracker"] = [summary.mark_truth(v, truth_trackers) for v in out["tracker"]]
    if "policy" in out.columns:
        out["policy"] = [summary.mark_truth(v, truth_policies) for v in out["policy"]]
    if "looks_per_step" in keys and "looks_made" in summ.columns:
        # the budget, with the looks made per step where they differ ("200 (144 made)")
        out["looks"] = [
            "–" if pol == "none" else summary.looks_text(lk, made)
            for lk, made, pol in zip(summ["looks_per_step"], summ["looks_made"],
                                     summ.get("policy_label", [""] * len(summ)), strict=True)]
    out["seeds"] = summ["n_seeds"].astype(int)
    for stem, head, scale, fmt in columns:
        if f"{stem}_mean" in summ.columns:
            out[head] = [fmt_pm(m, h, scale, fmt)
                         for m, h in zip(summ[f"{stem}_mean"], summ[f"{stem}_ci95"], strict=True)]
    if "note" in summ.columns and (summ["note"].astype(str) != "").any():
        out["note"] = summ["note"].astype(str)
    return out.reset_index(drop=True)


def paired_differences(results: pd.DataFrame, reference: str,
                       metrics: list[str] | None = None) -> pd.DataFrame:
    """Long table of paired differences ``tracker - reference`` for each metric
    (:func:`benchmarks.app.summary.paired_difference`); empty if the reference has no ok run.

    ``results`` is the step table or its :func:`benchmarks.app.summary.per_run` table;
    ``metrics`` defaults to those of :func:`paired_columns` that it has.
    """
    metrics = metrics or [m for m, *_ in paired_columns() if m in results.columns]
    parts = []
    for m in metrics:
        try:
            parts.append(summary.paired_difference(results, reference, m))
        except ValueError:
            return pd.DataFrame()
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def paired_table(paired: pd.DataFrame,
                 truth: tuple[set[str], set[str]] = (set(), set())) -> pd.DataFrame:
    """Wide display table of :func:`paired_differences`: one row per scenario x
    policy x looks x tracker, one ``mean ± half-width`` column per metric. ``truth``
    is ``(tracker labels, policy labels)`` that use the truth, marked in their cells
    (:func:`benchmarks.app.summary.truth_labels` of the runs)."""
    if paired.empty:
        return pd.DataFrame()
    keys = ["scenario", "policy_label", "looks_per_step", "tracker_label"]
    marks = {"policy_label": truth[1], "tracker_label": truth[0]}
    rows = []
    for key, g in paired.groupby(keys, sort=True):
        row = {_KEY_HEADERS[k]: (summary.mark_truth(v, marks[k]) if k in marks else v)
               for k, v in zip(keys, key, strict=True)}
        row["pairs"] = int(g["n_seeds"].min())
        by_metric = g.set_index("metric")
        for m, head, scale, fmt in paired_columns():
            if m in by_metric.index:
                r = by_metric.loc[m]
                row[head] = fmt_pm(r["diff_mean"], r["diff_ci95"], scale, fmt)
        rows.append(row)
    return pd.DataFrame(rows)


#: appended to a tuned setting's tracker cell on a scenario its file was not tuned on
OUT_OF_SAMPLE_MARK = " ¹"


def mark_out_of_sample(table: pd.DataFrame, tuned_on: dict[str, frozenset[str]] | None
                       ) -> pd.DataFrame:
    """``table`` (a display table with ``scenario`` and ``tracker`` columns) with
    :data:`OUT_OF_SAMPLE_MARK` after each tracker whose tuned file (``tuned_on``: label ->
    the scenarios it was tuned on) was tuned on other scenarios than the row's."""
    if not tuned_on or table.empty or not {"scenario", "tracker"} <= set(table.columns):
        return table
    out = table.copy()
    out["tracker"] = [
        f"{t}{OUT_OF_SAMPLE_MARK}" if _bare_label(t) in tuned_on
        and str(sc) not in tuned_on[_bare_label(t)] else t
        for t, sc in zip(out["tracker"], out["scenario"], strict=True)]
    return out


def _bare_label(cell: object) -> str:
    return str(cell).removesuffix(summary.TRUTH_MARK)


# --------------------------------------------------------- floor and ceiling
def gap_table(gc: summary.GapClosed,
              truth: tuple[set[str], set[str]] = (set(), set())) -> pd.DataFrame:
    """One row per scenario x policy x looks: floor and ceiling OSPA over the paired
    seeds, the gap ``floor - ceiling`` (``mean ± 95% t half-width`` of the per-seed
    differences) and whether it can rank trackers."""
    if gc.gaps.empty:
        return pd.DataFrame()
    name = column_label(gc.metric)
    floor_head = f"floor {gc.floor_label} {name}"
    ceil_head = f"ceiling {summary.mark_truth(gc.ceiling_label, truth[0])} {name}"
    rows = []
    for r in gc.gaps.itertuples(index=False):
        rows.append({
            "scenario": r.scenario, "policy": summary.mark_truth(r.policy_label, truth[1]),
            "looks": "–" if r.policy_label == "none" else r.looks_per_step,
            "pairs": int(r.n_pairs),
            floor_head: fmt_pm(r.floor_mean, r.floor_ci95),
            ceil_head: fmt_pm(r.ceiling_mean, r.ceiling_ci95),
            "gap": fmt_pm(r.gap_mean, r.gap_ci95),
            "ranks trackers": "yes" if r.rankable else "no"})
        if gc.bayes_label is not None:
            rows[-1].update({
                f"bayes {name}": fmt_pm(r.bayes_mean, r.bayes_ci95),
                "achievable gap": fmt_pm(r.achievable_mean, r.achievable_ci95),
                "bayes closes": fmt_pm(r.bayes_share_mean, r.bayes_share_ci95, 1.0, ".2f")
                + (" (problem-limited)" if r.problem_limited else "")})
    return pd.DataFrame(rows)


def bayes_notes(gc: summary.GapClosed) -> list[str]:
    """One line per group where the Bayes reference closes less than
    :data:`~.summary.PROBLEM_LIMITED_SHARE` of the floor-to-ceiling gap (the problem limits
    accuracy there, not the trackers) and one per contestant that beats the Bayes
    reference beyond its 95% interval (a finding to explain, not a share above 1)."""
    if gc.bayes_label is None or gc.gaps.empty:
        return []
    out = []
    for r in gc.gaps.itertuples(index=False):
        if r.problem_limited:
            out.append(f"{summary.group_text(r.scenario, r.policy_label, r.looks_per_step)}: "
                       f"the Bayes reference closes only {r.bayes_share_mean:.2f} of the gap "
                       "between floor and ceiling: here the problem (what the looks reveal), "
                       "not the trackers, limits accuracy; read the shares of the achievable "
                       "gap.")
    sh = gc.shares
    beat = sh[(sh["role"] == "") & (sh["vs_bayes_mean"] + sh["vs_bayes_ci95"] < 0)]
    for r in beat.itertuples(index=False):
        out.append(f"{summary.group_text(r.scenario, r.policy_label, r.looks_per_step)}: "
                   f"`{r.tracker_label}` beats the Bayes reference beyond noise "
                   f"({r.vs_bayes_mean:+.3f} ± {r.vs_bayes_ci95:.3f} OSPA): a finding to "
                   "explain (the reference's approximations, docs/bayes.md, or a point "
                   "estimate that suits OSPA better than the posterior mean).")
    return out


def share_table(gc: summary.GapClosed,
                truth: tuple[set[str], set[str]] = (set(), set())) -> pd.DataFrame:
    """Every tracker with the floor (first) and the ceiling (last) of its scenario x
    policy x looks: OSPA over the seeds it shares with both, and its share of the gap
    closed, ``mean ± 95% delta-method half-width``; the others in order of OSPA, worst
    first."""
    if gc.shares.empty:
        return pd.DataFrame()
    name = column_label(gc.metric)
    m = gc.metric
    order = {"floor": 0, "": 1, "bayes": 2, "ceiling": 3}
    sh = gc.shares.assign(_o=gc.shares["role"].map(order), _m=-gc.shares[f"{m}_mean"])
    sh = sh.sort_values([*summary.GAP_GROUP, "_o", "_m", "tracker_label"], kind="stable")
    rows = []
    for r in sh.itertuples(index=False):
        if r.role in ("floor", "ceiling"):
            share = f"{1 if r.role == 'ceiling' else 0} ({r.role})"
        else:
            share = fmt_pm(r.share_mean, r.share_ci95, 1.0, ".2f")
        rows.append({
            "scenario": r.scenario, "policy": summary.mark_truth(r.policy_label, truth[1]),
            "looks": "–" if r.policy_label == "none" else r.looks_per_step,
            "tracker": summary.mark_truth(r.tracker_label, truth[0]), "pairs": int(r.n_pairs),
            name: fmt_pm(getattr(r, f"{m}_mean"), getattr(r, f"{m}_ci95")),
            "share of gap closed": share})
        if gc.bayes_label is not None:
            rows[-1]["share of achievable gap"] = (
                "1 (bayes)" if r.role == "bayes" else "0 (floor)" if r.role == "floor"
                else fmt_pm(r.achievable_mean, r.achievable_ci95, 1.0, ".2f"))
    return pd.DataFrame(rows)


def _floor_ceiling_section(doc: Document, gc: summary.GapClosed,
                           truth: tuple[set[str], set[str]],
                           tuned_on: dict[str, frozenset[str]] | None = None) -> None:
    doc.add("h2", "Floor and ceiling: share of the gap closed")
    floor, ceiling = summary.FLOOR_TRACKER, summary.CEILING_TRACKER
    doc.add("p", f"The floor `{floor}` reports nothing; the ceiling `{ceiling}` is told the "
                 "number of targets and which look belongs to which target (it uses the truth: "
                 "a reference, not a competitor). A tracker's share of the gap closed is "
                 f"(OSPA_{floor} - OSPA) / (OSPA_{floor} - OSPA_{ceiling}) of the per-seed "
                 "mean OSPA over the seeds where all three runs are ok (the same worlds), "
                 "± the 95% half-width by the delta method: 1 is as good as the ceiling, 0 "
                 "no better than reporting nothing. A scenario whose gap is below "
                 f"{summary.MIN_GAP:g}, whose gap interval reaches 0, or where no contestant "
                 "beats the floor within its 95% interval cannot rank trackers.")
    if not gc.available:
        doc.add("p", gc.absent)
        return
    if gc.bayes_label is not None:
        doc.add("p", f"The `{summary.BAYES_TRACKER}` reference is the model's Bayes filter "
                     "(no truth: the best achievable on average, approximated by jmpd-ap at a "
                     "particle count where the last two fourfold increases each changed OSPA "
                     "by less than the tolerance, or else the largest count run, an estimate; "
                     "`mttbench bayes`, docs/bayes.md). A tracker's share of the "
                     f"achievable gap is (OSPA_{floor} - OSPA) / (OSPA_{floor} - "
                     f"OSPA_{summary.BAYES_TRACKER}) over the same seeds; where the reference "
                     "is far from the ceiling, the problem limits accuracy, not the trackers.")
    flags = summary.gap_notes(gc) + bayes_notes(gc)
    if flags:
        doc.add("list", flags)
    doc.add("table", gap_table(gc, truth))
    if not gc.shares.empty:
        doc.add("table", mark_out_of_sample(share_table(gc, truth), tuned_on))


# ------------------------------------------------------------------ the document
@dataclass
class Document:
    """A report as a list of blocks, rendered to Markdown and to self-contained HTML.

    Blocks: ``("h1"|"h2"|"h3", text)``, ``("p", text)``, ``("list", [items])``,
    ``("table", DataFrame)``, ``("figure", path, caption)``.
    """

    blocks: list[tuple[Any, ...]] = field(default_factory=list)

    def add(self, *block: Any) -> None:
        self.blocks.append(block)

    def markdown(self, base: Path) -> str:
        out = []
        for b in self.blocks:
            kind = b[0]
            if kind in ("h1", "h2", "h3"):
                out.append("#" * int(kind[1]) + " " + b[1])
            elif kind == "p":
                out.append(b[1])
            elif kind == "list":
                out.append("\n".join(f"- {item}" for item in b[1]))
            elif kind == "table":
                out.append(_md_table(b[1]))
            elif kind == "figure":
                rel = Path(b[1]).relative_to(base).as_posix()
                out.append(f"![{b[2]}]({rel})\n\n*{b[2]}*")
        return "\n\n".join(out) + "\n"

    def html(self, title: str) -> str:
        body = []
        for b in self.blocks:
            kind = b[0]
            if kind in ("h1", "h2", "h3"):
                body.append(f"<{kind}>{html.escape(b[1])}</{kind}>")
            elif kind == "p":
                body.append(f"<p>{_inline(b[1])}</p>")
            elif kind == "list":
                items = "".join(f"<li>{_inline(i)}</li>" for i in b[1])
                body.append(f"<ul>{items}</ul>")
            elif kind == "table":
                table = b[1].to_html(index=False, escape=True, border=0, na_rep="–",
                                     classes="results")
                body.append(f'<div class="scroll">{table}</div>')
            elif kind == "figure":
                data = base64.b64encode(Path(b[1]).read_bytes()).decode("ascii")
                body.append(f'<figure><img alt="{html.escape(b[2])}" '
                            f'src="data:image/png;base64,{data}"/>'
                            f"<figcaption>{_inline(b[2])}</figcaption></figure>")
        return (
            "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"/>"
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head>"
            "<body>\n" + "\n".join(body) + "\n</body></html>\n"
        )


_CSS = """
body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
table.results{border-collapse:collapse;font-size:13px;margin:0.5em 0 1.5em}
table.results th,table.results td{padding:3px 8px;border-bottom:1px solid #ddd;text-align:right;
white-space:nowrap}
div.scroll{overflow-x:auto}
table.results th:first-child,table.results td:first-child{text-align:left}
table.results thead th{background:#f3f3f3}
figure{margin:1em 0 2em}figure img{max-width:100%}figcaption{font-size:13px;color:#555}
code{background:#f3f3f3;padding:0 3px}
"""


def _inline(text: str) -> str:
    """Escape text, turning `code` spans into <code>."""
    parts = html.escape(text).split("`")
    return "".join(f"<code>{p}</code>" if i % 2 else p for i, p in enumerate(parts))


def _md_table(df: pd.DataFrame) -> str:
    if df.empty:
        return "*(no rows)*"
    head = [summary.md_cell(c) for c in df.columns]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for _, r in df.iterrows():
        lines.append("| " + " | ".join(summary.md_cell(v) for v in r) + " |")
    return "\n".join(lines)


# ------------------------------------------------- metrics a scenario cannot rank
def ranked_metrics() -> list[Metric]:
    """The metrics checked by :func:`baseline_notes`: the registered ones declared
    ``ranked``, in display order."""
    return [m for m in display_metrics() if m.ranked]


def _is_baseline(name: str) -> bool:
    try:
        return bool(trackers.get_class(name).baseline)
    except Exception:  # noqa: BLE001 - a tracker unknown here is not a baseline
        return False


def baseline_notes(summ: pd.DataFrame, runs: pd.DataFrame | None = None) -> list[str]:
    """Sentences for every scenario (x policy x looks) and metric of
    :func:`ranked_metrics` that cannot rank the trackers because a baseline tracker
    (``Tracker.baseline``, the ``null`` tracker that reports nothing) is not beaten there
    (e.g. on ``paper``, whose targets jump ~4.5 cells per step, reporting nothing scores
    as well as tracking on GOSPA).

    With the per-run table ``runs`` (what the report passes) the rule is the paired one
    of :func:`~.summary.gap_closed`: a contestant beats the baseline when its per-seed
    difference from it has a 95% interval wholly on the better side; a scenario where
    none does cannot rank trackers on that metric. Without ``runs`` (a summary alone):
    the baseline is best, or within the best's 95% interval."""
    if summ.empty or "tracker" not in summ.columns:
        return []
    if runs is not None and len(runs):
        return _paired_baseline_notes(summ, runs)
    baseline = summ["tracker"].astype(str).map(_is_baseline)
    if not baseline.any():
        return []
    truth_trackers, _ = summary.truth_labels(summ)
    # a tracker given the truth is a reference, not "the best tracker"
    # ... and so is the Bayes reference (no truth, but not a contestant)
    competing = ~summ["tracker_label"].astype(str).isin(truth_trackers
                                                         | summary.reference_labels(summ))
    notes = []
    group = [k for k in ("scenario", "policy_label", "looks_per_step") if k in summ.columns]
    for key, g in summ.groupby(group, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        where = f"`{key[0]}`" + (f" ({', '.join(map(str, key[1:]))} looks)"
                                 if len(key) == 3 else "")
        for m in ranked_metrics():
            metric, text = m.name, m.label
            col = f"{metric}_mean"
            if col not in g.columns or len(g) < 2:
                continue
            rows = g[g[col].notna() & competing.loc[g.index]]
            base = rows[baseline.loc[rows.index]]
            if base.empty or len(rows) < 2:
                continue
            sign = 1.0 if m.lower_is_better else -1.0  # the best has the least sign * value
            best = rows.loc[(sign * rows[col]).idxmin()]
            b = base.loc[(sign * base[col]).idxmin()]
            half = best[f"{metric}_ci95"]
            if b.name == best.name:
                notes.append(
                    f"On {where} the baseline `{b.tracker_label}` has the "
                    f"best {text}, {fmt_pm(b[col], b[f'{metric}_ci95'])}: this scenario cannot "
                    f"rank trackers on {text}.")
            elif not math.isnan(half) and sign * b[col] <= sign * best[col] + half:
                notes.append(
                    f"On {where} the baseline `{b.tracker_label}` scores "
                    f"{text} {fmt_pm(b[col], b[f'{metric}_ci95'])}, within the 95% interval "
                    f"of the best, `{best.tracker_label}` ({fmt_pm(best[col], half)}): this "
                    f"scenario cannot rank trackers on {text}.")
    return notes


def _paired_baseline_notes(summ: pd.DataFrame, runs: pd.DataFrame) -> list[str]:
    """:func:`baseline_notes` by the paired rule (per-seed differences from the baseline)."""
    ok = runs[runs["status"] == "ok"] if "status" in runs.columns else runs
    names = ok["tracker"].astype(str)
    is_base = names.map(_is_baseline)
    if not is_base.any():
        return []
    truth_trackers, _ = summary.truth_labels(summ)
    group = [k for k in ("scenario", "policy_label", "looks_per_step") if k in ok.columns]
    notes = []
    for key, g in ok.groupby(group, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        where = f"`{key[0]}`" + (f" ({', '.join(map(str, key[1:]))} looks)"
                                 if len(key) == 3 else "")
        base_labels = sorted(set(g.loc[is_base.loc[g.index], "tracker_label"].astype(str)))
        contestants = sorted(set(g.loc[~is_base.loc[g.index], "tracker_label"].astype(str))
                             - set(truth_trackers))
        if not base_labels or not contestants:
            continue
        b_label = base_labels[0]
        for m in ranked_metrics():
            if m.name not in g.columns:
                continue
            sign = 1.0 if m.lower_is_better else -1.0
            wide = g.pivot_table(index="seed", columns="tracker_label", values=m.name,
                                 aggfunc="first")
            if b_label not in wide.columns:
                continue
            best = None  # (lower bound of the improvement, mean, half, label)
            for lab in contestants:
                if lab not in wide.columns:
                    continue
                pair = wide[[b_label, lab]].dropna()
                if len(pair) < 2:
                    continue
                gain = sign * (pair[b_label].to_numpy(float) - pair[lab].to_numpy(float))
                mean, half = summary.mean_ci95(gain)
                if best is None or mean - half > best[0]:
                    best = (mean - half, mean, half, lab)
            if best is None or best[0] > 0:
                continue
            notes.append(
                f"On {where} no tracker beats the baseline `{b_label}` on {m.label} in the "
                f"paired test (per-seed differences, 95% interval): the closest, "
                f"`{best[3]}`, is better by {fmt_pm(best[1], best[2])}. This scenario "
                f"cannot rank trackers on {m.label}.")
    return notes


# ----------------------------------------------------------------------- report
@dataclass(frozen=True)
class ReportFiles:
    markdown: Path
    html: Path
    figures: dict[str, Path]


def build_report(results: pd.DataFrame, out_dir: str | Path, *, reference: str | None = "kfnn",
                 title: str = "mttbench head-to-head comparison",
                 intro: list[str] | None = None, settings: dict[str, Any] | None = None,
                 trace: Any = None, notes: list[str] | None = None,
                 draw: bool = True, sections: list[tuple[Any, ...]] | None = None,
                 tuned_on: dict[str, frozenset[str]] | None = None,
                 policy_order: list[str] | None = None, processes: int = 1) -> ReportFiles:
    """Write ``report.md``, ``report.html`` and ``figures/*.png`` into ``out_dir``.

    ``reference`` is the tracker label that paired differences subtract (skipped
    with a note when absent or None). ``settings`` is shown as a list (what was run);
    ``trace`` a :class:`benchmarks.engine.snapshot.Trace` for the snapshot figure;
    ``notes`` extra paragraphs at the end; ``draw=False`` skips the figures (tables only);
    ``sections`` blocks (:class:`Document`) shown after the settings (``compare``: the
    parameters each tracker ran and the effect of tuning). ``tuned_on`` maps a tuned
    setting's label to the scenarios its file was tuned on: every table marks the rows
    out of sample for it (:func:`mark_out_of_sample`). ``policy_order``: the policies in
    the order given (the first is the base of the differences between policies; default
    their order in ``results``). ``processes``: how many processes draw the figures
    (each figure is drawn whole by one of them; the files do not depend on it).
    :func:`start_report` does the same in two steps, for a caller with other work to do
    while the figures are drawn.
    """
    with start_report(results, out_dir, draw=draw, policy_order=policy_order,
                      processes=processes) as pending:
        pending.add_snapshot(trace)
        return pending.finish(reference=reference, title=title, intro=intro,
                              settings=settings, notes=notes, sections=sections,
                              tuned_on=tuned_on)


def start_report(results: pd.DataFrame, out_dir: str | Path, *, draw: bool = True,
                 policy_order: list[str] | None = None,
                 processes: int = 1) -> PendingReport:
    """The first half of :func:`build_report` (same arguments): the report's tables, and
    its figures being drawn in ``processes`` processes while the caller goes on (with one
    process, drawn here). Use it as a context manager (leaving it early ends the drawing)
    and end with :meth:`PendingReport.finish`, which writes the files."""
    out_dir = Path(out_dir)
    fig_dir = out_dir / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    runs = summary.per_run(results)
    summ = summary.summarize(runs)
    gc = summary.gap_closed(runs)
    axis = policy_axis.policy_axis(runs, gc, gc.metric, policy_order)

    tasks: list[FigureTask] = []
    if draw:
        if axis.available:  # one panel per scenario and policy
            tasks = _figure_tasks(_panel_per_policy(results), _panel_per_policy(runs),
                                  _panel_per_policy(summ), fig_dir, gc,
                                  summary.cutoff_text(results))
        else:
            tasks = _figure_tasks(results, runs, summ, fig_dir, gc)
    return PendingReport(results, out_dir, runs, summ, gc, axis, draw,
                         _Drawing(tasks, processes))


class PendingReport:
    """A report being made (:func:`start_report`): its tables are computed, its figures
    are being drawn. :meth:`add_snapshot` adds the snapshot figure; :meth:`finish` writes
    the document while the figures are drawn and every file once they all are."""

    def __init__(self, results: pd.DataFrame, out_dir: Path, runs: pd.DataFrame,
                 summ: pd.DataFrame, gc: summary.GapClosed, axis: policy_axis.PolicyAxis,
                 draw: bool, drawing: _Drawing) -> None:
        self.results, self.out_dir, self.runs, self.summ = results, out_dir, runs, summ
        self.gc, self.axis, self.draw, self.drawing = gc, axis, draw, drawing

    def add_snapshot(self, trace: Any) -> None:
        """Draw the snapshot of ``trace`` (a :class:`benchmarks.engine.snapshot.Trace`;
        None: no snapshot) after the other figures."""
        if trace is not None and self.draw:
            self.drawing.add(_snapshot_task(trace, self.out_dir / "figures"))

    def finish(self, *, reference: str | None = "kfnn",
               title: str = "mttbench head-to-head comparison",
               intro: list[str] | None = None, settings: dict[str, Any] | None = None,
               notes: list[str] | None = None, sections: list[tuple[Any, ...]] | None = None,
               tuned_on: dict[str, frozenset[str]] | None = None) -> ReportFiles:
        """Write ``report.md`` and ``report.html`` (arguments as :func:`build_report`)."""
        truth = summary.truth_labels(self.runs)
        doc = _document(self.results, self.runs, self.summ, truth, self.gc, self.axis,
                        self.drawing.paths, title=title, intro=intro, settings=settings,
                        notes=notes, sections=sections, tuned_on=tuned_on,
                        reference=reference)
        figs = self.drawing.wait()
        md_path = self.out_dir / "report.md"
        write_text_atomic(md_path, doc.markdown(self.out_dir))
        html_path = self.out_dir / "report.html"
        write_text_atomic(html_path, doc.html(title))
        return ReportFiles(md_path, html_path, figs)

    def __enter__(self) -> PendingReport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.drawing.__exit__(*exc)


def _document(results: pd.DataFrame, runs: pd.DataFrame, summ: pd.DataFrame,
              truth: pd.DataFrame, gc: summary.GapClosed, axis: policy_axis.PolicyAxis,
              figs: dict[str, Path], *, title: str, intro: list[str] | None,
              settings: dict[str, Any] | None, notes: list[str] | None,
              sections: list[tuple[Any, ...]] | None,
              tuned_on: dict[str, frozenset[str]] | None, reference: str | None) -> Document:
    """The report's blocks (:func:`build_report`); ``figs``: each figure's file."""
    doc = Document()
    doc.add("h1", title)
    _verdict_section(doc, results, runs, summ, gc, figs, axis)
    for para in intro or []:
        doc.add("p", para)
    out_of_sample = sorted({sc for sc in summ["scenario"].astype(str)
                            for lab, on in (tuned_on or {}).items()
                            if lab in set(summ["tracker_label"].astype(str)) and sc not in on})
    if out_of_sample:
        doc.add("p", f"{OUT_OF_SAMPLE_MARK.strip()} Out of sample: the tracker runs a tuned "
                     "file tuned on other scenarios than this row's ("
                     + "; ".join(f"`{lab}`: {', '.join(sorted(on))}"
                                 for lab, on in sorted((tuned_on or {}).items())) + ").")
    _floor_ceiling_section(doc, gc, truth, tuned_on)
    _policy_section(doc, axis)
    unranked = baseline_notes(summ, runs)
    if unranked:
        doc.add("h2", "Where the baseline is not beaten")
        doc.add("p", "A tracker that reports nothing is the floor every tracker must beat. "
                     "Where no tracker beats it in the paired test (the per-seed "
                     "differences' 95% interval wholly on the better side, the rule of "
                     "\"ranks trackers\" above), the scenario does not separate the "
                     "trackers on that metric, and the ranking below says nothing about "
                     "them there:")
        doc.add("list", unranked)
    doc.add("h2", "Accuracy")
    doc.add("p", "Mean over seeds of each run's mean over steps, ± half-width of the 95% "
                 "Student-t interval over seeds. OSPA, its localisation and cardinality parts "
                 "and the RMSE of the optimally assigned pairs are in workspace units (cells); "
                 "count error is |N_est - N| per step.")
    doc.add("table", mark_out_of_sample(summary_table(summ, accuracy_columns()), tuned_on))
    doc.add("h3", "GOSPA and its parts")
    doc.add("p", "GOSPA (alpha = 2); the localisation, missed and false parts are costs in the "
                 "p-th-power domain (they add up to GOSPA^p per step; missed and false are "
                 "c^p/2 per missed or false target).")
    doc.add("table", mark_out_of_sample(summary_table(summ, GOSPA_COLUMNS), tuned_on))
    _track_section(doc, runs, summ, tuned_on, summary.crossing_summary(results))
    doc.add("h2", "Runtime")
    doc.add("p", "Tracker time is predict + update + estimate per step (median over the steps "
                 "of a run, then mean over seeds, ± 95% interval); selection time is the cell "
                 "choice (with the tracker's predicted cell counts when the policy uses them). "
                 "Peak RSS is the worker's high-water mark, an upper bound.")
    doc.add("table", mark_out_of_sample(summary_table(summ, RUNTIME_COLUMNS), tuned_on))
    doc.add("h2", f"Paired differences against {reference}" if reference
            else "Paired differences")
    paired = paired_differences(runs, reference) if reference else pd.DataFrame()
    if not reference:
        doc.add("p", "No reference tracker (every tracker that ran uses the truth): no paired "
                     "differences.")
    elif paired.empty:
        doc.add("p", f"No ok runs of the reference tracker {reference!r}: no paired differences.")
    else:
        doc.add("p", f"Per seed, the tracker's run minus the {reference} run of the same world "
                     "(same truth and sensor random numbers), then mean ± 95% t half-width over "
                     "the pairs. Negative accuracy differences mean better than the reference; "
                     "an interval that excludes 0 is a difference at the 5% level.")
        doc.add("table", mark_out_of_sample(paired_table(paired, truth), tuned_on))
    doc.add("h2", "Figures")
    captions = {
        "ospa": "OSPA over time: mean over seeds with a shaded 95% band, per tracker.",
        "count_error": "Count error over time: mean over seeds with a shaded 95% band.",
        "ospa2": "OSPA(2) over time: at step k, OSPA(2) between the tracks of the window of "
                 "steps ending at k (clipped at step 0), mean over seeds with a shaded 95% "
                 "band, per tracker with track labels.",
        "runtime": "Tracker time per step: one dot per run (its median step), bar = mean.",
        "accuracy_runtime": "Mean OSPA against mean time per step, one point per tracker "
                            "and parameter setting, 95% error bars.",
        "snapshot": "Snapshot of one run: looked-at cells (grey), positive returns (magenta), "
                    "true targets (blue), estimates (black) with 95% covariance ellipses.",
    }
    for key, path in figs.items():
        if key != "gap_closed":  # shown with the verdict
            doc.add("figure", path, captions[key])
    bad = summ[summ["note"].astype(str) != ""]
    if len(bad):
        doc.add("h2", "Failed or unsupported runs")
        doc.add("list", [f"{r.scenario} / {r.tracker_label}: {r.note}" for r in bad.itertuples()])
    if settings:
        doc.add("h2", "Settings")
        doc.add("list", [f"{k}: {v}" for k, v in settings.items()])
    for block in sections or []:
        doc.add(*block)
    for para in notes or []:
        doc.add("p", para)
    return doc


def _panel_per_policy(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` with each grid scenario's name followed by its policy, so the figures
    draw one panel per scenario and policy."""
    pol = table["policy_label"].astype(str)
    out = table.copy()
    out["scenario"] = [sc if p == policy_axis.NO_POLICY else f"{sc} · {p}"
                       for sc, p in zip(table["scenario"].astype(str), pol, strict=True)]
    return out


def _policy_section(doc: Document, axis: policy_axis.PolicyAxis) -> None:
    """Trackers x policies: the best pair per scenario, where the Bayes reference is
    stored under one policy only, and per scenario the tracker x policy table."""
    if not axis.available:
        return
    doc.add("h2", "Trackers x policies")
    doc.add("p", policy_axis.explanation(axis))
    lines = policy_axis.best_lines(axis) + policy_axis.bayes_lines(axis)
    if lines:
        doc.add("list", lines)
    for head, table in policy_axis.display_tables(axis):
        doc.add("h3", head.replace("`", ""))
        doc.add("table", table)


def _verdict_section(doc: Document, results: pd.DataFrame, runs: pd.DataFrame,
                     summ: pd.DataFrame, gc: summary.GapClosed, figs: dict[str, Path],
                     axis: policy_axis.PolicyAxis | None = None) -> None:
    """The report's opening: per scenario who leads and by how much (paired, 95%
    intervals), the gaps and what cannot be ranked (:mod:`.verdict`), the best
    tracker-policy pair where several policies ran (:mod:`.policy_axis`), each tracker's
    cost, and the figure of the share of the gap closed."""
    doc.add("h2", "Verdict")
    name = column_label(gc.metric)
    doc.add("p", f"{name} with {summary.cutoff_text(results)}. "
                 f"Per scenario, the contestant of least mean {name} leads (trackers given "
                 "the truth, the Bayes reference and the floor do not compete); the others "
                 f"are compared with it seed by seed (their {name} minus the leader's, mean ± "
                 "95% t half-width): an interval reaching 0 is level within noise. The gap is "
                 f"the floor's {name} minus the ceiling's, the achievable gap the floor's minus "
                 "the Bayes reference's; the tables below give every number.")
    doc.add("list", verdict.group_lines(runs, gc, gc.metric, baseline_notes(summ, runs)))
    if axis is not None and axis.available and not axis.best.empty:
        doc.add("p", "Best tracker-policy pair per scenario (the table \"Trackers x "
                     "policies\" below gives every pair and the paired differences between "
                     "policies):")
        doc.add("list", policy_axis.best_lines(axis))
    if not gc.available:
        doc.add("p", gc.absent)
    cost = verdict.cost_line(summ)
    if cost:
        doc.add("p", cost)
    bad = summ[summ["note"].astype(str) != ""]
    if len(bad):
        doc.add("p", f"{len(bad)} scenario x tracker rows have failed or unsupported runs "
                     "(listed under \"Failed or unsupported runs\").")
    if "gap_closed" in figs:
        doc.add("figure", figs["gap_closed"],
                "Share of the gap closed per tracker and scenario, 0 = the floor (reports "
                "nothing), 1 = the ceiling (told the truth), 95% delta-method intervals.")


@dataclass(frozen=True)
class FigureTask:
    """A figure of the report: its key, its file and the :mod:`.figures` function that
    draws it (called ``draw(*args, path=path, **kwargs)``)."""

    key: str
    path: Path
    draw: Any
    args: tuple[Any, ...]
    kwargs: dict[str, Any] = field(default_factory=dict)

    def __call__(self) -> Path:
        return self.draw(*self.args, path=self.path, **self.kwargs)


def _figure_tasks(results: pd.DataFrame, runs: pd.DataFrame, summ: pd.DataFrame,
                  fig_dir: Path, gc: summary.GapClosed | None = None,
                  cut: str | None = None) -> list[FigureTask]:
    """The report's figures but the snapshot (:func:`_snapshot_task`), in the order the
    report shows them (the costliest first: :class:`_Drawing` hands them out in this
    order)."""
    cut = cut or summary.cutoff_text(results)
    tasks = [
        FigureTask("ospa", fig_dir / "ospa_over_time.png", figures.metric_over_time,
                   (results, "ospa"), {"ylabel": f"OSPA ({cut})"}),
        FigureTask("count_error", fig_dir / "count_error_over_time.png",
                   figures.metric_over_time, (results, "count_error"),
                   {"ylabel": "count error |N_est - N|"}),
    ]
    if "ospa2_window" in results.columns and results["ospa2_window"].notna().any():
        window = next((m.params.get("window") for m in registered_run_metrics()
                       if m.name == "ospa2_window"), None)
        tasks.append(FigureTask(
            "ospa2", fig_dir / "ospa2_over_time.png", figures.metric_over_time,
            (results, "ospa2_window"),
            {"ylabel": "OSPA(2)", "title": f"OSPA(2) of the window ending at the step ({cut}"
                                           + (f", {window:g} steps)" if window else ")")}))
    tasks.append(FigureTask("runtime", fig_dir / "runtime_per_step.png",
                            figures.runtime_per_step, (runs,)))
    tasks.append(FigureTask("accuracy_runtime", fig_dir / "accuracy_vs_runtime.png",
                            figures.accuracy_vs_runtime, (summ,)))
    if gc is not None and not gc.shares.empty and (~gc.shares["role"].isin(
            ("floor", "ceiling"))).any():
        tasks.append(FigureTask(
            "gap_closed", fig_dir / "gap_closed.png", figures.gap_closed_shares,
            (gc.shares,), {"style_labels": list(summ["tracker_label"].astype(str).unique())}))
    return tasks


def _snapshot_task(trace: Any, fig_dir: Path) -> FigureTask:
    """The snapshot figure of ``trace``: three steps of its run."""
    n = len(trace.steps)
    steps = sorted({max(0, n // 4 - 1), max(0, n // 2 - 1), n - 1})
    g = trace.scenario.grid
    return FigureTask(
        "snapshot", fig_dir / "snapshot.png", figures.snapshot, (trace.frames(),),
        {"steps": steps, "nx": g.nx, "ny": g.ny, "cell_size": g.cell_size,
         "title": f"{trace.tracker_label} on {trace.scenario.name}, seed {trace.seed}, "
                  f"policy {trace.policy_label}"})


class _Drawing:
    """The figures of ``tasks`` (and of those :meth:`add` gives later) being drawn. With
    ``processes <= 1`` each is drawn when it is given, in this process; else in that many
    worker processes at once, which go on while this one writes the report (:meth:`wait`
    collects them). A figure is one process's work, so its file is the one this process
    would write. An error in one is raised by :meth:`wait`; leaving the ``with`` block
    early (an error, Ctrl-C) ends the workers."""

    def __init__(self, tasks: list[FigureTask], processes: int = 1) -> None:
        self.paths: dict[str, Path] = {}  # where the report links them
        self._pool = None
        self._futures: list[tuple[str, Any]] = []
        self._drawn: dict[str, Path] = {}
        if processes > 1 and tasks:
            self._pool = ProcessPoolExecutor(max_workers=processes,
                                             mp_context=multiprocessing.get_context(),
                                             initializer=_ignore_sigint)
        for task in tasks:
            self.add(task)

    def add(self, task: FigureTask) -> None:
        """Draw ``task`` after those given before."""
        self.paths[task.key] = task.path
        if self._pool is None:
            self._drawn[task.key] = task()
        else:
            self._futures.append((task.key, self._pool.submit(task)))

    def wait(self) -> dict[str, Path]:
        """Each figure's file, ``{key: path}`` in the tasks' order, once all are drawn."""
        if self._pool is not None:
            self._drawn.update((key, fut.result()) for key, fut in self._futures)
            self._pool.shutdown()
            self._pool = None
        return self._drawn

    def __enter__(self) -> _Drawing:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            stop_pool(self._pool)
            self._pool = None


def _ignore_sigint() -> None:
    # a figure worker leaves Ctrl-C to the report, which ends it (no second traceback)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


# -------------------------------------------------------------- browser check
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")


def find_chromium() -> str | None:
    """Path of a chromium executable on PATH, or None."""
    for name in CHROMIUM_NAMES:
        exe = shutil.which(name)
        if exe:
            return exe
    return None


def screenshot(html_path: str | Path, png_path: str | Path, *, width: int = 1400,
               height: int = 3000, timeout: float = 120.0) -> Path:
    """Open ``html_path`` in headless chromium and save a screenshot to ``png_path``.

    A fresh profile directory is used and everything networked is switched off, so the
    page can only show what it embeds. Raises if chromium is missing or writes nothing.
    """
    exe = find_chromium()
    if exe is None:
        raise FileNotFoundError("no chromium on PATH (Debian: apt-get install chromium)")
    html_path, png_path = Path(html_path).resolve(), Path(png_path).resolve()
    png_path.unlink(missing_ok=True)
    with tempfile.TemporaryDirectory(prefix="mttbench-chromium-") as profile:
        cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
               "--no-first-run", "--disable-background-networking",
               "--disable-component-update", "--disable-sync", f"--user-data-dir={profile}",
               f"--screenshot={png_path}", f"--window-size={width},{height}",
               "--hide-scrollbars", html_path.as_uri()]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    if not png_path.exists() or png_path.stat().st_size == 0:
        raise RuntimeError(f"chromium wrote no screenshot (exit {proc.returncode}): "
                           f"{proc.stderr[-2000:]}")
    return png_path

"""The verdict a report opens with: who leads where, by how much, what cannot be ranked,
and what each tracker costs, generated from the runs (the tables follow it).

Per scenario x policy x looks (a *group*), over the contestants (no truth, not a
reference such as ``bayes``, not a baseline such as ``null``):

* the leader is the contestant of least mean ``metric`` over its seeds;
* every other contestant is compared with it by the paired rule used throughout the
  report: the per-seed difference ``X - leader`` over the seeds both ran ok, mean ± the
  95% Student-t half-width (:func:`~.summary.mean_ci95`); an interval reaching 0 is
  *level within noise*, one wholly above 0 is *behind beyond noise*;
* the floor-to-ceiling gap ``F - C`` and, with the Bayes reference, the achievable gap
  ``F - B``, and the leader's share of each (:func:`~.summary.gap_closed`);
* a group that cannot rank trackers (its gap too small or uncertain, or no contestant
  beating the floor in the paired test) says so first, with the reason.

Costs: per tracker, the mean over groups of its mean tracker time per step (each run's
median step), with the range over groups.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from . import summary

#: how the verdict writes a metric difference or level
_FMT = ".3f"


def contestants(runs: pd.DataFrame) -> set[str]:
    """Tracker labels of ``runs`` that compete: no truth, not a reference, not a baseline
    (the floor)."""
    truth, _ = summary.truth_labels(runs)
    refs = summary.reference_labels(runs)
    out = set()
    for name, label in set(zip(runs["tracker"].astype(str),
                               runs["tracker_label"].astype(str), strict=True)):
        if label not in truth and label not in refs and not _is_baseline(name):
            out.add(label)
    return out


def leader_comparison(group: pd.DataFrame, labels: set[str], metric: str = "ospa"
                      ) -> tuple[str, float, float, pd.DataFrame] | None:
    """The leader of one group's ok runs among ``labels`` (least mean ``metric`` over its
    seeds; ties by label), its mean ± half-width, and one row per other contestant:
    ``tracker_label, diff_mean, diff_ci95, n_pairs`` of ``X - leader`` paired by seed, in
    order of ``diff_mean``. None when no contestant has an ok run here."""
    ok = group[(group["status"] == "ok") & group["tracker_label"].astype(str).isin(labels)]
    ok = ok[ok[metric].notna()]
    if ok.empty:
        return None
    wide = ok.pivot_table(index="seed", columns="tracker_label", values=metric,
                          aggfunc="first")
    means = wide.mean().sort_index()
    leader = str(means.idxmin())
    lead_mean, lead_half = summary.mean_ci95(wide[leader].to_numpy(float))
    rows = []
    for lab in wide.columns:
        if lab == leader:
            continue
        pair = wide[[leader, lab]].dropna()
        d = pair[lab].to_numpy(float) - pair[leader].to_numpy(float)
        mean, half = summary.mean_ci95(d)
        rows.append({"tracker_label": str(lab), "diff_mean": mean, "diff_ci95": half,
                     "n_pairs": len(pair)})
    others = pd.DataFrame(rows, columns=["tracker_label", "diff_mean", "diff_ci95", "n_pairs"])
    others = others.sort_values(["diff_mean", "tracker_label"], kind="stable")
    return leader, lead_mean, lead_half, others.reset_index(drop=True)


def _pm(mean: float, half: float, fmt: str = _FMT, sign: bool = False) -> str:
    text = format(mean, ("+" if sign else "") + fmt)
    return text + (" ± n/a" if half is None or math.isnan(half) else f" ± {half:{fmt}}")


def _beyond_noise(mean: float, half: float) -> bool:
    return not math.isnan(half) and mean - half > 0


def group_lines(runs: pd.DataFrame, gc: summary.GapClosed, metric: str = "ospa",
                baseline_notes: list[str] | None = None) -> list[str]:
    """One sentence per group: whether it ranks trackers, the leader and by how much, the
    contestants level with it and the nearest one behind beyond noise, and the gaps.
    ``baseline_notes``: the report's paired baseline rule's sentences
    (:func:`~.report.baseline_notes`), read where floor and ceiling give no gap."""
    labels = contestants(runs)
    name = _metric_label(metric)
    floor_notes = [n for n in baseline_notes or [] if f" on {name} in the paired test" in n]
    gaps = gc.gaps.set_index(summary.GAP_GROUP) if not gc.gaps.empty else None
    shares = gc.shares
    out = []
    group = [k for k in summary.GAP_GROUP if k in runs.columns]
    for key, g in runs.groupby(group, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        sc, pol, looks = (*key, "", "")[:3]
        where = summary.group_text(sc, pol, looks)
        comp = leader_comparison(g, labels, metric)
        gap_row = None
        if gaps is not None and key in gaps.index:
            gap_row = gaps.loc[key]
        reasons = []
        if gap_row is not None and gap_row["reason"]:
            reasons.append(str(gap_row["reason"]).removeprefix(
                "this scenario cannot rank trackers: ").rstrip("."))
        on = f"On `{sc}`" + (f" ({', '.join(map(str, key[1:]))} looks)" if len(key) == 3
                             else "")
        if not reasons and any(n.startswith(on + " no tracker beats") for n in floor_notes):
            reasons.append("no contestant beats the floor in the paired test")
        parts = [f"{where}: " + (f"cannot rank trackers ({'; '.join(reasons)}); "
                                 if reasons else "")]
        if comp is None:
            parts.append("no contestant ran ok.")
            out.append("".join(parts))
            continue
        leader, lm, lh, others = comp
        parts.append(f"`{leader}` leads, {name} {_pm(lm, lh)}")
        level = others[~others.apply(lambda r: _beyond_noise(r.diff_mean, r.diff_ci95),
                                     axis=1)] if len(others) else others
        behind = others[~others.index.isin(level.index)]
        if len(level):
            parts.append("; level within noise: " + ", ".join(
                f"`{r.tracker_label}` ({_pm(r.diff_mean, r.diff_ci95, sign=True)})"
                for r in level.itertuples(index=False)))
        if len(behind):
            r = behind.iloc[0]
            parts.append(f"; ahead of the next, `{r.tracker_label}`, by "
                         f"{_pm(r.diff_mean, r.diff_ci95)} (paired, {int(r.n_pairs)} seeds)")
        elif not len(others):
            parts.append(" (the only contestant)")
        if gap_row is not None and np.isfinite(gap_row["gap_mean"]):
            parts.append(f". Gap floor to ceiling {_pm(gap_row['gap_mean'], gap_row['gap_ci95'])}")
            if "achievable_mean" in gap_row.index and np.isfinite(gap_row["achievable_mean"]):
                parts.append(f", achievable gap (floor to Bayes) "
                             f"{_pm(gap_row['achievable_mean'], gap_row['achievable_ci95'])}")
            sel = shares[(shares["tracker_label"].astype(str) == leader)
                         & np.logical_and.reduce([shares[k] == v for k, v in
                                                  zip(summary.GAP_GROUP, key, strict=False)])]
            if len(sel):
                s = sel.iloc[0]
                parts.append(f"; `{leader}` closes {_pm(s['share_mean'], s['share_ci95'], '.2f')}"
                             " of the gap")
                if "achievable_mean" in s.index and np.isfinite(s["achievable_mean"]):
                    parts.append(f" ({_pm(s['achievable_mean'], s['achievable_ci95'], '.2f')}"
                                 " of the achievable)")
        out.append("".join(parts) + ".")
    return out


def cost_line(summ: pd.DataFrame) -> str:
    """Tracker time per step of every tracker label, cheapest first: the mean over groups
    of its mean (each run's median step) and, with several groups, their range."""
    col = "tracker_wall_s_mean"
    if col not in summ.columns:
        return ""
    ok = summ[summ[col].notna()]
    items = []
    for lab, g in ok.groupby(ok["tracker_label"].astype(str)):
        ms = g[col].to_numpy(float) * 1e3
        text = f"`{lab}` {ms.mean():.3g}"
        if len(ms) > 1:
            text += f" ({ms.min():.3g}-{ms.max():.3g})"
        items.append((ms.mean(), lab, text))
    if not items:
        return ""
    items.sort()
    return ("Cost, tracker ms per step (mean over the scenarios; range over them), cheapest "
            "first: " + ", ".join(t for _, _, t in items) + ".")


def _is_baseline(name: str) -> bool:
    from ... import trackers

    try:
        return bool(trackers.get_class(name).baseline)
    except Exception:  # noqa: BLE001 - a tracker unknown here (outside:NAME) is not one
        return False


def _metric_label(metric: str) -> str:
    from ..engine.metrics import get_metric

    try:
        return get_metric(metric).label
    except Exception:  # noqa: BLE001 - an unregistered column: its own name
        return metric

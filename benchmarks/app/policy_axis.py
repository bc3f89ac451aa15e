"""Policies as an axis of the head-to-head: every tracker under every policy on the same
worlds, the tracker x policy table, the paired differences between policies and the best
tracker-policy pair.

Common random numbers: a run's truth and the return of the ``j``-th look at a cell in
step ``k`` depend on ``(scenario, seed)`` only (:func:`~mttbench.scenarios.simulator.
simulate`), so the runs of one tracker under two policies on one seed are paired: they
differ by the cells looked at and what follows from them, never by the world.

Per scenario and look budget (a *row group*), with ``X_{t,P,i}`` the per-run mean
``metric`` of tracker ``t`` under policy ``P`` on seed ``i`` (:func:`~.summary.per_run`):

* the table gives ``mean_i X_{t,P,i}`` ± the 95% t half-width over the ok seeds, and the
  share of the gap closed under that policy, ``(F_P - X) / (F_P - C_P)`` with the floor
  ``null`` and the ceiling ``truth-aided`` run under the same policy (and ``(F_P - X) /
  (F_P - B_P)`` where the Bayes reference ``B_P`` is stored for that policy), from
  :func:`~.summary.gap_closed` (delta-method intervals);
* the paired difference of a policy ``Q`` against the base policy ``P_0`` (the first
  given) for one tracker: ``d_i = X_{t,Q,i} - X_{t,P_0,i}`` over the seeds where both runs
  are ok, ``mean(d) ± t_{0.975, n-1} sd(d) / sqrt(n)``; negative is better under ``Q``;
* the best pair is the contestant pair (a tracker that neither uses the truth nor is a
  reference or baseline, :func:`~.verdict.contestants`, under a policy that does not use
  the truth) of least mean ``metric`` over its ok seeds, ties broken by tracker then policy
  label; it is *beyond noise* against the runner-up (the pair of the next least mean) when
  the paired difference ``runner-up - best`` has a 95% interval wholly above 0.

The shares of the gap are each policy's own (its floor and ceiling): the ceiling is a
tracker and is helped by a better policy as well, so pairs are ranked on the metric, whose
values share the worlds across policies.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..engine.specs import PolicySpec, resolve_policies
from . import summary, verdict
from .usage import UsageError

#: the row groups of the policy axis
ROW_GROUP = ["scenario", "looks_per_step"]
#: the policy label of runs without cells (the superposition sensor): no policy axis
NO_POLICY = "none"
#: appended to a paired difference whose 95% interval excludes 0
BEYOND_NOISE_MARK = " *"


def resolve(texts: Sequence[str], option: str = "--policies") -> list[PolicySpec]:
    """Policy specs for ``compare``: unknown names, refused parameters and a label given
    twice give one line (:func:`~mttbench.benchmarks.engine.specs.resolve_policies`), and
    so do two specs of one configuration (``renyi`` and ``renyi:alpha=<its default>``
    would run the same looks twice)."""
    specs = resolve_policies(list(texts))
    seen: dict[str, str] = {}
    for spec in specs:
        if spec.config in seen:
            raise UsageError(f"{option}: {seen[spec.config]} and {spec.label} are the same "
                             "policy (one configuration); give it once")
        seen[spec.config] = spec.label
    return specs


def policy_order(runs: pd.DataFrame, order: Sequence[str] | None = None) -> list[str]:
    """The policy labels of ``runs`` (cells only), those of ``order`` first in its order,
    then the others in order of appearance. The first is the base of the differences."""
    present = [str(p) for p in pd.unique(runs["policy_label"].astype(str)) if p != NO_POLICY]
    first = [p for p in (order or []) if p in present]
    return first + [p for p in present if p not in first]


def several(runs: pd.DataFrame) -> bool:
    """True when some scenario and look budget of ``runs`` ran under two policies or more."""
    cells = runs[runs["policy_label"].astype(str) != NO_POLICY]
    if cells.empty:
        return False
    return bool((cells.groupby(ROW_GROUP)["policy_label"].nunique() > 1).any())


@dataclass(frozen=True)
class PolicyAxis:
    """Result of :func:`policy_axis` (all frames empty when no group has two policies).

    ``table``: one row per ``scenario, looks_per_step, tracker_label, policy_label`` with
    ``role`` (floor, ceiling, bayes, or ""), ``tracker_uses_truth``,
    ``policy_uses_truth``, ``n_seeds``,
    ``<metric>_mean``, ``<metric>_ci95``, ``share_mean``, ``share_ci95``,
    ``achievable_mean``, ``achievable_ci95`` (NaN where not defined).
    ``diffs``: one row per group, tracker and policy other than the base:
    ``policy_label, base_label, diff_mean, diff_ci95, n_pairs`` (``X_Q - X_base``, paired).
    ``best``: one row per group with two policies or more: ``tracker_label,
    policy_label, mean, ci95, n_seeds`` of the best pair, ``runner_tracker,
    runner_policy, diff_mean, diff_ci95, n_pairs`` (runner-up minus best, paired;
    NaN/"" when the best pair is the only one), ``beyond_noise``.
    ``bayes_policies``: per group, the policies with a stored Bayes reference."""

    metric: str
    policies: list[str]
    table: pd.DataFrame
    diffs: pd.DataFrame
    best: pd.DataFrame
    bayes_policies: dict[tuple[str, int], set[str]]

    @property
    def available(self) -> bool:
        return not self.best.empty or not self.diffs.empty


_TABLE_COLS = [*ROW_GROUP, "tracker_label", "policy_label", "role", "tracker_uses_truth",
               "policy_uses_truth", "n_seeds",
               "share_mean", "share_ci95", "achievable_mean", "achievable_ci95"]
_DIFF_COLS = [*ROW_GROUP, "tracker_label", "policy_label", "base_label", "diff_mean",
              "diff_ci95", "n_pairs"]
_BEST_COLS = [*ROW_GROUP, "tracker_label", "policy_label", "mean", "ci95", "n_seeds",
              "runner_tracker", "runner_policy", "diff_mean", "diff_ci95", "n_pairs",
              "beyond_noise"]


def _role(label: str, gc: summary.GapClosed) -> str:
    if label == gc.floor_label:
        return "floor"
    if label == gc.ceiling_label:
        return "ceiling"
    if label == summary.BAYES_TRACKER:
        return "bayes"
    return ""


def paired(a: pd.Series, b: pd.Series) -> tuple[float, float, int]:
    """``mean ± 95% t half-width`` of ``a - b`` over the index values both hold (seeds),
    and the number of pairs."""
    both = pd.concat([a.rename("a"), b.rename("b")], axis=1).dropna()
    d = both["a"].to_numpy(float) - both["b"].to_numpy(float)
    mean, half = summary.mean_ci95(d)
    return mean, half, len(both)


def _beyond(mean: float, half: float) -> bool:
    return bool(np.isfinite(half) and mean - half > 0)


def best_pair(wide: pd.DataFrame) -> dict[str, object] | None:
    """The best pair of ``wide`` (seeds x ``(tracker, policy)`` columns of the metric, NaN
    where a run is not ok): least mean over its own seeds, ties by ``(tracker, policy)``;
    the runner-up (next least mean) and ``runner-up - best`` paired by seed. None when no
    column has a value."""
    means = wide.mean()
    means = means[means.notna()]
    if means.empty:
        return None
    # means equal to 12 significant digits are a tie (summation order aside)
    order = sorted(means.index, key=lambda k: (float(f"{means[k]:.12g}"), str(k[0]),
                                               str(k[1])))
    best = order[0]
    mean, half = summary.mean_ci95(wide[best].to_numpy(float))
    row: dict[str, object] = {
        "tracker_label": best[0], "policy_label": best[1], "mean": mean, "ci95": half,
        "n_seeds": int(wide[best].notna().sum()), "runner_tracker": "", "runner_policy": "",
        "diff_mean": math.nan, "diff_ci95": math.nan, "n_pairs": 0, "beyond_noise": False}
    if len(order) > 1:
        runner = order[1]
        d_mean, d_half, n = paired(wide[runner], wide[best])
        row.update(runner_tracker=runner[0], runner_policy=runner[1], diff_mean=d_mean,
                   diff_ci95=d_half, n_pairs=n, beyond_noise=_beyond(d_mean, d_half))
    return row


def policy_axis(runs: pd.DataFrame, gc: summary.GapClosed | None = None,
                metric: str = "ospa", order: Sequence[str] | None = None) -> PolicyAxis:
    """The tracker x policy table, the paired differences between policies and the best
    pair of every scenario and look budget run under two policies or more (see the module
    docstring). ``runs`` is a :func:`~.summary.per_run` table (a step table is reduced);
    ``gc`` its :func:`~.summary.gap_closed` (computed when None); ``order`` the policies in
    the order given (the first is the base of the differences)."""
    if "step" in runs.columns:
        runs = summary.per_run(runs)
    gc = gc if gc is not None else summary.gap_closed(runs, metric)
    pols = policy_order(runs, order)
    empty = PolicyAxis(metric, pols, pd.DataFrame(columns=_TABLE_COLS), pd.DataFrame(
        columns=_DIFF_COLS), pd.DataFrame(columns=_BEST_COLS), {})
    if not several(runs):
        return empty
    rank = {p: i for i, p in enumerate(pols)}
    truth_trackers, truth_policies = summary.truth_labels(runs)
    players = verdict.contestants(runs)
    shares = gc.shares.set_index([*summary.GAP_GROUP, "tracker_label"]) \
        if not gc.shares.empty else None
    ok = runs[(runs["status"] == "ok") & runs[metric].notna()]
    ok = ok[ok["policy_label"].astype(str) != NO_POLICY]
    table, diffs, best = [], [], []
    bayes_at: dict[tuple[str, int], set[str]] = {}
    for (sc, looks), g in ok.groupby(ROW_GROUP, sort=True):
        here = sorted(set(g["policy_label"].astype(str)), key=lambda p: (rank.get(p, 1e9), p))
        if len(here) < 2:
            continue
        key = (str(sc), int(looks))
        bayes_at[key] = set(g.loc[g["tracker_label"].astype(str) == summary.BAYES_TRACKER,
                                  "policy_label"].astype(str))
        wide = g.pivot_table(index="seed", columns=["tracker_label", "policy_label"],
                             values=metric, aggfunc="first")
        wide.columns = [(str(t), str(p)) for t, p in wide.columns]
        for t, p in sorted(wide.columns, key=lambda c: (c[0], rank.get(c[1], 1e9))):
            mean, half = summary.mean_ci95(wide[(t, p)].to_numpy(float))
            row = {"scenario": sc, "looks_per_step": looks, "tracker_label": t,
                   "policy_label": p, "role": _role(t, gc),
                   "tracker_uses_truth": t in truth_trackers,
                   "policy_uses_truth": p in truth_policies,
                   "n_seeds": int(wide[(t, p)].notna().sum()), f"{metric}_mean": mean,
                   f"{metric}_ci95": half, "share_mean": math.nan, "share_ci95": math.nan,
                   "achievable_mean": math.nan, "achievable_ci95": math.nan}
            k = (sc, p, looks, t)
            if shares is not None and k in shares.index:
                s = shares.loc[k]
                row.update(share_mean=s["share_mean"], share_ci95=s["share_ci95"],
                           achievable_mean=s.get("achievable_mean", math.nan),
                           achievable_ci95=s.get("achievable_ci95", math.nan))
            table.append(row)
        base = here[0]
        for t in sorted({c[0] for c in wide.columns}):
            if (t, base) not in wide.columns:
                continue
            for q in here[1:]:
                if (t, q) not in wide.columns:
                    continue
                d_mean, d_half, n = paired(wide[(t, q)], wide[(t, base)])
                if n:
                    diffs.append({"scenario": sc, "looks_per_step": looks, "tracker_label": t,
                                  "policy_label": q, "base_label": base, "diff_mean": d_mean,
                                  "diff_ci95": d_half, "n_pairs": n})
        contest = [c for c in wide.columns if c[0] in players and c[1] not in truth_policies]
        chosen = best_pair(wide[contest]) if contest else None
        if chosen is not None:
            best.append({"scenario": sc, "looks_per_step": looks, **chosen})
    cols = [*_TABLE_COLS[:8], f"{metric}_mean", f"{metric}_ci95", *_TABLE_COLS[8:]]
    return PolicyAxis(metric, pols, pd.DataFrame(table, columns=cols),
                      pd.DataFrame(diffs, columns=_DIFF_COLS),
                      pd.DataFrame(best, columns=_BEST_COLS), bayes_at)


# ------------------------------------------------------------------------- display
def _pm(mean: float, half: float, fmt: str = ".3f", sign: bool = False) -> str:
    if mean is None or not np.isfinite(mean):
        return "–"
    text = format(mean, ("+" if sign else "") + fmt)
    return text + (" ± n/a" if half is None or not np.isfinite(half) else f" ± {half:{fmt}}")


def _where(sc: object, looks: object) -> str:
    return f"`{sc}` ({looks} looks)"


def display_tables(axis: PolicyAxis) -> list[tuple[str, pd.DataFrame]]:
    """One display table per scenario and look budget: a row per tracker (floor first,
    then the others by their best mean, the Bayes reference and the ceiling last), per
    policy its metric, share of the gap closed and (where some policy has a stored Bayes
    reference) share of the achievable gap, then per policy other than the base the
    paired difference ``policy - base`` (:data:`BEYOND_NOISE_MARK` where its 95% interval
    excludes 0). Headed by the row group's text."""
    if axis.table.empty:
        return []
    m = axis.metric
    name = summary.column_label(m)
    truth_trackers, truth_policies = summary.truth_labels(axis.table)
    out = []
    for (sc, looks), g in axis.table.groupby(ROW_GROUP, sort=True):
        pols = [p for p in axis.policies if p in set(g["policy_label"].astype(str))]
        base = pols[0]
        with_bayes = bool(axis.bayes_policies.get((str(sc), int(looks))))
        d = axis.diffs[(axis.diffs["scenario"] == sc) & (axis.diffs["looks_per_step"] == looks)]
        roles = g.groupby("tracker_label")["role"].first()
        best_of = g.groupby("tracker_label")[f"{m}_mean"].min()
        order_key = {"floor": 0, "": 1, "bayes": 2, "ceiling": 3}
        trackers = sorted(roles.index, key=lambda t: (order_key.get(roles[t], 1),
                                                      float(best_of[t]), t))
        rows = []
        for t in trackers:
            mine = g[g["tracker_label"] == t].set_index("policy_label")
            row: dict[str, object] = {"tracker": summary.mark_truth(t, truth_trackers)}
            for p in pols:
                head = summary.mark_truth(p, truth_policies)
                if p not in mine.index:
                    row[f"{head} {name}"] = "–"
                    row[f"{head} gap closed"] = "–"
                    if with_bayes:
                        row[f"{head} of achievable"] = "–"
                    continue
                r = mine.loc[p]
                row[f"{head} {name}"] = _pm(r[f"{m}_mean"], r[f"{m}_ci95"])
                role = roles[t]
                row[f"{head} gap closed"] = (
                    "0 (floor)" if role == "floor" else "1 (ceiling)" if role == "ceiling"
                    else _pm(r["share_mean"], r["share_ci95"], ".2f"))
                if with_bayes:
                    has = p in axis.bayes_policies.get((str(sc), int(looks)), set())
                    row[f"{head} of achievable"] = (
                        "no reference" if not has else "0 (floor)" if role == "floor"
                        else "1 (bayes)" if role == "bayes"
                        else _pm(r["achievable_mean"], r["achievable_ci95"], ".2f"))
            for q in pols[1:]:
                sel = d[(d["tracker_label"] == t) & (d["policy_label"] == q)]
                head = f"{summary.mark_truth(q, truth_policies)} − {base}"
                if sel.empty:
                    row[head] = "–"
                    continue
                r = sel.iloc[0]
                row[head] = _pm(r["diff_mean"], r["diff_ci95"], sign=True) + (
                    BEYOND_NOISE_MARK if np.isfinite(r["diff_ci95"])
                    and abs(r["diff_mean"]) > r["diff_ci95"] else "")
            row["pairs"] = int(d.loc[d["tracker_label"] == t, "n_pairs"].min()) \
                if (d["tracker_label"] == t).any() else 0
            rows.append(row)
        out.append((_where(sc, looks), pd.DataFrame(rows)))
    return out


def best_lines(axis: PolicyAxis) -> list[str]:
    """One sentence per scenario and look budget: the best tracker-policy pair, its
    metric, and whether it is ahead of the runner-up beyond noise (paired)."""
    name = summary.column_label(axis.metric)
    out = []
    for r in axis.best.itertuples(index=False):
        text = (f"{_where(r.scenario, r.looks_per_step)}: best pair `{r.tracker_label}` under "
                f"`{r.policy_label}`, {name} {_pm(r.mean, r.ci95)}")
        if not r.runner_tracker:
            out.append(text + " (the only contestant pair).")
            continue
        runner = f"`{r.runner_tracker}` under `{r.runner_policy}`"
        diff = _pm(r.diff_mean, r.diff_ci95)
        if r.beyond_noise:
            text += (f"; ahead of the runner-up, {runner}, by {diff} beyond noise (paired, "
                     f"{int(r.n_pairs)} seeds)")
        else:
            text += (f"; level within noise with the runner-up, {runner} ({diff} behind, "
                     f"paired, {int(r.n_pairs)} seeds)")
        out.append(text + ".")
    return out


def bayes_lines(axis: PolicyAxis) -> list[str]:
    """Where a Bayes reference is stored under some policies of a group but not others:
    which (one line per such pattern, its groups listed; a reference's rows are never
    borrowed by another policy)."""
    patterns: dict[tuple[tuple[str, ...], tuple[str, ...]], list[str]] = {}
    for (sc, looks), have in sorted(axis.bayes_policies.items()):
        here = axis.table[(axis.table["scenario"] == sc)
                          & (axis.table["looks_per_step"] == looks)]
        pols = [p for p in axis.policies if p in set(here["policy_label"].astype(str))]
        missing = tuple(p for p in pols if p not in have)
        if have and missing:
            stored = tuple(p for p in pols if p in have)
            patterns.setdefault((stored, missing), []).append(_where(sc, looks))
    return [f"{', '.join(groups)}: the `{summary.BAYES_TRACKER}` reference is stored under "
            f"{', '.join(f'`{p}`' for p in stored)} only; none under "
            f"{', '.join(f'`{p}`' for p in missing)} (a reference is the model's Bayes "
            "filter under one policy's looks, never another's)."
            for (stored, missing), groups in patterns.items()]


def explanation(axis: PolicyAxis) -> str:
    """The paragraph that introduces the tables."""
    name = summary.column_label(axis.metric)
    base = axis.policies[0] if axis.policies else ""
    return (f"Every tracker under every policy on the same worlds (the truth and each "
            f"look's return depend on scenario and seed only), so runs on one seed are "
            f"paired across policies. Per policy: {name}, mean over seeds ± 95% t "
            "half-width; the share of the gap closed between that policy's floor "
            f"`{summary.FLOOR_TRACKER}` and ceiling `{summary.CEILING_TRACKER}` (and of the "
            f"achievable gap, to the `{summary.BAYES_TRACKER}` reference stored for that "
            "policy; `no reference` where none is), ± 95% delta-method half-width. "
            f"`Q − {base}`: the tracker's {name} under Q minus under `{base}`, seed by seed, "
            f"mean ± 95% t half-width (negative: Q is better); `{BEYOND_NOISE_MARK.strip()}`: "
            "its interval excludes 0. The best pair is the contestant (no truth, not a "
            "reference or baseline) under a policy without the truth of least mean "
            f"{name}; beyond noise when the runner-up's paired difference has its 95% "
            "interval above 0.")


def markdown(axis: PolicyAxis) -> str:
    """The section of ``summary.md`` (``""`` when no group ran two policies)."""
    if not axis.available:
        return ""
    parts = ["## Trackers x policies", "", explanation(axis), ""]
    lines = best_lines(axis) + bayes_lines(axis)
    parts += [f"- {line}" for line in lines] + ([""] if lines else [])
    for head, table in display_tables(axis):
        parts += [f"### {head}", "", _md(table), ""]
    return "\n".join(parts)


def _md(df: pd.DataFrame) -> str:
    head = [summary.md_cell(c) for c in df.columns]
    lines = ["| " + " | ".join(head) + " |",
             "|" + "|".join("---" if i == 0 else "---:" for i in range(len(head))) + "|"]
    lines += ["| " + " | ".join(summary.md_cell(v) for v in r) + " |"
              for r in df.itertuples(index=False)]
    return "\n".join(lines)

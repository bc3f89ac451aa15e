"""Budget frontiers (``mttbench frontier``): accuracy against cost as each tracker's budget
grows, on the same worlds.

Each tracker declares its budget parameters and their ranges
(:attr:`~mttbench.trackers.base.Tracker.budget`, :class:`~mttbench.trackers.params.Budget`).
A frontier sweeps the main one (the first declared, or the one ``--range NAME.PARAM=...``
names) on a log grid of ``points`` values (:meth:`~mttbench.trackers.params.Budget.grid`),
the tracker's other parameters at their defaults or as given, every setting on the same
seeds: the world depends on (scenario, seed) only, so the settings are compared on common
random numbers. A tracker that declares ``budget = {}`` (no such knob) is one point.

The sweep is an ordinary one (:func:`~mttbench.benchmarks.engine.loop.build_jobs`, the
engine's :func:`~mttbench.benchmarks.engine.sweep.run_sweep`): local pool or Dask, one
part per run, ``--resume``, a progress bar. From its rows (``results.parquet``):

* per run (:func:`per_run`): the mean OSPA over its steps, the mean tracker CPU time
  per step (``tracker_cpu_s``: predict + update + estimate, ``time.process_time``) in ms
  over the steps after the first (which carries one-off costs), the mean count error;
  only runs whose every step is ``ok``;
* per scenario x tracker x budget (:func:`frontier_table`, ``frontier.csv``): the means
  over seeds and their 95% Student-t half-widths
  (:func:`~mttbench.benchmarks.app.summary.mean_ci95`), ``n_seeds`` and ``n_failed``, and
  the paired difference to the tracker's best setting on the same seeds;
* the Pareto front across trackers (:func:`pareto_mask`): a setting is on it when no
  other setting of the scenario is at most as costly and at most as bad, and better in
  one of the two (mean CPU ms, mean OSPA); read left to right it is the lowest OSPA
  reachable for at most that CPU time;
* the cheapest budget (:func:`cheapest_within`): per scenario and tracker, the setting of
  least mean CPU ms whose mean OSPA is within :data:`TOLERANCE` (0.05) of the reference
  (:class:`Reference`, the converged Bayes filter's OSPA when given), else within 0.05 of
  the tracker's own plateau (its best mean OSPA over the budgets).

Outputs in the folder: ``results.parquet``, ``frontier.csv``, ``cheapest.csv``,
``frontier.md`` and ``frontier-<scenario>.png`` per scenario
(:func:`~mttbench.benchmarks.app.figures_frontier.frontier_figure`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...scenarios.spec import Scenario
from ...trackers.params import budget_problem
from ..engine.errors import ConfigError
from ..engine.loop import Job, build_jobs
from ..engine.specs import PolicySpec, TrackerSpec
from . import progress as _progress
from .summary import md_cell, mean_ci95, run_failures

#: a tracker's setting within this much mean OSPA of the reference (or of its plateau)
#: counts as reaching it
TOLERANCE = 0.05
#: budgets per tracker, seeds, and the most budgets one tracker may ask for
DEFAULT_POINTS = 5
DEFAULT_SEEDS = 5
MAX_POINTS = 50
TABLE_FILE, CHEAPEST_FILE, REPORT_FILE = "frontier.csv", "cheapest.csv", "frontier.md"
#: the columns of ``frontier.csv``, in order
COLUMNS = ["scenario", "tracker", "budget_param", "budget", "tracker_label", "ospa_mean",
           "ospa_ci95", "cpu_ms_mean", "cpu_ms_ci95", "count_error_mean", "count_error_ci95",
           "n_seeds", "n_failed", "ospa_minus_best_mean", "ospa_minus_best_ci95", "pareto"]


@dataclass(frozen=True)
class Reference:
    """A scenario's reference OSPA for the frontier (the converged Bayes filter's): its
    mean over the same seeds, the 95% half-width, and a label for the figure and table."""

    mean: float
    ci95: float
    label: str = "bayes"


@dataclass(frozen=True)
class Curve:
    """One tracker's budget ladder: ``base`` (the tracker as given, without the budget
    parameter), the parameter swept (None: a single point, the tracker has no budget)
    and its values."""

    base: TrackerSpec
    param: str | None
    values: tuple[Any, ...]

    @property
    def name(self) -> str:
        """The curve's name in tables and figures: the tracker's label as given."""
        return self.base.label

    def specs(self) -> list[TrackerSpec]:
        """One spec per budget (the base spec alone for a single point)."""
        if self.param is None:
            return [self.base]
        return [TrackerSpec(self.base.name, {**self.base.params, self.param: v})
                for v in self.values]


# ------------------------------------------------------------------- the ladders
_RANGE = re.compile(r"^\s*([^=\s]+?)(?:\.([A-Za-z_]\w*))?\s*=\s*([^:\s]+)\s*:\s*([^:\s]+)\s*$")


def parse_ranges(texts: Sequence[str] | None) -> dict[str, tuple[str | None, float, float]]:
    """``NAME[.PARAM]=LOW:HIGH`` items -> ``{NAME: (PARAM or None, LOW, HIGH)}``;
    :class:`ConfigError` (one line) for a malformed item or a tracker given twice."""
    out: dict[str, tuple[str | None, float, float]] = {}
    for text in texts or []:
        m = _RANGE.match(text)
        lo = hi = math.nan
        if m:
            try:
                lo, hi = float(m.group(3)), float(m.group(4))
            except ValueError:
                m = None
        if not m or not (math.isfinite(lo) and math.isfinite(hi)):
            raise ConfigError(f"--range {text!r}: expected NAME=LOW:HIGH or "
                              "NAME.PARAM=LOW:HIGH with numbers (jmpd-ap=100:4000)")
        if m.group(1) in out:
            raise ConfigError(f"--range: tracker {m.group(1)!r} given twice")
        out[m.group(1)] = (m.group(2), lo, hi)
    return out


def build_curves(specs: Sequence[TrackerSpec], points: int = DEFAULT_POINTS,
                 ranges: Mapping[str, tuple[str | None, float, float]] | None = None
                 ) -> list[Curve]:
    """The budget ladder of each tracker spec; :class:`ConfigError` (one line) for a
    tracker without a budget declaration (or a declaration its parameters refuse:
    :func:`~mttbench.trackers.params.budget_problem`), a spec that fixes the parameter swept, a
    range for an unknown tracker or parameter or outside the declaration, or points
    outside ``1..MAX_POINTS``."""
    if not 1 <= points <= MAX_POINTS:
        raise ConfigError(f"--points {points} is not allowed: expected an integer from 1 to "
                          f"{MAX_POINTS}")
    ranges = dict(ranges or {})
    names = {s.name for s in specs}
    unknown = [n for n in ranges if n not in names]
    if unknown:
        raise ConfigError(f"--range {unknown[0]!r}: not one of the --trackers "
                          f"({', '.join(sorted(names))})")
    curves = []
    for spec in specs:
        cls = spec.target()
        budget = getattr(cls, "budget", None)
        if budget is None:
            raise ConfigError(f"tracker {spec.label!r} declares no budget (Tracker.budget): "
                              "a frontier cannot sweep it")
        problem = budget_problem(cls)
        if problem:
            raise ConfigError(problem)
        param, lo, hi = ranges.get(spec.name, (None, None, None))
        if not budget:
            if spec.name in ranges:
                raise ConfigError(f"--range {spec.name!r}: the tracker has no budget "
                                  "parameter (it is one point)")
            curves.append(Curve(spec, None, ()))
            continue
        param = param or next(iter(budget))
        if param not in budget:
            raise ConfigError(f"--range {spec.name}.{param}: not a budget parameter of "
                              f"{spec.name!r} (its budget: {', '.join(budget)})")
        if param in spec.params:
            raise ConfigError(f"tracker {spec.label!r} fixes {param}, the budget the "
                              f"frontier sweeps: give its range with --range "
                              f"{spec.name}={param_range(budget[param])} instead")
        kind = (cls.declared_parameters() or {})[param].kind
        try:
            values = budget[param].grid(points, lo, hi, integer=kind is int)
        except ValueError as exc:
            raise ConfigError(f"--range {spec.name}.{param}: {exc}") from None
        curves.append(Curve(spec, param, tuple(values)))
    labels = [s.label for c in curves for s in c.specs()]
    if len(set(labels)) != len(labels):
        raise ConfigError(f"a tracker setting is given more than once: {labels}")
    return curves


def param_range(b: Any) -> str:
    """A declared range as ``--range`` takes it (``100:16000``)."""
    return f"{b.low:g}:{b.high:g}"


def frontier_jobs(scenarios: Sequence[Scenario], curves: Sequence[Curve],
                  policy: PolicySpec | None, looks: int | None, seeds: Sequence[int]
                  ) -> list[Job]:
    """Every scenario x curve x budget x seed (the engine's
    :func:`~mttbench.benchmarks.engine.loop.build_jobs`), ordered seed by seed: each
    round runs every setting once, so a machine whose load drifts during the sweep
    spreads the drift over all settings instead of timing one tracker in a busy hour."""
    specs = [s for c in curves for s in c.specs()]
    jobs = build_jobs(list(scenarios), specs, [policy] if policy else None,
                      [looks] if looks is not None else None, list(seeds))
    rank = {int(seed): i for i, seed in enumerate(seeds)}
    return sorted(jobs, key=lambda job: rank[job.seed])  # stable: settings keep their order


# ---------------------------------------------------------------------- the tables
def per_run(results: pd.DataFrame) -> pd.DataFrame:
    """One row per (scenario, tracker_label, seed): ``ok`` (every step ok), the means
    over the run's steps of ``ospa`` and ``count_error``, and ``cpu_ms``, the mean
    ``tracker_cpu_s`` over its steps after the first (in ms; the only step of a one-step
    run). The first step carries a worker's one-off costs (jmpd-ap imports numba and
    loads its cached kernels there: 0.75 s, more than 100 of its steps at N = 100),
    which a long run amortises and a short one does not."""
    if results.empty:
        return pd.DataFrame(columns=["scenario", "tracker_label", "seed", "ok", "ospa",
                                     "count_error", "cpu_ms"])
    later = results["step"] > results.groupby(
        ["scenario", "tracker_label", "seed"])["step"].transform("min")
    n_later = later.groupby([results["scenario"], results["tracker_label"],
                             results["seed"]]).transform("sum")
    timed = results["tracker_cpu_s"].where(later | (n_later == 0))
    g = results.assign(bad=results["status"] != "ok", cpu_s=timed).groupby(
        ["scenario", "tracker_label", "seed"], sort=True)
    out = g.agg(bad=("bad", "any"), ospa=("ospa", "mean"), count_error=("count_error", "mean"),
                cpu_s=("cpu_s", "mean")).reset_index()
    out["ok"] = ~out.pop("bad")
    out["cpu_ms"] = out.pop("cpu_s") * 1e3
    return out


def frontier_table(results: pd.DataFrame, curves: Sequence[Curve]) -> pd.DataFrame:
    """``frontier.csv``: per scenario x curve x budget (the order of the curves and of
    their budgets), the means over seeds with 95% half-widths, ``n_seeds`` (ok runs),
    ``n_failed`` and ``pareto`` (:func:`pareto_mask` within the scenario)."""
    runs = per_run(results)
    rows = []
    for sc in dict.fromkeys(results["scenario"]):
        for c in curves:
            for spec, v in zip(c.specs(), c.values or (math.nan,), strict=True):
                r = runs[(runs["scenario"] == sc) & (runs["tracker_label"] == spec.label)]
                ok = r[r["ok"]]
                row: dict[str, Any] = {"scenario": sc, "tracker": c.name,
                                       "budget_param": c.param or "",
                                       "budget": v, "tracker_label": spec.label}
                for col in ("ospa", "cpu_ms", "count_error"):
                    row[f"{col}_mean"], row[f"{col}_ci95"] = mean_ci95(ok[col].to_numpy(float))
                row["n_seeds"], row["n_failed"] = len(ok), int((~r["ok"]).sum())
                rows.append(row)
    table = pd.DataFrame(rows, columns=COLUMNS[:-3])
    given = table["budget"].dropna()
    if len(given) and all(float(v).is_integer() for v in given):  # 100, not 100.0
        table["budget"] = table["budget"].astype("Int64")
    table = _minus_best(table, runs)
    table["pareto"] = False
    for _, idx in table.groupby("scenario", sort=False).groups.items():
        sub = table.loc[idx]
        table.loc[idx, "pareto"] = pareto_mask(sub["cpu_ms_mean"].to_numpy(float),
                                               sub["ospa_mean"].to_numpy(float))
    return table[COLUMNS]


def _minus_best(table: pd.DataFrame, runs: pd.DataFrame) -> pd.DataFrame:
    """``ospa_minus_best_mean``/``_ci95``: per setting, the paired difference of its
    per-run OSPA minus that of its tracker's best setting (least mean OSPA) on the same
    seed, over the seeds where both runs are ok (common random numbers: far narrower than
    either interval alone). 0 at the best setting; NaN for a single point."""
    ok = runs[runs["ok"]]
    by_run = {key: g.set_index("seed")["ospa"]
              for key, g in ok.groupby(["scenario", "tracker_label"], sort=False)}
    table = table.assign(ospa_minus_best_mean=math.nan, ospa_minus_best_ci95=math.nan)
    for _, g in table.groupby(["scenario", "tracker"], sort=False):
        if g["budget_param"].iloc[0] == "" or not np.isfinite(g["ospa_mean"]).any():
            continue
        best = g.loc[g["ospa_mean"].idxmin()]
        ref = by_run[(best["scenario"], best["tracker_label"])]
        for i, r in g.iterrows():
            mine = by_run.get((r["scenario"], r["tracker_label"]))
            if mine is None:
                continue
            seeds = mine.index.intersection(ref.index)
            d = mine.loc[seeds].to_numpy(float) - ref.loc[seeds].to_numpy(float)
            table.loc[i, ["ospa_minus_best_mean", "ospa_minus_best_ci95"]] = mean_ci95(d)
    return table


def pareto_mask(cost: np.ndarray, loss: np.ndarray) -> np.ndarray:
    """``(n,)`` bool: the points ``(cost_i, loss_i)`` that no other point dominates (at
    most the cost and at most the loss, and less of one). NaN points are never on it and
    dominate nothing. Sorted by cost then loss, a point is on the front when its loss is
    below every strictly cheaper point's and the least at its own cost."""
    cost, loss = np.asarray(cost, float), np.asarray(loss, float)
    on = np.zeros(cost.shape, dtype=bool)
    good = np.flatnonzero(np.isfinite(cost) & np.isfinite(loss))
    best = math.inf  # least loss among strictly cheaper points
    order = good[np.lexsort((loss[good], cost[good]))]
    i = 0
    while i < order.size:
        same = order[cost[order] == cost[order[i]]]
        least = loss[same].min()
        if least < best:
            on[same[loss[same] == least]] = True
            best = least
        i += same.size
    return on


def cheapest_within(table: pd.DataFrame, reference: Mapping[str, Reference] | None = None,
                    tolerance: float = TOLERANCE) -> pd.DataFrame:
    """Per scenario and tracker of ``table`` (:func:`frontier_table`): the setting of
    least mean CPU ms whose mean OSPA is at most ``target``, where ``target`` is the
    scenario's reference mean + ``tolerance`` when ``reference`` has the scenario
    (``rule`` names it), else the tracker's best mean OSPA + ``tolerance`` (``rule``
    ``plateau``). No setting within the target: ``budget`` and the values NaN. Columns:
    scenario, tracker, budget_param, rule, target, budget, ospa_mean, ospa_ci95,
    cpu_ms_mean, cpu_ms_ci95, best_budget, best_ospa."""
    rows = []
    reference = reference or {}
    ok = table[np.isfinite(table["ospa_mean"].astype(float))
               & np.isfinite(table["cpu_ms_mean"].astype(float))]
    for (sc, tr), g in table.groupby(["scenario", "tracker"], sort=False):
        mine = ok[(ok["scenario"] == sc) & (ok["tracker"] == tr)]
        row: dict[str, Any] = {"scenario": sc, "tracker": tr,
                               "budget_param": g["budget_param"].iloc[0]}
        ref = reference.get(sc)
        if mine.empty:
            row.update(rule="plateau" if ref is None else ref.label, target=math.nan)
            rows.append(row)
            continue
        best = mine.loc[mine["ospa_mean"].idxmin()]
        if ref is not None:
            row.update(rule=ref.label, target=float(ref.mean) + tolerance)
        else:
            row.update(rule="plateau", target=float(best["ospa_mean"]) + tolerance)
        within = mine[mine["ospa_mean"] <= row["target"]]
        if len(within):
            pick = within.loc[within["cpu_ms_mean"].idxmin()]
            row.update({k: pick[k] for k in ("budget", "ospa_mean", "ospa_ci95",
                                             "cpu_ms_mean", "cpu_ms_ci95")})
        row.update(best_budget=best["budget"], best_ospa=float(best["ospa_mean"]))
        rows.append(row)
    cols = ["scenario", "tracker", "budget_param", "rule", "target", "budget", "ospa_mean",
            "ospa_ci95", "cpu_ms_mean", "cpu_ms_ci95", "best_budget", "best_ospa"]
    return pd.DataFrame(rows, columns=cols)


# ---------------------------------------------------------------------- the report
def _pm(mean: float, half: float, fmt: str) -> str:
    if not np.isfinite(mean):
        return "-"
    return f"{mean:{fmt}}" + ("" if not np.isfinite(half) else f" ± {half:{fmt.lstrip('+')}}")


def _budget_text(param: str, value: Any) -> str:
    if not param:
        return "(no budget)"
    if isinstance(value, float) and not np.isfinite(value):
        return "-"
    return f"{param}={value:g}" if isinstance(value, float) else f"{param}={value}"


def cheapest_caption(reference: Mapping[str, Reference] | None,
                     tolerance: float = TOLERANCE) -> str:
    """The rule of the cheapest-budget table, in words."""
    ref = ("the reference (" + ", ".join(sorted({r.label for r in reference.values()}))
           + ") where the scenario has one, else of " if reference else "")
    return (f"Cheapest budget: per scenario and tracker, the setting with the least mean CPU "
            f"ms per step whose mean OSPA is within {tolerance:g} of {ref}the tracker's own "
            "plateau (its best mean OSPA over the budgets swept). '-': no setting within "
            "it. Means over seeds ± 95% t half-widths.")


def to_markdown(table: pd.DataFrame, cheapest: pd.DataFrame, *, title: str,
                settings: Sequence[str], reference: Mapping[str, Reference] | None = None,
                figures: Mapping[str, str] | None = None) -> str:
    """``frontier.md``: the cheapest budgets first, then each scenario's frontier (with
    its figure), then the settings."""
    lines = [f"# {title}", ""]
    for sc, g in table.groupby("scenario", sort=False):  # the verdict first: the front
        front = g[g["pareto"].astype(bool)].sort_values("cpu_ms_mean")
        steps = ", then ".join(f"{md_cell(r['tracker_label'])} (OSPA {r['ospa_mean']:.3f} at "
                               f"{r['cpu_ms_mean']:.3g} ms)" for _, r in front.iterrows())
        lines.append(f"- **{md_cell(sc)}**, the Pareto front from the cheapest: {steps or '-'}.")
    lines += ["", cheapest_caption(reference), "",
             "| scenario | tracker | rule | target OSPA | cheapest budget | OSPA | CPU ms/step "
             "| best budget | best OSPA |", "|---|---|---|---|---|---|---|---|---|"]
    for _, r in cheapest.iterrows():
        lines.append(
            f"| {md_cell(r['scenario'])} | {md_cell(r['tracker'])} | {r['rule']} | "
            f"{_pm(r['target'], math.nan, '.3f')} | "
            f"{md_cell(_budget_text(r['budget_param'], r['budget']))} | "
            f"{_pm(r['ospa_mean'], r['ospa_ci95'], '.3f')} | "
            f"{_pm(r['cpu_ms_mean'], r['cpu_ms_ci95'], '.3g')} | "
            f"{md_cell(_budget_text(r['budget_param'], r['best_budget']))} | "
            f"{_pm(r['best_ospa'], math.nan, '.3f')} |")
    for sc, g in table.groupby("scenario", sort=False):
        lines += ["", f"## {sc}", ""]
        ref = (reference or {}).get(sc)
        if ref is not None:
            lines += [f"Reference ({ref.label}): OSPA {_pm(ref.mean, ref.ci95, '.3f')}.", ""]
        if figures and sc in figures:
            lines += [f"![frontier on {sc}]({figures[sc]})", ""]
        lines += ["| tracker | budget | OSPA | CPU ms/step | count error | OSPA - best "
                  "(paired) | seeds | Pareto |", "|---|---|---|---|---|---|---|---|"]
        for _, r in g.iterrows():
            seeds = f"{r['n_seeds']}" + (f" ({r['n_failed']} failed)" if r["n_failed"] else "")
            budget = md_cell(_budget_text(r["budget_param"], r["budget"]))
            lines.append(
                f"| {md_cell(r['tracker'])} | {budget} | "
                f"{_pm(r['ospa_mean'], r['ospa_ci95'], '.3f')} | "
                f"{_pm(r['cpu_ms_mean'], r['cpu_ms_ci95'], '.3g')} | "
                f"{_pm(r['count_error_mean'], r['count_error_ci95'], '.3f')} | "
                f"{_pm(r['ospa_minus_best_mean'], r['ospa_minus_best_ci95'], '+.3f')} | "
                f"{seeds} | "
                f"{'yes' if r['pareto'] else ''} |")
    lines += ["", "Pareto: no other setting of the scenario has at most its CPU ms and at most "
              "its OSPA (means), with less of one. CPU ms per step: tracker_cpu_s (predict, "
              "update, estimate; process time), the mean over a run's steps after the first "
              "(one-off costs: imports, compiled kernels), then over seeds. OSPA - best: the "
              "paired difference to the tracker's best setting on the same seeds. "
              "Every setting of a scenario runs on the same worlds (seeds).", "",
              "## Settings", "", *[f"- {s}" for s in settings], ""]
    return "\n".join(lines)


def is_finished(folder: Path) -> bool:
    """True if ``folder`` holds a finished frontier (its ``frontier.md``)."""
    return (Path(folder) / REPORT_FILE).is_file()


@dataclass
class FrontierResult:
    out_dir: Path
    results: pd.DataFrame
    table: pd.DataFrame
    cheapest: pd.DataFrame
    files: list[str]


def write_outputs(results: pd.DataFrame, curves: Sequence[Curve], out_dir: Path, *,
                  settings: Sequence[str],
                  reference: Mapping[str, Reference] | None = None) -> FrontierResult:
    """``frontier.csv``, ``cheapest.csv``, the figures and ``frontier.md`` from a
    frontier's rows (``results.parquet`` is the sweep's)."""
    from .figures_frontier import frontier_figure

    out_dir = Path(out_dir)
    table = frontier_table(results, curves)
    cheapest = cheapest_within(table, reference)
    table.to_csv(out_dir / TABLE_FILE, index=False)
    cheapest.to_csv(out_dir / CHEAPEST_FILE, index=False)
    figures = {}
    for i, sc in enumerate(dict.fromkeys(table["scenario"])):
        name = f"frontier-{_file_part(sc, i)}.png"
        frontier_figure(table, sc, out_dir / name, reference=(reference or {}).get(sc),
                        order=[c.name for c in curves])
        figures[sc] = name
    (out_dir / REPORT_FILE).write_text(
        to_markdown(table, cheapest, title="Budget frontiers", settings=settings,
                    reference=reference, figures=figures), encoding="utf-8")
    files = ["results.parquet", TABLE_FILE, CHEAPEST_FILE, REPORT_FILE, *figures.values()]
    return FrontierResult(out_dir, results, table, cheapest, files)


def _file_part(scenario: str, i: int) -> str:
    """A scenario name as a file-name part (a path given as a scenario: its stem)."""
    stem = Path(str(scenario)).stem if "/" in str(scenario) else str(scenario)
    safe = re.sub(r"[^A-Za-z0-9._-]", "_", stem)[:100]
    return safe or f"scenario{i}"


def run_frontier(jobs: list[Job], curves: Sequence[Curve], out_dir: Path, *,
                 settings: Sequence[str], workers: int = 1, progress: bool = True,
                 resume: bool = False, c: float | None = None, p: float = 2.0,
                 run_timeout: float | None = None,
                 reference: Mapping[str, Reference] | None = None) -> FrontierResult:
    """Run the frontier's ``jobs`` (:func:`frontier_jobs`) as a sweep into ``out_dir``
    (the current executor, else a local pool of ``workers``; ``resume`` skips the runs
    already saved) and write its outputs (:func:`write_outputs`)."""
    results = _progress.run_sweep(jobs, out_dir, progress=progress, workers=workers,
                                  resume=resume, c=c, p=p, run_timeout=run_timeout,
                                  store="parts")
    return write_outputs(results, curves, out_dir, settings=settings, reference=reference)


def failure_line(results: pd.DataFrame, out_dir: Path) -> str | None:
    """``k of n runs failed; first error: ...; see <out>/frontier.csv``, or None."""
    k, n, first = run_failures(results)
    if not k:
        return None
    return f"{k} of {n} runs failed; first error: {first}; see {Path(out_dir) / TABLE_FILE}"

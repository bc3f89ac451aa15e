"""``mttbench reproduce cdc2004``: non-myopic against myopic looks under time-varying
visibility, after Kreucher, Hero, Kastella and Chang (CDC 2004).

The paper tracks targets with a particle JMPD while the sensor's visibility changes
over time, and reports (its Table I as we read it) a median tracking error of 2.054 for
the myopic Renyi-gain policy against 0.932 for its value-to-go approximation: a ratio of
0.454. This module runs the comparison on the ``occlusion`` preset (our setting: the
paper's targets, grid and visibility pattern were not available to us; the preset's
description says what it holds):

* **Trackers** :data:`CDC_TRACKERS`, each under both policies on the same seeds (common
  random numbers: the truth and every look's return depend on the scenario and seed
  only, so the runs are paired): the literature-strength JMPD (``jmpd-ap``, 500
  particles, Kreucher's start: 10% of the particles on the declared initial states) and
  the GPF from its own prior.
* **Policies**: the myopic ``renyi`` (top-M distinct visible cells by the single-look
  Renyi gain) and the non-myopic ``lookahead``
  (:mod:`~mttbench.benchmarks.engine.policy_lookahead`: the gain times a value-to-go
  bracket read from the visibility of the next steps), both at the preset's looks.
* **Metric**: per run, the mean OSPA (c = 2 cells, p = 2, positions) over the steps
  ``k >= BURN_IN``; per tracker and policy the median and the mean with its 95% t
  interval over seeds; per tracker the **paired difference** (non-myopic minus myopic,
  seed by seed) with its 95% t interval, and the ratios of medians and of means
  against the paper's 0.454. The paper's error is its own multitarget RMS position
  error, not OSPA: only the ratio is comparable, and only loosely.

``--check`` (:func:`check`) is this reproduction's own, not a reference CSV:

1. structure: every run finished; every tracker has both policies on every seed of the
   setting; every step of every run made the full ``M`` looks (a look at a blind cell is
   dropped by the harness, so a shortfall is a policy that chose a blind cell; the preset
   leaves at least ``M`` cells visible at every step) and the visibility is in force
   (some step of the setting has blind cells);
2. not worse: per tracker, the lower end of the paired 95% interval of the difference
   (non-myopic minus myopic) is at most 0: the non-myopic policy is not worse than the
   myopic one beyond the Monte Carlo noise.

The runs are cached as the other reproductions' are (:func:`cache_key`: the setting,
trackers, policies, scenario text, code fingerprint and environment).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
from scipy import stats

from ... import scenarios
from ...scenarios.spec import Scenario, dumps
from ..engine.loop import Job, build_jobs
from ..engine.specs import PolicySpec, TrackerSpec
from . import reproduce
from .report import Document
from .reproduce_kreucher import per_seed
from .summary import mean_ci95

#: the trackers compared (the paper's is a particle JMPD)
CDC_TRACKERS: tuple[str, ...] = ("jmpd-ap:n_particles=500,init_fraction=0.1", "gpf")
#: the myopic and the non-myopic policy
MYOPIC, NONMYOPIC = "renyi", "lookahead"
#: the scenario
CDC_PRESET = "occlusion"
#: steps before this are left out of each run's mean OSPA
BURN_IN = 10
#: the paper's Table I medians as we read them (its own RMS error, not OSPA)
PAPER_MEDIANS = {"myopic": 2.054, "non-myopic": 0.932}
PAPER_RATIO = PAPER_MEDIANS["non-myopic"] / PAPER_MEDIANS["myopic"]


@dataclass(frozen=True)
class CdcSetting:
    """A pinned setting of the non-myopic reproduction."""

    name: str
    n_steps: int
    seeds: tuple[int, ...]
    trackers: tuple[str, ...] = CDC_TRACKERS
    myopic: str = MYOPIC
    nonmyopic: str = NONMYOPIC
    preset: str = CDC_PRESET
    burn_in: int = BURN_IN
    c: float = 2.0
    p: float = 2.0


SETTINGS = {
    # seeds 100-139: the policy's parameters were chosen on other worlds (docs/nonmyopic.md)
    "full": CdcSetting("full", 100, tuple(range(100, 140))),
    "reduced": CdcSetting("reduced", 40, (0, 1, 2),
                          trackers=("jmpd-ap:n_particles=200,init_fraction=0.1",)),
}


# ------------------------------------------------------------------------- runs
def setting_scenario(setting: CdcSetting) -> Scenario:
    """The preset with the setting's number of steps."""
    return dataclasses.replace(scenarios.get(setting.preset), n_steps=setting.n_steps)


def policy_specs(setting: CdcSetting) -> list[PolicySpec]:
    """The myopic and the non-myopic policy, checked (canonical values)."""
    return [PolicySpec.parse(t).validated() for t in (setting.myopic, setting.nonmyopic)]


def setting_jobs(setting: CdcSetting, specs: list[TrackerSpec]) -> list[Job]:
    """Every tracker under both policies at the preset's looks, every seed."""
    sc = setting_scenario(setting)
    return build_jobs([sc], specs, policy_specs(setting), [sc.model.sensor.looks_per_step],
                      list(setting.seeds))


def cache_key(setting: CdcSetting, specs: list[TrackerSpec], env: dict | None = None) -> str:
    """Hash of everything that determines the runs, ``cdc2004-`` first."""
    ident = {
        "reproduction": "cdc2004",
        "setting": dataclasses.asdict(setting),
        "trackers": [[s.name, s.params] for s in specs],
        "policies": [[s.name, s.params] for s in policy_specs(setting)],
        "scenario": dumps(setting_scenario(setting)),
        "code": reproduce.code_fingerprint(),
        "environment": reproduce.environment() if env is None else env,
    }
    text = json.dumps(ident, sort_keys=True, default=str)
    return "cdc2004-" + hashlib.sha256(text.encode()).hexdigest()[:20]


def run_or_load(setting: CdcSetting, specs: list[TrackerSpec], cache_dir: Path, *,
                workers: int = 1, progress: bool = True, use_cache: bool = True,
                run_timeout: float | None = None) -> tuple[pd.DataFrame, bool]:
    """The sweep's results table, from the cache when it holds this key; ``(results,
    cached)``. ``use_cache=False`` neither reads nor writes ``cache_dir``
    (:func:`~mttbench.benchmarks.app.reproduce.cached_sweep`)."""
    folder = Path(cache_dir) / cache_key(setting, specs) if use_cache else None
    return reproduce.cached_sweep(setting_jobs(setting, specs), folder, "cdc2004", setting.name,
                                  c=setting.c, p=setting.p, workers=workers,
                                  progress=progress, run_timeout=run_timeout)


# ---------------------------------------------------------------------- numbers
def policy_table(runs: pd.DataFrame) -> pd.DataFrame:
    """Per tracker and policy: ``n_seeds``, ``ospa_median``, ``ospa_mean``, ``ospa_ci95``
    and ``lost_fraction`` of the per-seed table (:func:`per_seed`)."""
    rows = []
    for (tracker, policy), g in runs.groupby(["tracker_label", "policy"], sort=True):
        m, h = mean_ci95(g["ospa"].to_numpy(float))
        rows.append({"tracker": tracker, "policy": policy, "n_seeds": len(g),
                     "ospa_median": float(g["ospa"].median()), "ospa_mean": m,
                     "ospa_ci95": h, "lost_fraction": float(g["lost"].mean())})
    return pd.DataFrame(rows, columns=["tracker", "policy", "n_seeds", "ospa_median",
                                       "ospa_mean", "ospa_ci95", "lost_fraction"])


def paired_table(runs: pd.DataFrame, setting: CdcSetting) -> pd.DataFrame:
    """Per tracker: the seeds both policies finished (``n_pairs``), the mean paired
    difference non-myopic minus myopic (``diff_mean``) with its 95% t interval
    (``diff_low``, ``diff_high``), the ratios non-myopic / myopic of the medians and of
    the means, and the paper's ratio."""
    myopic = PolicySpec.parse(setting.myopic).name
    nonmyopic = PolicySpec.parse(setting.nonmyopic).name
    rows = []
    for tracker, g in runs.groupby("tracker_label", sort=True):
        wide = g.pivot_table(index="seed", columns="policy", values="ospa")
        if not {myopic, nonmyopic} <= set(wide.columns):
            continue
        wide = wide[[myopic, nonmyopic]].dropna()
        d = (wide[nonmyopic] - wide[myopic]).to_numpy(float)
        n = d.size
        mean = float(d.mean()) if n else math.nan
        half = (float(stats.t.ppf(0.975, n - 1) * d.std(ddof=1) / math.sqrt(n))
                if n > 1 else math.nan)
        rows.append({
            "tracker": tracker, "n_pairs": n, "diff_mean": mean,
            "diff_low": mean - half, "diff_high": mean + half,
            "ratio_median": float(wide[nonmyopic].median() / wide[myopic].median()),
            "ratio_mean": float(wide[nonmyopic].mean() / wide[myopic].mean()),
            "paper_ratio": PAPER_RATIO})
    return pd.DataFrame(rows, columns=["tracker", "n_pairs", "diff_mean", "diff_low",
                                       "diff_high", "ratio_median", "ratio_mean",
                                       "paper_ratio"])


def short_steps(results: pd.DataFrame) -> pd.DataFrame:
    """The finished steps that made fewer looks than the run's ``M`` (a look at a blind
    cell, dropped by the harness)."""
    ok = results[(results["step"] >= 0) & (results["status"] == "ok")]
    return ok[ok["n_looks"] < ok["looks_per_step"]]


# ------------------------------------------------------------------------ check
@dataclass(frozen=True)
class Check:
    """The outcome of :func:`check`: passed, and one line per failed condition."""

    passed: bool
    lines: list[str]
    n_conditions: int


def check(setting: CdcSetting, specs: list[TrackerSpec], results: pd.DataFrame) -> Check:
    """The module docstring's conditions on a sweep's results."""
    lines: list[str] = []
    n = 0
    bad = results[results["status"] == "error"]
    n += 1
    if len(bad):
        lines.append(f"{bad.groupby(['tracker_label', 'policy', 'seed']).ngroups} run(s) "
                     f"failed, first: {bad['error'].iloc[0]}")
    runs = per_seed(results, setting.burn_in)
    want = set(setting.seeds)
    for spec in specs:
        for pol in policy_specs(setting):
            n += 1
            got = set(runs[(runs["tracker_label"] == spec.label)
                           & (runs["policy"] == pol.name)]["seed"])
            if got != want:
                lines.append(f"{spec.label} / {pol.name}: seeds {sorted(want - got)} missing")
    n += 1
    short = short_steps(results)
    if len(short):
        r = short.iloc[0]
        lines.append(f"{len(short)} step(s) made fewer than M looks (a look at a blind cell), "
                     f"first: {r['tracker_label']} / {r['policy']} seed {r['seed']} step "
                     f"{r['step']}: {r['n_looks']} of {r['looks_per_step']}")
    n += 1
    sc = setting_scenario(setting)
    if not any(sc.model.blocked_cells(k).size for k in range(sc.n_steps)):
        lines.append(f"no step of {sc.name!r} ({sc.n_steps} steps) has a blind cell")
    paired = paired_table(runs, setting)
    for spec in specs:
        n += 1
        row = paired[paired["tracker"] == spec.label]
        if row.empty or row["n_pairs"].iloc[0] < 2:
            lines.append(f"{spec.label}: fewer than 2 paired seeds")
        elif row["diff_low"].iloc[0] > 0:
            r = row.iloc[0]
            lines.append(f"{spec.label}: {setting.nonmyopic} is worse than {setting.myopic} "
                         f"beyond noise (paired OSPA difference {r['diff_mean']:+.3f}, 95% "
                         f"[{r['diff_low']:+.3f}, {r['diff_high']:+.3f}])")
    return Check(not lines, lines, n)


# ------------------------------------------------------------------------ report
def _f(v: float, fmt: str = ".3f") -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:{fmt}}"


def verdict_lines(paired: pd.DataFrame, setting: CdcSetting) -> list[str]:
    """What matches the paper and what does not, one line per tracker."""
    out = []
    for r in paired.itertuples():
        if r.diff_high < 0:
            sign = f"{setting.nonmyopic} beats {setting.myopic} (paired upper bound below 0)"
        elif r.diff_low > 0:
            sign = (f"{setting.nonmyopic} is worse than {setting.myopic} (paired lower "
                    "bound above 0)")
        else:
            sign = "no difference resolved (the paired interval contains 0)"
        out.append(f"`{r.tracker}`: {sign}; mean difference {r.diff_mean:+.3f} "
                   f"[{r.diff_low:+.3f}, {r.diff_high:+.3f}] over {r.n_pairs} seeds; ratio "
                   f"of medians {r.ratio_median:.3f}, of means {r.ratio_mean:.3f}, against "
                   f"the paper's {PAPER_RATIO:.3f}")
    return out


def _write_report(out: Path, setting: CdcSetting, specs: list[TrackerSpec],
                  missing: list[str], table: pd.DataFrame, paired: pd.DataFrame,
                  cached: bool, failures: list[str]) -> None:
    sc = setting_scenario(setting)
    doc = Document()
    doc.add("h1", f"Non-myopic against myopic looks under occlusion ({setting.name} setting)")
    doc.add("p", "Command: `mttbench reproduce cdc2004"
            + (" --reduced" if setting.name == "reduced" else "") + "`. Kreucher, Hero, "
            "Kastella and Chang (CDC 2004) report that with time-varying visibility a "
            "value-to-go approximation roughly halves the myopic tracking error (Table I "
            f"as we read it: median {PAPER_MEDIANS['myopic']} myopic, "
            f"{PAPER_MEDIANS['non-myopic']} non-myopic, ratio {PAPER_RATIO:.3f}).")
    doc.add("list", [
        f"scenario: `{sc.name}` ({sc.n_steps} steps): {sc.description}",
        "trackers: " + ", ".join(f"`{s.label}`" for s in specs)
        + (f" (not registered, left out: {', '.join(missing)})" if missing else ""),
        "policies: " + ", ".join(f"`{p.label}`" for p in policy_specs(setting))
        + f" at {sc.model.sensor.looks_per_step} looks per step",
        f"seeds: {', '.join(map(str, setting.seeds))} (paired: same worlds for both policies)",
        f"error: each run's mean OSPA (c = {setting.c:g} cells, p = {setting.p:g}) over steps "
        f">= {setting.burn_in}",
        f"runs {'loaded from the cache' if cached else 'computed'}",
    ])
    if failures:
        doc.add("h2", "Runs that failed (excluded)")
        doc.add("list", failures)
    doc.add("h2", "Against the paper")
    doc.add("list", verdict_lines(paired, setting) + [
        "Not comparable: the paper's error is its multitarget RMS position error on its "
        "own scenario (targets, grid, visibility pattern, number of looks), which we "
        "could not read; ours is OSPA on the `occlusion` preset. Only the direction and "
        "the ratio are compared."])
    doc.add("h2", "Per tracker and policy")
    doc.add("table", pd.DataFrame({
        "tracker": table["tracker"], "policy": table["policy"], "seeds": table["n_seeds"],
        "OSPA median": table["ospa_median"].map(_f),
        "OSPA mean": [f"{_f(m)} ± {_f(h)}" for m, h in zip(table["ospa_mean"],
                                                          table["ospa_ci95"], strict=True)],
        "lost": table["lost_fraction"].map(lambda v: f"{v:.0%}")}))
    doc.add("h2", "Paired difference (non-myopic minus myopic)")
    doc.add("table", pd.DataFrame({
        "tracker": paired["tracker"], "pairs": paired["n_pairs"],
        "mean difference": paired["diff_mean"].map(lambda v: f"{v:+.3f}"),
        "95% interval": [f"[{lo:+.3f}, {hi:+.3f}]" for lo, hi in
                         zip(paired["diff_low"], paired["diff_high"], strict=True)],
        "ratio of medians": paired["ratio_median"].map(_f),
        "ratio of means": paired["ratio_mean"].map(_f),
        "paper's ratio": paired["paper_ratio"].map(_f)}))
    (out / "report.md").write_text(doc.markdown(out), encoding="utf-8")
    (out / "report.html").write_text(doc.html("mttbench: non-myopic against myopic looks"),
                                     encoding="utf-8")


@dataclass(frozen=True)
class CdcReproduction:
    out_dir: Path
    results: pd.DataFrame
    table: pd.DataFrame
    paired: pd.DataFrame
    specs: list[TrackerSpec]
    cached: bool


def reproduce_cdc2004(setting: CdcSetting, out_dir: str | Path, cache_dir: str | Path, *,
                      tracker_texts: tuple[str, ...] | None = None, workers: int = 1,
                      progress: bool = True, use_cache: bool = True,
                      run_timeout: float | None = None) -> CdcReproduction:
    """Run (or load) the setting; write ``policies.csv``, ``paired.csv``, ``report.md``
    and ``report.html`` into ``out_dir``."""
    setting, specs, missing, out = reproduce.start(setting, tracker_texts, out_dir)
    results, cached = run_or_load(setting, specs, Path(cache_dir), workers=workers,
                                  progress=progress, use_cache=use_cache,
                                  run_timeout=run_timeout)
    runs = per_seed(results, setting.burn_in)
    table = policy_table(runs)
    paired = paired_table(runs, setting)
    runs.to_csv(out / "runs.csv", index=False)
    table.to_csv(out / "policies.csv", index=False)
    paired.to_csv(out / "paired.csv", index=False)
    bad = results[results["status"] == "error"]
    failures = sorted({f"{r.tracker_label} / {r.policy_label} seed {r.seed}: {r.error}"
                       for r in bad.itertuples()})
    _write_report(out, setting, specs, missing, table, paired, cached, failures)
    return CdcReproduction(out, results, table, paired, specs, cached)


def summary_lines(rep: CdcReproduction, setting: CdcSetting) -> list[str]:
    """The verdict, one line per tracker (printed by the command)."""
    return verdict_lines(rep.paired, setting)


__all__ = ["CDC_TRACKERS", "PAPER_MEDIANS", "PAPER_RATIO", "SETTINGS", "Check", "CdcSetting",
           "check", "paired_table", "policy_table", "reproduce_cdc2004", "setting_jobs"]

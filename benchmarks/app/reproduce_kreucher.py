"""``mttbench reproduce kreucher``: Kreucher's managed-versus-periodic curve, checked.

Kreucher, Kastella and Hero (Signal Processing 2005, Sec. 5.1; docs/literature/jmpd.md
Sec. 7.1) track three simulated targets whose paths cross twice on a 12x12 grid with
``p_d = 0.5`` and report that 24 managed looks per step (Rényi-divergence gain) give the
error of about 312 periodic looks (a raster scan), "about 13 times" fewer. This module
runs that comparison on the ``kreucher`` preset:

* **Scenarios.** ``kreucher`` (snr 10) and ``kreucher-snr2``: the same preset with the
  sensor's linear ``snr`` replaced by 2 (``dataclasses.replace`` on the loaded
  :class:`~mttbench.scenarios.spec.Scenario`, renamed; its description says so). The
  13x claim rests on SNR 2-3; at SNR >= 9 every scan of 120 looks or more lies within
  about 0.05 cell of the managed one (jmpd.md Sec. 7.1 and Sec. 9 item 15). The
  simulator keys a world on the scenario's name, so ``kreucher-snr2`` has its own
  trajectories (same design, other noise).
* **Trackers** :data:`KREUCHER_TRACKERS`, each under every policy of the setting: the
  literature-strength JMPD (``jmpd-ap``, 500 particles as in Kreucher's study) from its
  own prior, the same with Kreucher's start (``init_fraction=0.1``: 10% of the particles
  hold the preset's declared initial states; the others start from no target), and the
  GPF from its own prior (it has no such start). Kreucher's 13x was measured with his
  start; from nothing, at SNR 2 (``p_f = 0.125``) the trackers rarely acquire the
  targets.
* **Policies.** The managed scans of :data:`KREUCHER_MANAGED` at
  :data:`MANAGED_LOOKS` = 24 looks: ``renyi`` (the project's default, distinct top-M
  cells, alpha = 0.5), ``renyi:repeats=true`` (greedy on the marginal gain, a cell may
  get several looks) and Kreucher's own choice ``renyi:alpha=0.99999,repeats=true``
  (jmpd.md Sec. 9 item 17). At SNR 2 one look says little, and the repeated looks
  matter. The periodic
  scan ``raster`` at :data:`RASTER_LOOKS` = 24, 48, 72, 144, 216, 312 looks: a pointer
  advancing M cells per step, row by row from the bottom row, wrapping around, so 216 and
  312 looks revisit cells within a step (216: every cell once and 72 twice; 312: every
  cell twice and 24 three times; :class:`~mttbench.benchmarks.engine.policies.Raster`).
* **Metric.** Per run (one seed): the mean OSPA (the harness's c = 2 cells, p = 2, on
  positions) over the steps ``k >= BURN_IN`` (10: acquisition from the tracker's own
  prior is not what the curve measures). Over the seeds: the **median** (Kreucher plots
  the median) and the **mean** with its 95% t interval (occasional losses hide behind the
  median; SPIE03b's mean panel tells another story). A seed is **lost** when its mean
  OSPA over the last :data:`LOST_WINDOW` = 10 steps is at least :data:`LOST_OSPA` = 1
  cell: with three targets, c = 2 and p = 2 one missing target alone gives
  ``sqrt(c^2 / 3) = 1.15``. Failed runs are excluded and listed.
* **Matched looks** (:func:`matched_looks`): the raster curve, OSPA against
  ``log(looks)``, is interpolated linearly between its points and the first point where
  it comes down to the managed value is the number of periodic looks that matches 24
  managed ones; the ratio is that over 24. When the managed value is below every raster
  point it is reported as ``>= 312`` ("beyond the curve"); when it is above raster at 24
  looks, as ``< 24``. Done separately for the median and for the mean.
* **Crossings** (:data:`KREUCHER_CROSSINGS` = steps 30 and 70): for the raster scan of
  every cell once per step (144 looks), the mean OSPA over the 20 steps before and the 20
  steps from each crossing (the goal: after at most 1.5x before), when both windows fit in the run.
  Noise drifts the targets: the preset's description gives how often they really share
  a cell (tests/test_kreucher_presets.py).

Outputs in ``reports/kreucher/`` (``--out``): ``fig_managed_vs_periodic.png``,
``curve.csv`` (one row per scenario, tracker, policy and looks), ``matched.csv``,
``crossings.csv``, ``numbers_<setting>.csv`` (every number, one long table with the
columns of :data:`~mttbench.benchmarks.app.reproduce.KEYS`), ``report.md`` and ``report.html``.

Cache and checks reuse :mod:`~mttbench.benchmarks.app.reproduce`: the runs are cached under
``<cache>/kreucher-<key>/`` where the key hashes the setting, the resolved trackers and
policies, the scenarios as run (the SNR-2 variant and the step count included), the
code fingerprint (:func:`~mttbench.benchmarks.app.reproduce.code_fingerprint`) and the
environment (:func:`~mttbench.benchmarks.app.reproduce.environment`); everything in this
module besides the jobs only summarises the cached table, so it is not hashed.
``--check`` is :func:`~mttbench.benchmarks.app.reproduce.check_numbers` on the long table,
laid out so that its Monte Carlo bands apply: the rows of ``figure = "error"`` hold, per
scenario and ``tracker = "<tracker> / <policy>"``, the mean over seeds of each run's
mean OSPA (``state_error``), count error and estimated count with their 95% half-widths,
the mean true count and ``n_seeds``, and their ``step`` column holds the **look budget**
(the curve runs over looks, not time). A curve (a tracker and policy) passes when the
mean of ``|now - ref| / (band + floor)`` over its look budgets is at most 1 and no
budget exceeds 4; true counts and seed counts are exact; ``figure = "snapshot"`` rows
hold the true positions of seed 0 at the crossing steps and the last step (exact: the
simulated world).
The medians, lost fractions, matched looks and crossing numbers (``figure`` =
``summary``, ``matched``, ``crossing``) are compared by ``--check --exact`` only
(bit for bit, same package versions). References: ``reports/reference/kreucher_<setting>.csv``
with its ``.versions.json`` (``--update-reference``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ... import scenarios
from ...scenarios.simulator import simulate
from ...scenarios.spec import Scenario, dumps
from ..engine.loop import Job, build_jobs
from ..engine.specs import PolicySpec, TrackerSpec
from . import figures_kreucher, reproduce
from .report import Document
from .summary import mean_ci95

#: the trackers compared: the literature-strength JMPD with Kreucher's 500 particles,
#: from its own prior (no target) and with Kreucher's start (10% of the particles on the
#: preset's declared initial states, SP 2005 Sec. 5.1), and the GPF from its own prior
KREUCHER_TRACKERS: tuple[str, ...] = ("jmpd-ap:n_particles=500",
                                      "jmpd-ap:n_particles=500,init_fraction=0.1", "gpf")
#: the steps at which the preset's nominal paths meet in one cell (A-B, then A-C)
KREUCHER_CROSSINGS: tuple[int, ...] = (30, 70)
#: the preset whose variants are run
KREUCHER_PRESET = "kreucher"
#: linear SNRs; the preset's own (10) keeps its name, others are ``kreucher-snr<v>``
KREUCHER_SNRS: tuple[float, ...] = (2.0, 10.0)
#: managed scans (at :data:`MANAGED_LOOKS` looks): the project's default and Kreucher's
KREUCHER_MANAGED: tuple[str, ...] = ("renyi", "renyi:repeats=true",
                                     "renyi:alpha=0.99999,repeats=true")
MANAGED_LOOKS = 24
#: periodic scans: Kreucher's 24, 72, 216, 312 plus 48 and 144 (every cell once per step)
RASTER_LOOKS: tuple[int, ...] = (24, 48, 72, 144, 216, 312)
#: steps before this are left out of each run's mean OSPA (acquisition)
BURN_IN = 10
#: a seed is lost when its mean OSPA over the last LOST_WINDOW steps is >= LOST_OSPA cells
LOST_WINDOW = 10
LOST_OSPA = 1.0
#: the crossing windows: OSPA over the CROSSING_WINDOW steps before and from each crossing
CROSSING_WINDOW = 20
#: the name of a periodic scan in the tables
PERIODIC = "raster"

#: Kreucher's medians read off SP05 Fig. 3 (+-0.03; multitarget RMS error per target in
#: cells, not OSPA), from docs/literature/jmpd.md Sec. 7.1: {snr: {scan: median}}
SP05_MEDIANS: dict[float, dict[str, float]] = {
    2.0: {"periodic 24": 1.95, "periodic 72": 1.63, "periodic 120": 0.99, "periodic 216": 0.77,
          "periodic 312": 0.62, "managed 24": 0.47},
    9.0: {"periodic 24": 0.68, "periodic 72": 0.44, "periodic 120": 0.39, "periodic 216": 0.35,
          "periodic 312": 0.35, "managed 24": 0.35},
}


@dataclass(frozen=True)
class KreucherSetting:
    """A pinned setting of the managed-versus-periodic reproduction."""

    name: str
    n_steps: int
    seeds: tuple[int, ...]
    trackers: tuple[str, ...] = KREUCHER_TRACKERS
    snrs: tuple[float, ...] = KREUCHER_SNRS
    managed: tuple[str, ...] = KREUCHER_MANAGED
    managed_looks: int = MANAGED_LOOKS
    raster_looks: tuple[int, ...] = RASTER_LOOKS
    burn_in: int = BURN_IN
    preset: str = KREUCHER_PRESET
    c: float = 2.0
    p: float = 2.0


SETTINGS = {
    "full": KreucherSetting("full", 100, tuple(range(20))),
    "reduced": KreucherSetting("reduced", 50, (0, 1, 2)),
}


# ------------------------------------------------------------------- the runs
def snr_name(preset: str, snr: float, own_snr: float) -> str:
    """``preset`` at its own SNR, else ``<preset>-snr<snr>`` (e.g. ``kreucher-snr2``)."""
    return preset if snr == own_snr else f"{preset}-snr{snr:g}"


def setting_scenarios(setting: KreucherSetting) -> list[Scenario]:
    """The preset at each SNR of the setting, ``n_steps`` set, in the setting's order."""
    base = scenarios.get(setting.preset)
    sensor = base.model.sensor
    out = []
    for snr in setting.snrs:
        sc = base
        if snr != sensor.snr:
            sc = dataclasses.replace(
                base, name=snr_name(setting.preset, snr, sensor.snr),
                description=f"the {setting.preset} preset with the sensor's linear snr "
                            f"{sensor.snr:g} replaced by {snr:g} (p_f = "
                            f"{sensor.p_d ** (1 + snr):.3g})",
                model=dataclasses.replace(base.model,
                                          sensor=dataclasses.replace(sensor, snr=float(snr))))
        out.append(dataclasses.replace(sc, n_steps=setting.n_steps))
    return out


def policy_specs(setting: KreucherSetting) -> list[PolicySpec]:
    """The managed policies of the setting, checked (canonical values)."""
    return [PolicySpec.parse(t).validated() for t in setting.managed]


def setting_jobs(setting: KreucherSetting, specs: list[TrackerSpec]) -> list[Job]:
    """The harness jobs: per scenario, each tracker under raster at every budget of
    ``raster_looks`` and under each managed policy at ``managed_looks``, every seed."""
    seeds = list(setting.seeds)
    jobs: list[Job] = []
    for sc in setting_scenarios(setting):
        jobs += build_jobs([sc], specs, [PolicySpec(PERIODIC)], list(setting.raster_looks),
                           seeds)
        jobs += build_jobs([sc], specs, policy_specs(setting), [setting.managed_looks], seeds)
    return jobs


def cache_key(setting: KreucherSetting, specs: list[TrackerSpec],
              env: dict | None = None) -> str:
    """Hash of everything that determines the runs (module docstring), ``kreucher-`` first."""
    ident = {
        "reproduction": "kreucher",
        "setting": dataclasses.asdict(setting),
        "trackers": [[s.name, s.params] for s in specs],
        "policies": [[s.name, s.params] for s in policy_specs(setting)],
        "scenarios": [dumps(sc) for sc in setting_scenarios(setting)],
        "code": reproduce.code_fingerprint(),
        "environment": reproduce.environment() if env is None else env,
    }
    text = json.dumps(ident, sort_keys=True, default=str)
    return "kreucher-" + hashlib.sha256(text.encode()).hexdigest()[:20]


def run_or_load(setting: KreucherSetting, specs: list[TrackerSpec], cache_dir: Path, *,
                workers: int = 1, progress: bool = True, use_cache: bool = True,
                run_timeout: float | None = None) -> tuple[pd.DataFrame, bool]:
    """The sweep's results table, from the cache when it holds this key; ``(results,
    cached)``. ``use_cache=False`` neither reads nor writes ``cache_dir``
    (:func:`~mttbench.benchmarks.app.reproduce.cached_sweep`)."""
    folder = Path(cache_dir) / cache_key(setting, specs) if use_cache else None
    return reproduce.cached_sweep(setting_jobs(setting, specs), folder, "kreucher", setting.name,
                                  c=setting.c, p=setting.p, workers=workers,
                                  progress=progress, run_timeout=run_timeout)


# ---------------------------------------------------------------- the numbers
RUN_COLUMNS = ["scenario", "tracker_label", "policy", "policy_label", "looks_per_step", "seed"]


def per_seed(results: pd.DataFrame, burn_in: int = BURN_IN, lost_window: int = LOST_WINDOW,
             lost_ospa: float = LOST_OSPA) -> pd.DataFrame:
    """One row per run that finished (no ``error`` row): the means over its steps
    ``k >= burn_in`` of OSPA, count error, estimated and true count (``ospa``,
    ``count_error``, ``est_count``, ``true_count``), the mean OSPA over its last
    ``lost_window`` steps (``ospa_final``) and ``lost = ospa_final >= lost_ospa``."""
    res = results[results["step"] >= 0]
    failed = res[res["status"] == "error"].groupby(RUN_COLUMNS).size().index
    keyed = res.set_index(RUN_COLUMNS)
    keyed = keyed[~keyed.index.isin(failed)].reset_index()
    if keyed.empty:
        return pd.DataFrame(columns=[*RUN_COLUMNS, "ospa", "count_error", "est_count",
                                     "true_count", "ospa_final", "lost"])
    last = keyed.groupby(RUN_COLUMNS)["step"].transform("max")
    after = keyed[keyed["step"] >= burn_in]
    # Kreucher's count error is the tracker's own count's
    after = after.assign(count_error=after["own_count_error"])
    out = after.groupby(RUN_COLUMNS)[["ospa", "count_error", "est_count", "true_count"]].mean()
    final = keyed[keyed["step"] > last - lost_window].groupby(RUN_COLUMNS)["ospa"].mean()
    out["ospa_final"] = final
    out["lost"] = out["ospa_final"] >= lost_ospa
    return out.reset_index()


def revisits(looks: int, n_cells: int) -> str:
    """How a raster scan of ``looks`` on ``n_cells`` cells repeats cells within a step."""
    q, r = divmod(int(looks), int(n_cells))
    if q == 0 or (q == 1 and r == 0):
        return "no"
    if r == 0:
        return f"every cell {q}x"
    times = "twice" if q + 1 == 2 else f"{q + 1}x"
    return f"every cell {q}x, {r} cells {times}"


def curve_table(runs: pd.DataFrame, setting: KreucherSetting) -> pd.DataFrame:
    """One row per scenario, tracker, policy and looks: ``n_seeds``, ``ospa_median``,
    ``ospa_mean`` and ``ospa_ci95``, the same for the count error and the estimated
    count (mean and half-width), the mean true count, ``lost_fraction``; ``kind``
    (``periodic`` or ``managed``), ``snr`` and ``revisits`` (raster beyond the cell count)."""
    snr = {sc.name: sc.model.sensor.snr for sc in setting_scenarios(setting)}
    n_cells = scenarios.get(setting.preset).grid.n_cells
    rows = []
    keys = ["scenario", "tracker_label", "policy", "policy_label", "looks_per_step"]
    for key, g in runs.groupby(keys, sort=True):
        sc, tracker, pol, pol_label, looks = key
        row = {"scenario": sc, "snr": snr.get(sc, math.nan), "tracker": tracker,
               "policy": pol_label, "kind": "periodic" if pol == PERIODIC else "managed",
               "looks": int(looks), "n_seeds": len(g),
               "ospa_median": float(g["ospa"].median())}
        for col in ("ospa", "count_error", "est_count"):
            m, h = mean_ci95(g[col].to_numpy(float))
            row[f"{col}_mean"], row[f"{col}_ci95"] = m, h
        row["true_count_mean"] = float(g["true_count"].mean())
        row["lost_fraction"] = float(g["lost"].mean())
        row["revisits"] = (revisits(looks, n_cells) if pol == PERIODIC else
                           "allowed" if "repeats=True" in pol_label else "no")
        rows.append(row)
    cols = ["scenario", "snr", "tracker", "policy", "kind", "looks", "revisits", "n_seeds",
            "ospa_median", "ospa_mean", "ospa_ci95", "count_error_mean", "count_error_ci95",
            "est_count_mean", "est_count_ci95", "true_count_mean", "lost_fraction"]
    return pd.DataFrame(rows, columns=cols)


@dataclass(frozen=True)
class Match:
    """The periodic looks that match a managed scan's error (:func:`matched_looks`).

    ``looks`` is the interpolated budget when ``bound == 0``; the largest raster budget
    with ``bound = +1`` (the managed scan beats every raster point: "at least"); the
    smallest with ``bound = -1`` (it is worse than raster at that budget: "fewer than");
    NaN when a value is missing."""

    looks: float
    bound: int

    def ratio(self, managed_looks: int) -> float:
        return self.looks / managed_looks

    def text(self) -> str:
        if math.isnan(self.looks):
            return "n/a"
        if self.bound > 0:
            return f">= {self.looks:g} (beyond the curve)"
        if self.bound < 0:
            return f"< {self.looks:g}"
        return f"{self.looks:.0f}"

    def ratio_text(self, managed_looks: int) -> str:
        if math.isnan(self.looks):
            return "n/a"
        sign = {1: ">= ", -1: "< ", 0: ""}[self.bound]
        return f"{sign}{self.ratio(managed_looks):.1f}x"


def matched_looks(looks: Sequence[float], errors: Sequence[float], target: float) -> Match:
    """The raster budget whose error equals ``target``: ``errors`` against ``log(looks)``
    interpolated linearly, the first point (in increasing looks) where the curve comes
    down to ``target``.

    ``target`` above the error at the smallest budget: ``Match(smallest, -1)``; below
    every error: ``Match(largest, +1)``; a NaN anywhere: ``Match(nan, 0)``."""
    x = np.asarray(looks, dtype=float)
    y = np.asarray(errors, dtype=float)
    order = np.argsort(x, kind="stable")
    x, y = x[order], y[order]
    if x.size == 0 or math.isnan(target) or np.isnan(y).any():
        return Match(math.nan, 0)
    if target > y[0]:
        return Match(float(x[0]), -1)
    j = int(np.argmax(y <= target)) if (y <= target).any() else -1
    if j < 0:
        return Match(float(x[-1]), +1)
    if j == 0 or y[j] == target:  # on a point of the curve: its budget, exactly
        return Match(float(x[j]), 0)
    t = (y[j - 1] - target) / (y[j - 1] - y[j])  # y[j-1] > target >= y[j]
    lx = math.log(x[j - 1]) + t * (math.log(x[j]) - math.log(x[j - 1]))
    return Match(float(math.exp(lx)), 0)


def matched_table(curve: pd.DataFrame, managed_looks: int = MANAGED_LOOKS) -> pd.DataFrame:
    """Per scenario, tracker and managed policy: its median and mean OSPA and the raster
    budget matching each (:func:`matched_looks`), as numbers and as text."""
    rows = []
    for (sc, tracker), g in curve.groupby(["scenario", "tracker"], sort=True):
        raster = g[g["kind"] == "periodic"].sort_values("looks")
        for m in g[g["kind"] == "managed"].itertuples():
            row = {"scenario": sc, "snr": m.snr, "tracker": tracker, "policy": m.policy,
                   "looks": int(m.looks)}
            for stat in ("median", "mean"):
                value = float(getattr(m, f"ospa_{stat}"))
                match = matched_looks(raster["looks"], raster[f"ospa_{stat}"], value)
                row[f"ospa_{stat}"] = value
                row[f"matched_{stat}"] = match.looks
                row[f"bound_{stat}"] = match.bound
                row[f"matched_{stat}_text"] = match.text()
                row[f"ratio_{stat}_text"] = match.ratio_text(int(m.looks))
            rows.append(row)
    return pd.DataFrame(rows)


def crossing_table(results: pd.DataFrame, setting: KreucherSetting,
                   crossings: Sequence[int] = KREUCHER_CROSSINGS,
                   window: int = CROSSING_WINDOW) -> pd.DataFrame:
    """The raster scan of every cell once per step (looks = cell count) around each
    crossing ``k`` whose windows fit the run: per scenario and tracker, the mean over
    seeds of each run's mean OSPA over steps ``[k - window, k)`` (``before``) and
    ``[k, k + window)`` (``after``) with 95% half-widths, and ``after / before``."""
    n_cells = scenarios.get(setting.preset).grid.n_cells
    cols = ["scenario", "tracker", "looks", "crossing", "n_seeds", "ospa_before",
            "ospa_before_ci95", "ospa_after", "ospa_after_ci95", "ratio"]
    ks = [k for k in crossings if k - window >= 0 and k + window <= setting.n_steps]
    sel = results[(results["policy"] == PERIODIC) & (results["looks_per_step"] == n_cells)
                  & (results["step"] >= 0)]
    runs = per_seed(sel, burn_in=0)  # only to know the runs that finished
    ok = sel.merge(runs[RUN_COLUMNS], on=RUN_COLUMNS)
    rows = []
    for k in ks:
        for (sc, tracker), g in ok.groupby(["scenario", "tracker_label"], sort=True):
            before = g[(g["step"] >= k - window) & (g["step"] < k)].groupby("seed")["ospa"].mean()
            after = g[(g["step"] >= k) & (g["step"] < k + window)].groupby("seed")["ospa"].mean()
            mb, hb = mean_ci95(before.to_numpy(float))
            ma, ha = mean_ci95(after.to_numpy(float))
            rows.append({"scenario": sc, "tracker": tracker, "looks": n_cells, "crossing": k,
                         "n_seeds": int(before.size), "ospa_before": mb,
                         "ospa_before_ci95": hb, "ospa_after": ma, "ospa_after_ci95": ha,
                         "ratio": ma / mb if mb > 0 else math.nan})
    out = pd.DataFrame(rows, columns=cols)
    return out.sort_values(["scenario", "tracker", "crossing"], kind="stable").reset_index(
        drop=True)


def truth_rows(setting: KreucherSetting, seed: int) -> pd.DataFrame:
    """The simulated world of ``seed`` at the crossings within the run and at its last
    step: true positions and ids (``figure = "snapshot"``, tracker ``world``; compared
    exactly by --check)."""
    rows = []
    for sc in setting_scenarios(setting):
        run = simulate(sc, seed)
        steps = sorted({*(k for k in KREUCHER_CROSSINGS if k < sc.n_steps), sc.n_steps - 1})
        for k in steps:
            for i, (tid, x) in enumerate(zip(run.ids[k], run.states[k], strict=True)):
                for q, v in (("truth.px", x[0]), ("truth.py", x[2]), ("truth.id", tid)):
                    rows.append({"figure": "snapshot", "scenario": sc.name, "tracker": "world",
                                 "step": k, "item": i, "quantity": q, "value": float(v)})
    return pd.DataFrame(rows, columns=[*reproduce.KEYS, "value"])


def long_numbers(curve: pd.DataFrame, matched: pd.DataFrame, crossings: pd.DataFrame,
                 truth: pd.DataFrame) -> pd.DataFrame:
    """Every number as one long table with :data:`~mttbench.benchmarks.app.reproduce.KEYS`
    and ``value`` (module docstring: the ``error`` rows carry the look budget as
    ``step``, so --check's Monte Carlo bands run along the curve)."""
    parts = []

    def melt(df: pd.DataFrame, figure: str, tracker: pd.Series, step: pd.Series,
             quantities: dict[str, str]) -> None:
        if df.empty:
            return
        base = pd.DataFrame({"scenario": df["scenario"].to_numpy(), "tracker": tracker.to_numpy(),
                             "step": step.to_numpy()})
        for col, q in quantities.items():
            parts.append(base.assign(figure=figure, item=0, quantity=q,
                                     value=df[col].to_numpy(float)))

    who = curve["tracker"] + " / " + curve["policy"]
    melt(curve, "error", who, curve["looks"], {
        "ospa_mean": "state_error", "ospa_ci95": "state_error_ci95",
        "count_error_mean": "count_error", "count_error_ci95": "count_error_ci95",
        "est_count_mean": "est_count", "est_count_ci95": "est_count_ci95",
        "true_count_mean": "true_count", "n_seeds": "n_seeds"})
    melt(curve, "summary", who, curve["looks"], {"ospa_median": "state_error_median",
                                                 "lost_fraction": "lost_fraction"})
    if not matched.empty:
        melt(matched, "matched", matched["tracker"] + " / " + matched["policy"],
             matched["looks"], {"matched_median": "matched_looks_median",
                                "bound_median": "matched_bound_median",
                                "matched_mean": "matched_looks_mean",
                                "bound_mean": "matched_bound_mean"})
    if not crossings.empty:
        melt(crossings, "crossing", crossings["tracker"] + " / " + PERIODIC,
             crossings["crossing"], {"ospa_before": "ospa_before",
                                     "ospa_before_ci95": "ospa_before_ci95",
                                     "ospa_after": "ospa_after",
                                     "ospa_after_ci95": "ospa_after_ci95", "ratio": "ratio"})
    if not truth.empty:
        parts.append(truth)
    if not parts:
        return pd.DataFrame(columns=[*reproduce.KEYS, "value"])
    out = pd.concat(parts, ignore_index=True)[[*reproduce.KEYS, "value"]]
    out["value"] = out["value"].astype(float)
    out[["step", "item"]] = out[["step", "item"]].astype("int64")
    return out.sort_values(reproduce.KEYS, kind="stable").reset_index(drop=True)


# ---------------------------------------------------------------------- report
def _pm(mean: float, half: float, fmt: str = ".3f") -> str:
    if math.isnan(mean):
        return "–"
    return f"{mean:{fmt}}" + ("" if math.isnan(half) else f" ± {half:{fmt}}")


def _write_report(out: Path, setting: KreucherSetting, specs: list[TrackerSpec],
                  missing: list[str], curve: pd.DataFrame, matched: pd.DataFrame,
                  crossings: pd.DataFrame, fig: Path, failures: list[str],
                  cached: bool) -> None:
    """``report.md`` and a self-contained ``report.html``."""
    n_cells = scenarios.get(setting.preset).grid.n_cells
    doc = Document()
    doc.add("h1", f"Kreucher's managed-versus-periodic result ({setting.name} setting)")
    doc.add("p", "Command: `mttbench reproduce kreucher"
            + (" --reduced" if setting.name == "reduced" else "") + "`. Kreucher, Kastella "
            "and Hero (Signal Processing 2005, Sec. 5.1) report that 24 managed looks per "
            "step track as well as about 312 periodic ones, 13 times fewer.")
    scs = setting_scenarios(setting)
    doc.add("list", [
        "scenarios: " + ", ".join(f"`{sc.name}` (snr {sc.model.sensor.snr:g})" for sc in scs)
        + f"; the SNR variants are the `{setting.preset}` preset with the sensor's snr "
          f"replaced (dataclasses.replace), each with its own simulated world; "
          f"{setting.n_steps} steps",
        "trackers: " + ", ".join(f"`{s.label}`" for s in specs)
        + (f" (not registered, left out: {', '.join(missing)})" if missing else ""),
        f"seeds: {', '.join(map(str, setting.seeds))}",
        f"managed scans at {setting.managed_looks} looks: "
        + ", ".join(f"`{p.label}`" for p in policy_specs(setting)),
        f"periodic scan (`raster`) at {', '.join(map(str, setting.raster_looks))} looks "
        f"per step on {n_cells} cells: the scan continues across steps and wraps, so "
        + "; ".join(f"{lk} looks revisit cells within a step ({revisits(lk, n_cells)})"
                    for lk in setting.raster_looks if lk > n_cells),
        f"error: each run's mean OSPA (c = {setting.c:g} cells, p = {setting.p:g}) over "
        f"steps >= {setting.burn_in}; median and mean (± 95% t half-width) over seeds; a "
        f"seed is lost when its mean OSPA over its last {LOST_WINDOW} steps is >= "
        f"{LOST_OSPA:g} cell",
        f"runs {'loaded from the cache' if cached else 'computed'}",
    ])
    if failures:
        doc.add("h2", "Runs that failed (excluded)")
        doc.add("list", failures)
    doc.add("h2", "Periodic looks that match the managed scan")
    doc.add("p", "The raster curve (OSPA against log looks) interpolated to the managed "
            "scan's value; `>= 312 (beyond the curve)` when the managed scan beats every "
            "raster budget, `< 24` when it is worse than raster at 24 looks.")
    if not matched.empty:
        doc.add("table", pd.DataFrame({
            "scenario": matched["scenario"], "tracker": matched["tracker"],
            "managed": matched["policy"], "looks": matched["looks"],
            "median OSPA": matched["ospa_median"].map(lambda v: f"{v:.3f}"),
            "raster looks (median)": matched["matched_median_text"],
            "ratio (median)": matched["ratio_median_text"],
            "mean OSPA": matched["ospa_mean"].map(lambda v: f"{v:.3f}"),
            "raster looks (mean)": matched["matched_mean_text"],
            "ratio (mean)": matched["ratio_mean_text"]}))
    doc.add("h2", "Figure")
    doc.add("figure", fig, "OSPA against looks per step: raster (periodic) curves, managed "
            "scans at 24 looks as horizontal lines and markers; one panel per SNR, one "
            "colour per tracker, median solid and mean dashed.")
    doc.add("h2", "Numbers")
    doc.add("p", f"Raster at {', '.join(str(lk) for lk in setting.raster_looks if lk > n_cells)}"
            f" looks on {n_cells} cells looks at cells twice or more per step (column "
            "`revisits`); each repeat is an independent look.")
    doc.add("table", pd.DataFrame({
        "scenario": curve["scenario"], "tracker": curve["tracker"], "policy": curve["policy"],
        "looks": curve["looks"], "revisits": curve["revisits"], "seeds": curve["n_seeds"],
        "OSPA median": curve["ospa_median"].map(lambda v: f"{v:.3f}"),
        "OSPA mean": [_pm(m, h) for m, h in zip(curve["ospa_mean"], curve["ospa_ci95"],
                                                  strict=True)],
        "count error": [_pm(m, h) for m, h in zip(curve["count_error_mean"],
                                                    curve["count_error_ci95"], strict=True)],
        "lost": curve["lost_fraction"].map(lambda v: f"{v:.0%}")}))
    doc.add("h2", "Crossings (raster over every cell, each step)")
    if crossings.empty:
        doc.add("p", f"No crossing of {KREUCHER_CROSSINGS} has {CROSSING_WINDOW} steps on "
                f"either side within the {setting.n_steps} steps of this setting, or no "
                f"raster scan of {n_cells} looks ran.")
    else:
        doc.add("p", f"Mean OSPA over the {CROSSING_WINDOW} steps before and from each "
                "crossing of the nominal paths (the goal: after at most 1.5x before). "
                "The targets drift: see the preset's description for how often they really "
                "share a cell.")
        doc.add("table", pd.DataFrame({
            "scenario": crossings["scenario"], "tracker": crossings["tracker"],
            "crossing step": crossings["crossing"], "seeds": crossings["n_seeds"],
            "before": [_pm(m, h) for m, h in zip(crossings["ospa_before"],
                                                   crossings["ospa_before_ci95"], strict=True)],
            "after": [_pm(m, h) for m, h in zip(crossings["ospa_after"],
                                                  crossings["ospa_after_ci95"], strict=True)],
            "after / before": crossings["ratio"].map(lambda v: f"{v:.2f}")}))
    doc.add("h2", "Kreucher's medians, for comparison")
    doc.add("p", "Read off SP05 Fig. 3 (± 0.03; his multitarget RMS error per target, in "
            "cells by the reading of docs/literature/jmpd.md Sec. 6, not OSPA; 500 "
            "particles, 10% of them started at the truth). He plots SNR 1-15; 9 is the "
            "nearest to 10.")
    doc.add("table", pd.DataFrame([{"snr": f"{snr:g}", **{k: f"{v:.2f}" for k, v in m.items()}}
                                   for snr, m in SP05_MEDIANS.items()]))
    (out / "report.md").write_text(doc.markdown(out), encoding="utf-8")
    (out / "report.html").write_text(doc.html("mttbench: Kreucher's managed-versus-periodic "
                                              "result"), encoding="utf-8")


# ------------------------------------------------------------------------ main
def reproduce_kreucher(setting: KreucherSetting, out_dir: str | Path, cache_dir: str | Path, *,
                       tracker_texts: tuple[str, ...] | None = None, workers: int = 1,
                       progress: bool = True, use_cache: bool = True,
                       run_timeout: float | None = None) -> reproduce.Reproduction:
    """Run (or load) the setting; write the figure, CSVs and report into ``out_dir``; a
    run past ``run_timeout`` seconds (None: the app's default) gets an error row."""
    setting, specs, missing, out = reproduce.start(setting, tracker_texts, out_dir)
    results, cached = run_or_load(setting, specs, Path(cache_dir), workers=workers,
                                  progress=progress, use_cache=use_cache,
                                  run_timeout=run_timeout)
    runs = per_seed(results, setting.burn_in)
    curve = curve_table(runs, setting)
    matched = matched_table(curve, setting.managed_looks)
    crossings = crossing_table(results, setting)
    curve.to_csv(out / "curve.csv", index=False)
    matched.to_csv(out / "matched.csv", index=False)
    crossings.to_csv(out / "crossings.csv", index=False)
    fig = figures_kreucher.managed_vs_periodic(curve, out / "fig_managed_vs_periodic.png",
                                               n_cells=scenarios.get(setting.preset)
                                               .grid.n_cells)
    numbers = long_numbers(curve, matched, crossings, truth_rows(setting, setting.seeds[0]))
    csv = out / f"numbers_{setting.name}.csv"
    numbers.to_csv(csv, index=False, float_format="%.17g")
    bad = results[results["status"] == "error"]
    failures = sorted({f"{r.scenario} / {r.tracker_label} / {r.policy_label} "
                       f"@{r.looks_per_step} seed {r.seed}: {r.error}" for r in bad.itertuples()})
    _write_report(out, setting, specs, missing, curve, matched, crossings, fig, failures, cached)
    return reproduce.Reproduction(out, numbers, csv, cached, results)

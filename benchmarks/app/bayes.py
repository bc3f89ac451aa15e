"""``mttbench bayes``: the converged Bayes reference, computed once and stored.

``bayes`` is a reference, not a contestant: the model's Bayes filter, the best any tracker
given the same model and the same looks can do on average. No closed form exists for
the multitarget model on the cell sensor, so it is approximated by the best particle
filter of the suite, ``jmpd-ap`` (:mod:`mttbench.trackers.jmpd.ap`: locally optimal
per-cluster proposals, measurement-directed births, Rao-Blackwellised velocities), at a
particle count where more particles no longer change the answer. That is measured,
never assumed, on a ladder of particle counts ``N_0, 4 N_0, 16 N_0, ...`` run on the same
worlds (common random numbers: a run's truth and every look's return depend on the
scenario and seed only)::

    d_i = OSPA_i(N) - OSPA_i(4 N)        (run means of seed i, paired)
    within at 4 N     when  |mean(d)| + t_{0.975, n-1} sd(d) / sqrt(n)
                            <= max(tolerance, gap_share * (OSPA_null - OSPA(4 N)))
    converged at 4 N  when  the last ``confirm`` steps (N/4 -> N and N -> 4 N) are within

(defaults: ``tolerance`` 0.02 OSPA, ``gap_share`` 0.05). ``OSPA_null`` is the floor's
score on the same worlds (``c`` at every step with a target, 0 at the others: exact, no
run needed), so ``OSPA_null - OSPA(4 N)`` is the achievable gap every share is measured
against; within 5% of it, a tracker's share of that gap moves by at most about 0.05 when
the reference moves within its interval. One step within is not enough (``confirm`` 2 by
default): on ``kreucher`` 1,000 -> 4,000 moved 0.008 and 4,000 -> 16,000 then 0.039
(docs/bayes.md). The reference is the rung ``4 N`` of the first such
pair. A rung whose runs are estimated to take longer than ``run_limit_s`` CPU seconds
each (4x the last rung's measured time) is not run: the scenario is then **not
converged at N**, and its largest rung is an estimate of the reference, never a bound
(reports say so).

Point estimate: ``jmpd-ap``'s, ``E[T]`` rounded for the count and the posterior mean of
each of the most probable slots for the states (docs/bayes.md says why that suits
OSPA). What ``jmpd-ap`` does not represent exactly (its undetected-target field ignores
motion, births only at detected cells, a position-noise floor) is listed in its module
docstring; docs/bayes.md measures the agreement with an exact grid filter where one
exists (single-target scenarios).

A reference is keyed by what determines its numbers: the scenario's full text (its
model, length and name), the policy and look budget, the OSPA ``c`` and ``p`` and the
ladder's tracker. It is stored as two files in a reference folder (the checkout's
``reports/reference/bayes/``, shipped with the package; ``--store`` elsewhere)::

    <scenario>-<key>.parquet   the reference rung's step rows, tracker ``bayes``
    <scenario>-<key>.json      provenance: scenario hash, seeds, ladder, every rung's
                               OSPA and cost, the paired differences, the verdict,
                               commit, versions, wall and CPU time

Reports attach a stored reference when its seeds cover theirs (:func:`attach`).
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...scenarios.simulator import Scenario
from ...scenarios.spec import dumps as scenario_text
from ..engine.loop import Job, build_jobs
from ..engine.metrics import cutoff
from ..engine.specs import PolicySpec, TrackerSpec
from ..engine.store import write_text_atomic
from .summary import mean_ci95
from .usage import UsageError

#: the label of the reference in every table
REFERENCE = "bayes"
#: the tracker whose particle-count ladder approximates the Bayes filter
LADDER_TRACKER = "jmpd-ap"
#: its settings besides the particle count: the model's prior, every particle starting on
#: the declared initial states (a prior every tracker may use; ``jmpd-ap``'s default
#: starts from nothing, as the contestants do)
LADDER_PARAMS: dict[str, float] = {"init_fraction": 1.0}
#: format of the stored files (2: the ladder's tracker counts undetected targets, lets a
#: dead target stay dead and starts on the declared states)
FORMAT = 2
_PACKAGE_ROOT = Path(__file__).resolve().parents[2]
#: the policy of a reference by default: the raster every tracker of a report shares
RASTER = PolicySpec("raster")


def default_store() -> Path:
    """The stored references the package reads and, in a checkout, writes: the checkout's
    ``reports/reference/bayes/`` (``mttbench/reference/bayes/`` of an installed package)."""
    return _PACKAGE_ROOT / "reports" / "reference" / "bayes" if (
        _PACKAGE_ROOT / "pyproject.toml").is_file() else _PACKAGE_ROOT / "reference" / "bayes"


@dataclass(frozen=True)
class Ladder:
    """The particle-count ladder: ``n_start * factor**k`` up to ``n_max``; converged when
    two consecutive rungs' paired OSPA difference lies (95%) within ``+-tolerance`` or
    within ``gap_share`` of the achievable gap, whichever is wider (module docstring); a
    rung whose runs would take more than ``run_limit_s`` CPU seconds each is not run."""

    n_start: int = 1000
    factor: int = 4
    n_max: int = 64000
    tolerance: float = 0.02
    run_limit_s: float = 600.0
    gap_share: float = 0.05
    confirm: int = 2

    def __post_init__(self) -> None:
        if not (isinstance(self.n_start, int) and self.n_start >= 1):
            raise UsageError(f"--n-start {self.n_start!r}: a whole number >= 1")
        if not (isinstance(self.factor, int) and self.factor >= 2):
            raise UsageError(f"--factor {self.factor!r}: a whole number >= 2")
        if not (isinstance(self.n_max, int) and self.n_max >= self.n_start * self.factor):
            raise UsageError(f"--n-max {self.n_max!r}: at least n_start x factor = "
                             f"{self.n_start * self.factor} (two rungs to compare)")
        if not (math.isfinite(self.tolerance) and self.tolerance > 0):
            raise UsageError(f"--tolerance {self.tolerance!r}: a positive OSPA difference")
        if not (math.isfinite(self.run_limit_s) and self.run_limit_s > 0):
            raise UsageError(f"--run-limit {self.run_limit_s!r}: positive seconds")
        if not (math.isfinite(self.gap_share) and 0 <= self.gap_share < 1):
            raise UsageError(f"--gap-share {self.gap_share!r}: a share in [0, 1) of the "
                             "achievable gap (0: the absolute --tolerance alone)")
        if not (isinstance(self.confirm, int) and 1 <= self.confirm <= 3):
            raise UsageError(f"--confirm {self.confirm!r}: 1, 2 or 3 consecutive steps")
        if self.n_start * self.factor ** self.confirm > self.n_max:
            raise UsageError(f"--n-max {self.n_max}: at least n_start x factor^confirm = "
                             f"{self.n_start * self.factor ** self.confirm} ({self.confirm} "
                             "steps to compare)")

    def is_converged(self, steps: Sequence[Mapping[str, Any]]) -> bool:
        """Whether the last ``confirm`` paired steps each lie within their tolerance."""
        last = list(steps)[-self.confirm:]
        return len(last) == self.confirm and all(
            s["bound"] is not None and s["bound"] <= s["tolerance"] for s in last)

    def tolerance_for(self, gap: float) -> float:
        """The tolerance of a step whose achievable gap (null minus the higher rung) is
        ``gap`` (NaN when the rows do not say: the absolute tolerance alone)."""
        return max(self.tolerance, self.gap_share * gap) if math.isfinite(gap) else self.tolerance

    def rungs(self) -> list[int]:
        out, n = [], self.n_start
        while n <= self.n_max:
            out.append(n)
            n *= self.factor
        return out


def ladder_spec(n: int) -> TrackerSpec:
    """The ladder's tracker at ``n`` particles."""
    return TrackerSpec(LADDER_TRACKER, {**LADDER_PARAMS, "n_particles": int(n)})


def reference_key(scenario: Scenario, policy: PolicySpec, looks: int | None,
                  c: float | None, p: float) -> str:
    """What determines a reference's numbers, hashed (the seeds are stored inside); a
    look budget equal to the scenario's own is the same as None, and ``c`` None is the
    default cut-off in the scenario's units (:func:`~.metrics.cutoff`)."""
    c = cutoff(c, scenario.grid.cell_size)
    own = getattr(scenario.model.sensor, "looks_per_step", None)
    if looks is not None and own is not None and int(looks) == int(own):
        looks = None
    ident = {"scenario": scenario_text(scenario), "policy": [policy.name, policy.params],
             "looks": looks, "c": float(c), "p": float(p), "tracker": LADDER_TRACKER,
             "tracker_params": LADDER_PARAMS, "format": FORMAT}
    text = json.dumps(ident, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _stem(scenario: Scenario, key: str) -> str:
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in scenario.name)
    return f"{safe}-{key}"


# ------------------------------------------------------------------ one rung's verdict
@dataclass(frozen=True)
class Rung:
    """One particle count's runs on one scenario: per-seed OSPA (run means), the CPU
    time per step (mean over seeds of each run's median step) and per run (that times
    the steps)."""

    n_particles: int
    ospa: dict[int, float]
    cpu_ms_per_step: float
    run_cpu_s: float
    errors: int
    #: the floor's (``null``'s) OSPA of each seed on the same worlds (empty when the rows
    #: carry no ``true_count``)
    null_ospa: dict[int, float] = field(default_factory=dict)

    def gap(self) -> float:
        """The achievable gap at this rung: mean null OSPA minus mean OSPA over the seeds
        both have (NaN without the floor's numbers)."""
        seeds = sorted(set(self.ospa) & set(self.null_ospa))
        if not seeds:
            return math.nan
        return float(np.mean([self.null_ospa[s] - self.ospa[s] for s in seeds]))

    def summary(self) -> dict[str, Any]:
        m, h = mean_ci95(np.array(list(self.ospa.values()), dtype=float))
        return {"n_particles": self.n_particles, "ospa_mean": _num(m), "ospa_ci95": _num(h),
                "cpu_ms_per_step": _num(self.cpu_ms_per_step), "run_cpu_s": _num(self.run_cpu_s),
                "n_seeds": len(self.ospa), "errors": self.errors}


def _num(x: float) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else round(float(x), 6)


def paired_step(lo: Rung, hi: Rung) -> dict[str, Any]:
    """``OSPA(lo) - OSPA(hi)`` paired over the seeds both finished: mean, 95% t
    half-width, and the largest ``|difference|`` the interval allows."""
    seeds = sorted(set(lo.ospa) & set(hi.ospa))
    d = np.array([lo.ospa[s] - hi.ospa[s] for s in seeds], dtype=float)
    m, h = mean_ci95(d)
    bound = abs(m) + h if len(seeds) >= 2 else math.inf
    return {"n_low": lo.n_particles, "n_high": hi.n_particles, "n_pairs": len(seeds),
            "diff_mean": _num(m), "diff_ci95": _num(h), "bound": _num(bound)}


def rung_of(results: pd.DataFrame, n_particles: int) -> Rung:
    """The :class:`Rung` of one scenario's rows at ``n_particles``."""
    # a run counts when every one of its rows is ok (as in the summaries)
    run_ok = results.groupby("seed")["status"].agg(lambda st: bool((st == "ok").all()))
    means = results.groupby("seed")["ospa"].mean()
    ospa = {int(s): float(means[s]) for s in run_ok.index if run_ok[s]}
    # the median step: the first steps of a worker include the compiled kernels' start-up
    steps = results[results["status"] == "ok"].groupby("seed")["tracker_cpu_s"]
    per_step = steps.median().to_numpy(float)
    per_run_s = per_step * steps.size().to_numpy(float)
    null: dict[int, float] = {}
    if {"true_count", "ospa_c"} <= set(results.columns):
        # the floor reports nothing: OSPA is c at a step with a target, 0 without one
        floor = np.where(results["true_count"].to_numpy() > 0,
                         results["ospa_c"].to_numpy(float), 0.0)
        by_seed = pd.Series(floor, index=results.index).groupby(results["seed"]).mean()
        null = {s: float(by_seed[s]) for s in ospa}
    return Rung(int(n_particles), ospa,
                float(per_step.mean() * 1e3) if per_step.size else math.nan,
                float(per_run_s.mean()) if per_run_s.size else math.nan,
                int((~run_ok).sum()), null)


# ------------------------------------------------------------------ stored references
@dataclass
class Reference:
    """A stored reference: the reference rung's step rows (tracker ``bayes``) and its
    provenance (module docstring)."""

    rows: pd.DataFrame
    provenance: dict[str, Any] = field(default_factory=dict)

    @property
    def converged(self) -> bool:
        return bool(self.provenance.get("converged"))

    @property
    def n_particles(self) -> int:
        return int(self.provenance.get("n_reference", 0))

    @property
    def seeds(self) -> list[int]:
        return [int(s) for s in self.provenance.get("seeds", [])]

    def verdict(self) -> str:
        """One line: converged at N (with the last paired difference) or not."""
        prov = self.provenance
        step = (prov.get("steps") or [{}])[-1]
        diff = ""
        if step.get("diff_mean") is not None:
            half = step.get("diff_ci95")
            diff = (f"; OSPA(N={step['n_low']}) - OSPA(N={step['n_high']}) = "
                    f"{step['diff_mean']:+.3f} ± "
                    f"{'n/a' if half is None else format(half, '.3f')}")
        if self.converged:
            tol = step.get("tolerance") or prov["tolerance"]
            share = ("" if step.get("gap") is None or tol <= prov["tolerance"] else
                     f", {prov['ladder']['gap_share']:g} of the achievable gap "
                     f"{step['gap']:.3f}")
            return (f"converged at N = {self.n_particles} (within ±{tol:.3f}{share}"
                    f"{diff})")
        return (f"not converged at N = {self.n_particles}: an estimate, not a bound "
                f"({prov.get('reason', '')}{diff})")


def _paths(store: Path, scenario: Scenario, key: str) -> tuple[Path, Path]:
    stem = _stem(scenario, key)
    return store / f"{stem}.parquet", store / f"{stem}.json"


def save(store: str | Path, scenario: Scenario, key: str, ref: Reference) -> Path:
    """Write both files atomically (rows first: a provenance file always has its rows)."""
    store = Path(store)
    store.mkdir(parents=True, exist_ok=True)
    rows_path, prov_path = _paths(store, scenario, key)
    tmp = rows_path.with_name(rows_path.name + ".tmp")
    ref.rows.to_parquet(tmp, index=False)
    tmp.replace(rows_path)
    write_text_atomic(prov_path, json.dumps(ref.provenance, indent=1, sort_keys=True) + "\n")
    return prov_path


def load(store: str | Path, scenario: Scenario, key: str) -> Reference | None:
    """The stored reference of ``(scenario, key)`` in ``store``, or None (absent, or a
    file that does not read back as one: a line on stderr says which)."""
    rows_path, prov_path = _paths(Path(store), scenario, key)
    if not prov_path.is_file():
        return None
    try:
        prov = json.loads(prov_path.read_text())
        rows = pd.read_parquet(rows_path)
        if prov.get("key") != key or prov.get("format") != FORMAT:
            raise ValueError("its key or format differs from its name")
        if set(rows["seed"].astype(int)) != {int(s) for s in prov["seeds"]}:
            raise ValueError("its rows and its seeds differ")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"note: the stored bayes reference {prov_path} is unreadable ({exc}); "
              "ignored", file=sys.stderr)
        return None
    return Reference(rows, prov)


def find(scenario: Scenario, policy: PolicySpec, looks: int | None, seeds: Sequence[int],
         c: float | None = None, p: float = 2.0, stores: Sequence[str | Path] | None = None
         ) -> Reference | None:
    """The first stored reference (``stores``, default :func:`default_store`) for this
    scenario, policy, looks, ``c`` and ``p`` whose seeds include ``seeds``, its rows cut to
    those seeds; None when there is none."""
    key = reference_key(scenario, policy, looks, c, p)
    for store in stores or [default_store()]:
        ref = load(store, scenario, key)
        if ref is not None and set(int(s) for s in seeds) <= set(ref.seeds):
            rows = ref.rows[ref.rows["seed"].isin([int(s) for s in seeds])]
            return Reference(rows.reset_index(drop=True), ref.provenance)
    return None


# ------------------------------------------------------------------------- the ladder
Sweep = Callable[[list[Job], Path], pd.DataFrame]


def _reference_rows(rows: pd.DataFrame) -> pd.DataFrame:
    """A rung's rows relabelled as the reference (``tracker``, ``tracker_label``)."""
    out = rows.copy()
    out["tracker"] = REFERENCE
    out["tracker_label"] = REFERENCE
    return out.reset_index(drop=True)


def run_ladder(scenarios: Sequence[Scenario], seeds: Sequence[int], sweep: Sweep,
               work_dir: str | Path, *, ladder: Ladder = Ladder(),
               policy: PolicySpec = RASTER, looks: int | None = None,
               c: float | None = None, p: float = 2.0,
               provenance: Mapping[str, Any] | None = None,
               say: Callable[[str], None] = print) -> dict[str, Reference]:
    """Run the ladder for every scenario at once (rung by rung, each rung one sweep of the
    scenarios still open, so workers stay busy) and return each scenario's
    :class:`Reference`. ``sweep(jobs, work_dir)`` runs jobs into the one resumable work
    folder (the command line's progress bar, executor and timeouts); a scenario leaves
    the ladder when it converges, when its next rung would exceed ``ladder.run_limit_s``
    per run, or when a run fails."""
    seeds = [int(s) for s in seeds]
    if len(seeds) < 2:
        raise UsageError("the bayes reference needs at least 2 seeds (a paired interval)")
    work_dir = Path(work_dir)
    open_ = {sc.name: sc for sc in scenarios}
    rungs: dict[str, list[Rung]] = {name: [] for name in open_}
    steps: dict[str, list[dict[str, Any]]] = {name: [] for name in open_}
    top_rows: dict[str, pd.DataFrame] = {}
    verdict: dict[str, tuple[bool, str]] = {}
    started = {name: time.perf_counter() for name in open_}
    wall: dict[str, float] = {}
    for n in ladder.rungs():
        if not open_:
            break
        todo = list(open_.values())
        jobs = build_jobs(todo, [ladder_spec(n)], [policy], None if looks is None else [looks],
                          seeds)
        say(f"bayes: N = {n} on {', '.join(open_)} ({len(jobs)} runs)")
        results = sweep(jobs, work_dir)
        here = results[(results["tracker"] == LADDER_TRACKER)
                       & (results["param_n_particles"] == n)]
        for sc in todo:
            rows = here[here["scenario"] == sc.name]
            rung = rung_of(rows, n)
            rungs[sc.name].append(rung)
            top_rows[sc.name] = rows
            if rung.errors:
                verdict[sc.name] = (False, f"{rung.errors} run(s) failed at N = {n}")
            elif len(rungs[sc.name]) >= 2:
                step = paired_step(rungs[sc.name][-2], rung)
                step["gap"] = _num(rung.gap())
                step["tolerance"] = _num(ladder.tolerance_for(rung.gap()))
                steps[sc.name].append(step)
                if ladder.is_converged(steps[sc.name]):
                    verdict[sc.name] = (True, "")
            if sc.name not in verdict and n * ladder.factor > ladder.n_max:
                verdict[sc.name] = (False, f"the ladder's n_max {ladder.n_max} reached")
            elif sc.name not in verdict and rung.run_cpu_s * ladder.factor > ladder.run_limit_s:
                verdict[sc.name] = (False, f"the next rung, N = {n * ladder.factor}, "
                                           f"would take about {rung.run_cpu_s * ladder.factor:.0f}"
                                           f" CPU s per run, above the limit "
                                           f"{ladder.run_limit_s:g} s")
            if sc.name in verdict:
                wall[sc.name] = time.perf_counter() - started[sc.name]
                del open_[sc.name]
                say(f"bayes: {sc.name}: " + ("converged" if verdict[sc.name][0] else
                                             "not converged") + f" at N = {n}")
    out = {}
    for sc in scenarios:
        name = sc.name
        converged, reason = verdict.get(name, (False, "not run"))
        rs = rungs[name]
        prov = {
            "format": FORMAT, "key": reference_key(sc, policy, looks, c, p),
            "scenario": name, "scenario_sha256": hashlib.sha256(
                scenario_text(sc).encode()).hexdigest(),
            "n_steps": int(sc.n_steps), "policy": policy.label, "looks": looks,
            "ospa_c": cutoff(c, sc.grid.cell_size), "ospa_p": float(p), "seeds": seeds,
            "tracker": LADDER_TRACKER, "ladder": asdict(ladder),
            "tolerance": ladder.tolerance, "rungs": [r.summary() for r in rs],
            "steps": steps[name], "converged": converged, "reason": reason,
            "n_reference": rs[-1].n_particles if rs else None,
            "wall_time_s": round(wall.get(name, 0.0), 1),
            "cpu_time_s": round(sum(r.run_cpu_s * len(r.ospa) for r in rs
                                    if math.isfinite(r.run_cpu_s)), 1),
            "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
            **dict(provenance or {}),
        }
        out[name] = Reference(_reference_rows(top_rows.get(name, pd.DataFrame())), prov)
    return out


# ---------------------------------------------------------------- reports and tables
def attach(results: pd.DataFrame, scenarios: Sequence[Scenario], seeds: Sequence[int],
           policy: PolicySpec = RASTER, looks: int | None = None,
           c: float | None = None, p: float = 2.0, stores: Sequence[str | Path] | None = None,
           name_policy: bool = False) -> tuple[pd.DataFrame, list[str]]:
    """``results`` with the stored reference's rows of every scenario that has one for
    these seeds under ``policy`` (:func:`find`: the key holds the policy, so another
    policy's reference is never attached), and one line per scenario saying what was
    attached (converged at N, or an estimate) or that none is stored, with the command
    that computes it. The lines name the policy when it is not raster or when
    ``name_policy`` (a report of several policies)."""
    frames, notes = [results], []
    under = policy != RASTER or name_policy
    option = "" if policy == RASTER else f" --policy {policy_text(policy)}"
    for sc in scenarios:
        where = f"`{sc.name}`" + (f" under `{policy.label}`" if under else "")
        ref = find(sc, policy, looks, seeds, c, p, stores)
        if ref is None:
            notes.append(f"{where}: no stored `bayes` reference for these seeds "
                         f"(compute it: `mttbench bayes {sc.name} --seeds "
                         f"{max(seeds) + 1}{option}`)")
            continue
        rows = ref.rows.copy()
        notes.append(f"{where}: `bayes` {ref.verdict()}; computed in "
                     f"{ref.provenance.get('wall_time_s', 0):.0f} s at commit "
                     f"{str((ref.provenance.get('git') or {}).get('commit') or '?')[:7]}")
        frames.append(rows)
    if len(frames) == 1:
        return results, notes
    merged = pd.concat(frames, ignore_index=True, sort=False)
    return merged, notes


def policy_text(policy: PolicySpec) -> str:
    """``policy`` as typed on the command line."""
    if not policy.params:
        return policy.name
    return policy.name + ":" + ",".join(f"{k}={v}" for k, v in sorted(policy.params.items()))


def ladder_table(refs: Mapping[str, Reference]) -> pd.DataFrame:
    """One row per scenario and rung: OSPA mean ± 95%, CPU ms per step, and the paired
    difference to the next rung (docs and the command's output)."""
    rows = []
    for name, ref in refs.items():
        steps = {s["n_low"]: s for s in ref.provenance.get("steps", [])}
        for r in ref.provenance.get("rungs", []):
            s = steps.get(r["n_particles"], {})
            rows.append({"scenario": name, "N": r["n_particles"],
                         "OSPA": _pm(r["ospa_mean"], r["ospa_ci95"]),
                         "ms/step": r["cpu_ms_per_step"],
                         "OSPA(N) - OSPA(4N)": _pm(s.get("diff_mean"), s.get("diff_ci95"),
                                                   signed=True),
                         "tolerance": s.get("tolerance") or "",
                         "verdict": (ref.verdict() if r["n_particles"] == ref.n_particles
                                     else "")})
    return pd.DataFrame(rows)


def _pm(mean: float | None, half: float | None, signed: bool = False) -> str:
    if mean is None:
        return ""
    m = f"{mean:+.3f}" if signed else f"{mean:.3f}"
    return m + (" ± n/a" if half is None else f" ± {half:.3f}")


# ------------------------------------------------------------------ the command
#: seeds of a reference by default: those of ``mttbench compare``
DEFAULT_SEEDS = 10


def default_write_store() -> Path:
    """Where ``mttbench bayes`` writes without ``--store``: the checkout's store, or
    ``./bayes`` from an installed package."""
    return default_store() if (_PACKAGE_ROOT / "pyproject.toml").is_file() else Path("bayes")


def run_command(scenarios: Sequence[Scenario], seeds: Sequence[int], ladder: Ladder,
                policy: PolicySpec, looks: int | None, out_dir: str | Path,
                store: str | Path, *, workers: int = 1, progress: bool = True,
                resume: bool = False, c: float | None = None, p: float = 2.0,
                run_timeout: float | None = None,
                provenance: Mapping[str, Any] | None = None) -> dict[str, Reference]:
    """``mttbench bayes``: check every rung's runs fit (memory) before the first, run the
    ladder in ``out_dir`` (one resumable sweep folder that grows rung by rung), store each
    scenario's reference in ``store``, write ``ladder.csv`` and ``ladder.md`` into
    ``out_dir`` and print the table. ``provenance`` (commit, versions, the command) goes
    into every stored reference."""
    from . import resources
    from .progress import run_sweep

    out_dir = Path(out_dir)
    top = [build_jobs(list(scenarios), [ladder_spec(n)],
                      [policy], None if looks is None else [looks], list(seeds)[:1])
           for n in ladder.rungs()]
    for line in resources.check_jobs([j for jobs in top for j in jobs], workers):
        print(line, file=sys.stderr)
    started = time.perf_counter()

    def sweep(jobs: list[Job], folder: Path) -> pd.DataFrame:
        # resume=True within one command: each rung adds its jobs to the same folder
        return run_sweep(jobs, folder, progress=progress, workers=workers, c=c, p=p,
                         resume=True, extend=True, run_timeout=run_timeout)

    if not resume and (out_dir / "parts").is_dir() and any((out_dir / "parts").iterdir()):
        raise UsageError(f"{out_dir} holds runs already: --resume to continue them, or "
                         "another --out")
    refs = run_ladder(scenarios, seeds, sweep, out_dir, ladder=ladder, policy=policy,
                      looks=looks, c=c, p=p, provenance=provenance,
                      say=lambda line: print(line, file=sys.stderr))
    for sc in scenarios:
        ref = refs[sc.name]
        if len(ref.rows):
            where = save(store, sc, ref.provenance["key"], ref)
            print(f"stored {where}", file=sys.stderr)
    table = ladder_table(refs)
    table.to_csv(out_dir / "ladder.csv", index=False)
    from .summary import md_cell

    lines = [f"# The `bayes` reference: particle-count ladder of `{LADDER_TRACKER}`", "",
             f"Seeds {list(seeds)[0]}..{list(seeds)[-1]} ({len(seeds)}), policy "
             f"{policy.label}, OSPA c = {'2 cells' if c is None else format(c, 'g')}, "
             f"p = {p:g}; converged when the paired "
             f"difference's 95% interval lies within ±{ladder.tolerance:g} or within "
             f"{ladder.gap_share:g} of the achievable gap (null minus the higher count), "
             "whichever is wider. "
             f"Wall time {time.perf_counter() - started:.0f} s.", "",
             "| " + " | ".join(table.columns) + " |",
             "|" + "---|" * len(table.columns)]
    lines += ["| " + " | ".join(md_cell(v) for v in row) + " |"
              for row in table.itertuples(index=False)]
    text = "\n".join(lines) + "\n"
    write_text_atomic(out_dir / "ladder.md", text)
    print(text)
    return refs

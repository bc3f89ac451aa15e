"""``mttbench compare``: the head-to-head report of every tracker (the main job).

One command runs every registered tracker on the standard scenarios (``default``,
``crossing``, ``births``, ``kreucher``: scenarios where trackers can be ranked, the
floor ``null`` far above the trackers; ``paper`` is a stress test that cannot rank them
and is run only on request) over several seeds, in parallel processes
(:func:`benchmarks.engine.sweep.run_sweep`: the results do not depend on the number of
workers, timings aside), and writes a report folder::

    reports/compare-<UTC timestamp>/
        results.parquet     the tidy table, one row per scenario x tracker x seed x step
        summary.csv/.md     means over seeds with 95% t half-widths
        report.md           tables, floor (null) and ceiling (truth-aided) with each
                            tracker's share of the gap closed, paired differences
                            against --reference, figures
        report.html         the same, self-contained (figures embedded)
        figures/*.png       error over time, runtime, accuracy vs runtime, snapshot
        manifest.json       command line, versions, git commit, seeds, wall time

``manifest.json`` is written when the comparison starts (``"status": "running"``) and
rewritten when it ends: ``"finished"``, or ``"interrupted"`` (Ctrl-C) / ``"failed"``. A
folder is *unfinished* when it has no manifest or its status is not ``"finished"``;
``mttbench compare --resume`` without ``--out`` picks the most recent unfinished one.
``sessions`` lists every session that worked on the folder (a first run and its
resumes) with its wall time, and ``wall_time_s`` is their sum (a session killed
without a chance to write, e.g. by SIGKILL, counts as 0).

Default budget: the settings below are chosen so that the default command finishes
in well under a minute on a 2-core machine: 10 seeds, each scenario's own
length, the raster policy at each scenario's look budget, and JMPD at 1000 particles
(its own default is 2000), plus a 250-particle JMPD setting so the accuracy-against-
runtime figure shows the particle-count trade-off. ``--seeds``, ``--steps``,
``--trackers`` (with ``name:key=val`` parameters), ``--scenarios`` scale it.

Policies: ``--policies raster renyi ...`` runs every tracker under every policy on the
same worlds (:mod:`~mttbench.benchmarks.app.policy_axis`: the tracker x policy table,
paired differences between policies, the best pair); one policy gives the report of
that policy alone.

Parameters: a tracker with a tuned file (``tuned/<tracker>.toml``, written by ``mttbench
tune`` on seeds held apart; :mod:`~mttbench.benchmarks.app.tuned`) runs those parameters,
labelled ``name(tuned)``; ``--untuned`` runs the defaults; ``--tuning-effect`` runs both
and reports tuned minus default per tracker. The summary and the report list the
parameters each tracker ran.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pandas as pd

from ... import trackers
from ..engine.executors import describe_current
from ..engine.loop import build_jobs, spec_uses_truth
from ..engine.metrics import cutoff, describe_cutoff, run_metric_params
from ..engine.specs import PolicySpec, TrackerSpec, resolve_scenarios, resolve_trackers
from ..engine.store import check_sweep, prepare_out_dir, write_text_atomic
from . import bayes, policy_axis, resources, summary, tuned
from .progress import run_sweep
from .resources import default_run_timeout
from .usage import UsageError

if TYPE_CHECKING:
    from .report import ReportFiles

#: scenarios that can rank trackers (``paper`` at 24 looks cannot: every tracker within
#: ~0.2 OSPA of the floor ``null``, its Q being the paper's units on unit cells)
COMPARE_SCENARIOS = ("default", "crossing", "births", "kreucher")
COMPARE_SEEDS = 10
#: the default reference of the paired differences, the first of these that runs: the
#: Poisson multi-Bernoulli filter (the principled peer every tracker, the GPF first, is
#: measured against), else KF-NN; never a tracker that uses the truth
COMPARE_REFERENCES = ("pmb", "kfnn")
#: parameters used when ``--trackers`` is not given (keeps the default run ~35 s)
DEFAULT_PARAMS: dict[str, list[dict[str, Any]]] = {
    "jmpd": [{"n_particles": 1000}, {"n_particles": 250}],
    "jmpd-ip": [{"n_particles": 1000}],
    "jmpd-ap": [{"n_particles": 250}],
}
#: tracker drawn in the snapshot figure, first registered one wins
SNAPSHOT_PREFERENCE = ("gpf", "jmpd", "kfnn")
#: distributions whose versions go into the manifest
VERSIONED = ("mttbench", "numpy", "scipy", "pandas", "pyarrow", "matplotlib", "filterpy", "tqdm",
             "numba")
#: every file and folder a finished comparison leaves in its folder (``parts/`` aside)
OUTPUT_FILES = ("results.parquet", "summary.csv", "summary.md", "report.md", "report.html",
                "figures/", "manifest.json")


def default_tracker_texts() -> list[str]:
    """Every registered tracker, with the budget parameters of :data:`DEFAULT_PARAMS`
    (only those the tracker actually accepts)."""
    out = []
    for name in trackers.available():
        missing = getattr(trackers.get_class(name), "missing_extra", None)
        if callable(missing) and missing():
            continue  # an optional extra that is not installed (the Stone Soup peers)
        if getattr(trackers.get_class(name), "reference", False):
            continue  # a reference without the truth (grid-bayes): on request only
        accepted = set(trackers.get_class(name).param_names())
        settings = [s for s in DEFAULT_PARAMS.get(name, []) if set(s) <= accepted] or [{}]
        for s in settings:
            out.append(name + (":" + ",".join(f"{k}={v}" for k, v in s.items()) if s else ""))
    return out


def package_versions() -> dict[str, str]:
    """Installed versions of :data:`VERSIONED` (``"not installed"`` if absent)."""
    out = {"python": platform.python_version()}
    for dist in VERSIONED:
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def read_manifest(folder: str | Path) -> dict[str, Any] | None:
    """The folder's ``manifest.json``, or None if it has none (or an unreadable one)."""
    try:
        data = json.loads((Path(folder) / "manifest.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def is_finished(folder: str | Path) -> bool:
    """True if ``folder`` holds a finished comparison (manifest status ``"finished"``;
    manifests written before the status existed count as finished)."""
    man = read_manifest(folder)
    return man is not None and man.get("status", "finished") == "finished"


def git_commit(where: Path | None = None) -> dict[str, Any]:
    """``{"commit": sha or None, "dirty": bool or None}`` of the checkout holding this file."""
    where = where or Path(__file__).resolve().parent
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=where, capture_output=True,
                             text=True, timeout=10, check=True).stdout.strip()
        status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                                cwd=where, capture_output=True, text=True, timeout=10,
                                check=True).stdout
        return {"commit": sha, "dirty": bool(status.strip())}
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}


@dataclass(frozen=True)
class CompareOutput:
    results: pd.DataFrame
    out_dir: Path
    files: ReportFiles
    manifest: dict[str, Any]


def run_compare(scenario_names: Sequence[str] = COMPARE_SCENARIOS,
                tracker_texts: Sequence[str] | None = None, seeds: Sequence[int] | None = None,
                steps: int | None = None, workers: int | None = None,
                out_dir: str | Path | None = None, reference: str | None = None,
                progress: bool = True, resume: bool = False, c: float | None = None, p: float = 2.0,
                snapshot: bool = True, argv: Sequence[str] | None = None,
                tuned_dir: str | Path | None = None, untuned: bool = False,
                tuning_effect: bool = False,
                run_timeout: float | None = None, compute_bayes: bool = False,
                bayes_ladder: bayes.Ladder | None = None,
                policies: Sequence[PolicySpec] | None = None) -> CompareOutput:
    """Run the comparison and write the report folder (see the module docstring).

    ``tracker_texts`` None means :func:`default_tracker_texts`; ``seeds`` None means
    ``0..COMPARE_SEEDS-1``; ``workers`` None means the number of CPUs. ``reference`` is
    a tracker label (``name`` or ``name(k=v)``; a bare name matches that tracker's first
    setting); None means ``kfnn`` when it runs, else the first tracker that does not use
    the truth (a truth-aided tracker is a reference for the share of the gap closed,
    never the default reference of the paired differences; given explicitly it is
    accepted), else no paired differences. Raises
    :class:`~mttbench.benchmarks.engine.specs.UsageError` on bad names, including an unknown
    reference, on runs that cannot fit in memory
    (:func:`~mttbench.benchmarks.app.resources.check_jobs`) and on an output folder that
    cannot be written, all before any run and before the folder is touched.
    ``resume=True`` keeps the parts already in the folder and adds this session to the
    manifest's ``sessions``.

    The converged Bayes reference (:mod:`~mttbench.benchmarks.app.bayes`) of each scenario
    whose stored reference covers the seeds (the package's, and the folder's
    ``bayes/store``) joins the summary and the report as the row ``bayes`` with each
    tracker's share of the achievable gap; ``compute_bayes`` first computes the missing
    ones (``bayes_ladder``) into ``<out>/bayes/`` with a progress bar.

    Tuned parameters (:mod:`~mttbench.benchmarks.app.tuned`): a tracker with a file
    ``<tuned_dir>/<name>.toml`` (None: the package's ``tuned/``) runs its parameters under
    the label ``name(tuned)`` unless ``untuned``; ``tuning_effect`` also runs its defaults
    (label ``name``) for the report's "Effect of tuning". A bare ``reference`` name means
    the tuned setting.

    ``policies`` (None: raster) are the cell-selection policies every tracker runs under,
    the first the base of the paired differences between policies; the Bayes reference
    is looked up (and computed) per policy, never borrowed from another policy.
    """
    t0 = time.perf_counter()
    pols = list(policies) if policies else [PolicySpec("raster")]
    started = datetime.now(UTC)
    scs = resolve_scenarios(list(scenario_names), steps)
    texts = list(tracker_texts) if tracker_texts else default_tracker_texts()
    seeds = list(range(COMPARE_SEEDS)) if seeds is None else [int(s) for s in seeds]
    plan = tuned.plan_tuning(resolve_trackers(texts), tuned_dir, seeds, untuned=untuned,
                             tuning_effect=tuning_effect)
    specs = plan.specs
    labels = [s.label for s in specs]
    if reference is None:
        reference = default_reference(plan.main)
    else:
        reference = _resolve_reference(reference, plan.main)
        if reference not in labels:
            raise UsageError(f"--reference {reference!r} is not one of the trackers {labels}")
    workers = workers or os.cpu_count() or 1
    out = Path(out_dir) if out_dir else Path("reports") / f"compare-{started:%Y%m%dT%H%M%SZ}"

    jobs = build_jobs(scs, specs, pols, None, seeds)
    for line in resources.check_jobs(jobs, workers):
        print(line, file=sys.stderr)
    prepare_out_dir(out)
    # another sweep's folder, or this one's without --resume: refused before it is touched
    check_sweep(out, [job.key(c, p) for job in jobs], c, p, resume)

    command = list(argv) if argv is not None else list(sys.argv)
    previous = read_manifest(out) if resume else None
    sessions: list[dict[str, Any]] = [
        s for s in (previous or {}).get("sessions", []) if isinstance(s, dict)]
    session = {"started_utc": started.isoformat(), "command": command, "wall_time_s": None,
               "status": "running"}
    sessions.append(session)
    manifest: dict[str, Any] = {
        "status": "running",
        "command": command,
        "started_utc": started.isoformat(),
        "wall_time_s": None,
        "session_wall_time_s": None,
        "runs_wall_time_s": None,
        "sessions": sessions,
        "workers": workers,
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "versions": package_versions(),
        "git": git_commit(),
        "scenarios": [sc.name for sc in scs],
        "steps": {sc.name: sc.n_steps for sc in scs},
        "trackers": [s.label for s in specs],
        "policies": [pol.label for pol in pols],
        "parameters": {label: {"tuned_file": str(src.tuned.path) if src.tuned else None,
                               "source": src.why, "params": src.params}
                       for label, src in plan.sources.items()},
        "seeds": seeds,
        "reference": reference,
        "ospa_c": {sc.name: cutoff(c, sc.grid.cell_size) for sc in scs},
        "ospa_p": p,
        # the run-level (track) metrics and their parameters (c and p: the run's)
        "track_metrics": run_metric_params(),
        "n_runs": len(jobs),
        "n_rows": None,
    }

    def save_manifest(status: str) -> None:
        wall = round(time.perf_counter() - t0, 3)
        session.update(wall_time_s=wall, status=status)
        manifest.update(status=status, session_wall_time_s=wall, wall_time_s=round(
            sum(float(s.get("wall_time_s") or 0.0) for s in sessions), 3))
        write_text_atomic(out / "manifest.json", json.dumps(manifest, indent=2) + "\n")

    save_manifest("running")
    axis = f" x {len(pols)} policies" if len(pols) > 1 else ""
    print(f"{len(jobs)} runs ({len(scs)} scenarios x {len(specs)} trackers{axis} x "
          f"{len(seeds)} seeds) on {describe_current(workers)} -> {out}", file=sys.stderr)
    try:
        results = run_sweep(jobs, out, workers=workers, progress=progress, resume=resume,
                            c=c, p=p, run_timeout=run_timeout or default_run_timeout(jobs))
        stores = [bayes.default_store(), out / "bayes" / "store"]
        if compute_bayes:
            _compute_missing_bayes(scs, seeds, out, stores, bayes_ladder or bayes.Ladder(),
                                   workers, progress, c, p, run_timeout, pols)
        t_runs = time.perf_counter() - t0
        manifest["runs_wall_time_s"] = round(t_runs, 3)
        manifest["n_rows"] = len(results)
        bayes_lines = []
        for pol in pols:
            results, lines = bayes.attach(results, scs, seeds, pol, None, c, p, stores,
                                          name_policy=len(pols) > 1)
            bayes_lines += lines
        manifest["bayes"] = bayes_lines
        order = [pol.label for pol in pols]
        earlier = sum(float(s.get("wall_time_s") or 0.0) for s in sessions[:-1])
        wall_text = f"{t_runs:.1f} s"
        if len(sessions) > 1:
            wall_text += (f" in this session; {earlier + t_runs:.1f} s over {len(sessions)} "
                          "sessions (resumed after an interruption)")
        settings = {
            "scenarios": ", ".join(f"{sc.name} ({sc.n_steps} steps)" for sc in scs),
            "trackers": ", ".join(s.label for s in specs),
            "parameters": ("defaults (--untuned)" if untuned else "tuned where "
                           f"{tuned.show_path(plan.tuned_dir)}/<tracker>.toml exists (label "
                           "name(tuned)), else the defaults; see Parameters"),
            "seeds": _seed_text(seeds),
            "policy": _policy_setting(pols),
            "metrics": f"OSPA/GOSPA cut-off c = {_cutoff_text(c, scs)}, order p = {p:g}; "
                       "positions only",
            "reference for paired differences": reference or "none (every tracker uses "
                                                             "the truth)",
            "floor and ceiling": f"{summary.FLOOR_TRACKER} and {summary.CEILING_TRACKER} "
                                 "(share of the OSPA gap closed)",
            "Bayes reference": "; ".join(bayes_lines),
            "workers": describe_current(workers),
            "wall time of the runs": wall_text,
        }
        intro = [
            "Every tracker on the same simulated worlds (common random numbers: truth and "
            "sensor returns depend only on scenario and seed); the settings of this report "
            "are listed at the end. Without options `mttbench compare` runs a budget chosen to "
            "take well under a minute on two cores: 10 seeds, each scenario's own "
            "length, JMPD at 1000 particles (plus a 250-particle setting). Narrow the "
            "intervals with `--seeds`, lengthen runs with `--steps`, choose trackers and "
            "parameters with `--trackers name:key=value`.",
        ]
        from . import report  # matplotlib: imported only when a report is drawn

        # the figures are drawn in the workers while this process writes the summary,
        # traces the snapshot's run and writes the report
        with report.start_report(results, out, policy_order=order,
                                 processes=workers) as pending:
            axis_md = policy_axis.markdown(pending.axis) if len(pols) > 1 else ""
            summary.write_summary(results, out, "mttbench compare",
                                  notes=tuned.parameter_notes(plan),
                                  sections=[axis_md] if axis_md else (), runs=pending.runs,
                                  summ=pending.summ, gc=pending.gc)
            pending.add_snapshot(_snapshot_trace(scs, specs, seeds, pols[0]) if snapshot
                                 else None)
            files = pending.finish(reference=reference, intro=intro, settings=settings,
                                   sections=tuned.report_sections(plan, results),
                                   tuned_on=tuned.tuned_scenarios(plan))
    except BaseException as exc:
        status = "interrupted" if isinstance(exc, KeyboardInterrupt) else "failed"
        with contextlib.suppress(OSError):
            save_manifest(status)
        raise
    save_manifest("finished")
    return CompareOutput(results, out, files, manifest)


def _compute_missing_bayes(scs, seeds: list[int], out: Path, stores: list[Path],
                           ladder: bayes.Ladder, workers: int, progress: bool, c: float,
                           p: float, run_timeout: float | None,
                           pols: Sequence[PolicySpec] = (bayes.RASTER,)) -> None:
    """The Bayes reference of every scenario and policy that has none stored for these
    seeds, run in ``<out>/bayes/ladder`` (raster; ``ladder-<policy>`` for the others;
    resumable with the comparison) and stored in ``stores[-1]``."""
    for pol in pols:
        missing = [sc for sc in scs if bayes.find(sc, pol, None, seeds, c, p, stores) is None]
        if not missing:
            continue
        under = "" if pol == PolicySpec("raster") else f" under {pol.label}"
        print(f"computing the bayes reference of {', '.join(sc.name for sc in missing)}"
              f"{under} (docs/bayes.md)", file=sys.stderr)
        folder = "ladder" if not under else "ladder-" + "".join(
            ch if ch.isalnum() or ch in "-_." else "_" for ch in pol.label)
        bayes.run_command(missing, seeds, ladder, pol, None, out / "bayes" / folder,
                          stores[-1], workers=workers, progress=progress, resume=True, c=c,
                          p=p, run_timeout=run_timeout,
                          provenance={"git": git_commit(), "versions": package_versions()})


def _policy_setting(pols: Sequence[PolicySpec]) -> str:
    """The report's line on the cell-selection policy (or policies)."""
    if len(pols) == 1 and pols[0] == PolicySpec("raster"):
        return ("raster sweep at each scenario's looks_per_step (the same cells for every "
                "tracker, so differences are the trackers')")
    if len(pols) == 1:
        return (f"{pols[0].label} at each scenario's looks_per_step (every tracker chooses "
                "its own cells when the policy reads the tracker's prediction)")
    return (", ".join(pol.label for pol in pols) + " at each scenario's looks_per_step, "
            "every tracker under each on the same worlds (paired by seed); differences "
            f"between policies against {pols[0].label}")


def default_reference(specs: Sequence[TrackerSpec]) -> str | None:
    """The reference when none is given: the first of :data:`COMPARE_REFERENCES` that runs
    (its first setting), else the first tracker that does not use the truth, else None."""
    fair = [s for s in specs if s.name != summary.CEILING_TRACKER and not spec_uses_truth(s)]
    if not fair:
        return None
    labels = [s.label for s in fair]
    for name in COMPARE_REFERENCES:
        chosen = _resolve_reference(name, fair)
        if chosen in labels:
            return chosen
    return fair[0].label


def _resolve_reference(reference: str, specs: Sequence[TrackerSpec]) -> str:
    labels = [s.label for s in specs]
    if reference in labels:
        return reference
    named = [s.label for s in specs if s.name == reference]
    return named[0] if named else reference


def _cutoff_text(c: float | None, scs: Sequence[Any]) -> str:
    """The cut-off of each scenario with its units (one text when they agree)."""
    texts = {describe_cutoff(cutoff(c, sc.grid.cell_size), sc.grid.cell_size) for sc in scs}
    if len(texts) == 1:
        return texts.pop()
    return "; ".join(f"{sc.name} {describe_cutoff(cutoff(c, sc.grid.cell_size), sc.grid.cell_size)}"
                     for sc in scs)


def _seed_text(seeds: list[int]) -> str:
    if seeds and seeds == list(range(seeds[0], seeds[0] + len(seeds))):
        return f"{seeds[0]}..{seeds[-1]} ({len(seeds)} seeds)"
    return ", ".join(map(str, seeds))


def _snapshot_trace(scs, specs: list[TrackerSpec], seeds: list[int],
                    policy: PolicySpec = bayes.RASTER):
    """Trace seed ``seeds[0]`` of the first grid scenario for the preferred tracker under
    ``policy``."""
    from ...scenarios.model import RayleighGridSensor
    from ..engine.snapshot import trace_run

    grid_scs = [sc for sc in scs if isinstance(sc.model.sensor, RayleighGridSensor)]
    if not grid_scs or not seeds:
        return None
    by_name = {s.name: s for s in specs}
    chosen = next((by_name[n] for n in SNAPSHOT_PREFERENCE if n in by_name), specs[0])
    try:
        return trace_run(grid_scs[0], chosen, seeds[0], policy)
    except Exception:  # noqa: BLE001 - a failing tracker is already in the tables
        return None

"""Resource checks before a sweep: refuse runs that cannot fit in memory, warn about slow ones.

A sweep is checked before its first run (and before its output folder is touched):
every job's peak memory is estimated from the scenario and the tracker and policy
parameters, and a job that cannot fit in the memory one worker may use is refused
with one line naming the estimate and the limit. A sweep estimated to take more than
:data:`SLOW_SWEEP_S` of wall time gets a one-line warning. Both estimates are simple,
deliberately conservative (upper) bounds of the current code's behaviour, not
predictions; the constants were measured on a 2-core x86-64 Linux machine and rounded
up: the peak RSS of one ``run_job`` in a fresh process (``getrusage``, the high-water
mark reset after the imports and a warm-up run) and its wall time, with
``docs/resources_memory.py`` (every command, the tables, each tracker's and policy's
terms and what is still ``O(cells)``: docs/resources.md).

What a run costs whatever it runs is here; what the tracker and the policy add, they
declare themselves: :meth:`Tracker.resource_terms
<mttbench.trackers.base.Tracker.resource_terms>` gives the tracker's
:class:`~mttbench.trackers.base.ResourceTerms` (``tracker.*`` below; a tracker written
elsewhere gets the base class's terms) and :meth:`Policy.resource_terms
<mttbench.benchmarks.engine.policies.Policy.resource_terms>` the policy's
:class:`~mttbench.benchmarks.engine.policies.PolicyTerms` (``policy.*``), each from the
parameters with their defaults filled in; their measured constants sit next to the
classes they describe.

A run's step costs ``O(looks + targets + particles)`` unless its policy
asks for every cell, so the estimate is in steps ``S``, looks per step ``M`` (the
policy's ``policy.looks``: the budget, or ``C`` for a policy that looks at every cell),
targets ``T`` and particles; the grid's ``C`` cells enter only as a cap (``min(C, .)``:
there are no more distinct cells than that), through the bits of a look's position in
the simulator's stream, and where the code is ``O(cells)``: ``M = C`` looks, and a
policy's dense ``P_c(t)`` (``policy.dense_rows``). Memory of one job, in bytes::

    WORKER_BASE                                  interpreter, numpy/pandas, numba kernels
    + RUN_BASE                                   a run's fixed working memory
    + S * (T * 48 + 256)                         the truth (simulated up front)
    + S * ROW_BYTES                              the result rows of the run
    + JUMP_TABLE_BYTES * tables + M * LOOK_BYTES simulator: one jump table per 16 bits of
                                                 the largest stream position R * C, and
                                                 each look's arrays (tracker's included)
    + policy.state_bytes                         the policy's own working memory
    + min(C, S * m) * tracker.looked_cell_bytes  an undetected field keeping a value for
                                                 every cell looked at so far
    + tracker.state_bytes + tracker.update_bytes the tracker's own
      + m * tracker.look_bytes
    + prediction                                 below, only when the policy reads P_c(t)

``m = min(M, C)`` distinct cells are looked at per step (the tracker's terms are
computed for them; ``m = 0`` and no grid terms without a grid sensor). ``R``, the most
looks one cell can get in a step, is ``ceil(M / C)`` for a policy that spreads its looks
(a raster that wraps), ``M`` when ``policy.repeats`` (:func:`rows_per_step`); ``tables =
ceil(bits(R C) / 16)``. ``T`` counts the initial targets and the expected births over
the run.

The prediction (``P_c(t)`` and the policy's work on it): ``E * ENTRY_BYTES + rows *
(PREDICTION_ROW_BYTES + n_counts * PREDICTION_COUNT_BYTES)``, with ``E =
tracker.prediction_entries`` (the entries ``P_c`` is built from: particle slots, cells
of Gaussians' boxes), ``n_counts = tracker.prediction_counts`` and ``rows = min(C, E +
looked so far) + policy.dense_rows`` (the cells with a row of their own, the looked
cells only for a tracker with a field).

The limit per worker is the memory available now (``MemAvailable`` of
``/proc/meminfo``, lowered to the cgroup's ``memory.max - memory.current`` when one is
set; ``os.sysconf`` elsewhere; the environment variable ``MTTBENCH_MEMORY_LIMIT_GB``
overrides it) divided by the number of runs that execute at once. The main process
also holds the whole results table, ``RESULT_ROW_BYTES`` per step of every run, which
must fit in what is available. If the available memory cannot be read, nothing is
refused.

Wall time of one job, in seconds: ``RUN_S + S * (STEP_S + T * tracker.target_seconds +
tracker.step_seconds + M * LOOK_S + min(C, S m) * tracker.looked_cell_seconds +
tracker.update_seconds + m * tracker.look_seconds + prediction)``, the prediction's
``(E + rows * n_counts) * PREDICTION_S + tracker.prediction_seconds``.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ...scenarios.model import RayleighGridSensor
from ...trackers.base import Tracker
from ...trackers.compiled import cold_modules
from ..engine.policies import Policy
from .usage import UsageError

MIB = 2**20

# ----------------------------------------------------------------- memory constants
#: resident memory of a worker after its imports and a first run: 174-183 MB measured,
#: 274-284 MB with the JMPDs' numba kernels loaded
WORKER_BASE = 384 * MIB
#: fixed growth of the peak RSS during any run (frames, metrics, allocator slack): under
#: 1 MB measured for null and kfnn on 12x12 as on 1e5 x 1e5 (raster)
RUN_BASE = 16 * MIB
#: one jump table of the simulator's PCG64 stream: four arrays of 2^16 uint64 (exact)
JUMP_TABLE_BYTES = 4 * 2**16 * 8
#: bits of the stream position per jump table (``scenarios.simulator._DIGIT_BITS``)
JUMP_TABLE_BITS = 16
#: per look and step: the simulator's 128-bit arithmetic on uint64 arrays and the
#: tracker's per-look work; 212-230 B measured (``all`` on 700x700: null, kfnn,
#: truth-aided)
LOOK_BYTES = 512
#: per entry P_c(t) is built from (a particle slot or a Gaussian's cell in its box)
ENTRY_BYTES = 192
#: per row of P_c(t) and per row and count column: the rows, their copies and renyi's
#: gain tables: 454 B per row at 4 columns (kfnn: 250,000 looked cells under renyi),
#: 581 B at 5 (jmpd-ap, the same) and 2,650 B at 31 (jmpd, 48,041 rows) measured
PREDICTION_ROW_BYTES = 384
PREDICTION_COUNT_BYTES = 96
#: one step's result row inside the worker (a dict of ~45 entries, then a DataFrame row)
#: and its truth: 2.5-4.0 KB per step measured over 20,000 steps (null, kfnn on 12x12)
ROW_BYTES = 6144
#: one step's result row in the main process (parts read back, concatenated, sorted)
RESULT_ROW_BYTES = 4096

# ------------------------------------------------------------------- time constants
STEP_S = 1e-3
#: per look: the simulator's ~1 us and the trackers' per-look work
LOOK_S = 2e-6
#: per run: the truth's simulation, the tracker's reset, the rows' DataFrame
RUN_S = 0.1
#: per entry and per row and column of the prediction (kfnn under renyi: ~60 ms per
#: step with 250,000 rows of 4 columns)
PREDICTION_S = 1e-7
#: a sweep estimated to take longer than this on its workers gets a warning
SLOW_SWEEP_S = 3600.0

MEMORY_ENV = "MTTBENCH_MEMORY_LIMIT_GB"


@dataclass(frozen=True)
class Estimate:
    """Estimated peak memory (bytes) and wall time (seconds) of one job; ``parts`` names
    the memory terms (bytes), largest first when shown."""

    memory: float
    seconds: float
    parts: dict[str, float]

    def largest_part(self) -> str:
        return max(self.parts, key=self.parts.__getitem__)


def _params(kind: str, name: str, given: dict[str, Any]) -> tuple[dict[str, Any], Any]:
    """All parameters (defaults filled in) and the class, or ``(given, None)`` if unknown."""
    try:
        if kind == "tracker":
            from ... import trackers
            cls = trackers.get_class(name)
        else:
            from ..engine import policies
            cls = policies.get_policy_class(name)
        return {**cls.param_defaults(), **given}, cls
    except Exception:  # noqa: BLE001 - an unknown class has no known cost
        return dict(given), None


def rows_per_step(n_looks: int, n_cells: int, repeats: bool) -> int:
    """The most looks one cell can get in a step (the simulator's repeat index runs
    below it): ``ceil(M / C)`` spread, ``M`` with repeats."""
    if n_looks <= 0 or n_cells <= 0:
        return 1
    return max(1, n_looks if repeats else math.ceil(n_looks / n_cells))


def jump_tables(n_positions: int) -> int:
    """Jump tables the simulator builds for stream positions below ``n_positions``: one
    per 16 bits of the largest ``position + 1`` (at least one)."""
    return max(1, math.ceil(int(n_positions).bit_length() / JUMP_TABLE_BITS))


def estimate_job(job: Any) -> Estimate:
    """The memory and time estimate of one :class:`~mttbench.benchmarks.engine.loop.Job`
    (formulas in the module docstring)."""
    sc = job.scenario
    model = sc.model
    steps = float(sc.n_steps)
    bd = model.birth_death
    targets = len(bd.initial_states) + bd.n_random_initial + bd.birth_rate * steps
    parts: dict[str, float] = {
        "worker": float(WORKER_BASE),
        "run": float(RUN_BASE),
        "truth": steps * (targets * 48.0 + 256.0),
        "result rows": steps * ROW_BYTES,
    }
    per_step = STEP_S  # seconds

    on_grid = isinstance(model.sensor, RayleighGridSensor)
    distinct = 0.0  # distinct cells looked at per step
    if on_grid:
        cells = float(model.grid.n_cells)
        pparams, pcls = _params("policy", job.policy.name, dict(job.policy.params))
        budget = float(job.looks_per_step if job.looks_per_step is not None
                       else model.sensor.looks_per_step)
        policy = (pcls or Policy).resource_terms(pparams, model, budget)
        looks = policy.looks
        distinct = min(looks, cells)
        looked = min(cells, steps * distinct)  # by the run's end
    tparams, tcls = _params("tracker", job.tracker.name, dict(job.tracker.params))
    tracker = (tcls or Tracker).resource_terms(tparams, model, distinct, targets)
    per_step += targets * tracker.target_seconds
    per_step += tracker.step_seconds
    tracker_bytes = tracker.state_bytes

    if on_grid:
        rows = rows_per_step(int(min(looks, 2**62)), int(min(cells, 2**62)), policy.repeats)
        parts["simulator"] = (jump_tables(int(rows * cells)) * JUMP_TABLE_BYTES
                              + looks * LOOK_BYTES)
        per_step += looks * LOOK_S
        if policy.state_bytes:
            parts["policy"] = policy.state_bytes
        field = tracker.keeps_looked_cells
        if field:
            parts["looked cells"] = looked * tracker.looked_cell_bytes
            per_step += looked * tracker.looked_cell_seconds
        tracker_bytes += tracker.update_bytes
        per_step += tracker.update_seconds
        tracker_bytes += distinct * tracker.look_bytes
        per_step += distinct * tracker.look_seconds
        if pcls is not None and getattr(pcls, "uses_prediction", False):
            n_counts, entries = tracker.prediction_counts, tracker.prediction_entries
            own = min(cells, entries + (looked if field else 0.0))
            pc_rows = own + policy.dense_rows
            parts["predicted cell counts"] = (
                entries * ENTRY_BYTES
                + pc_rows * (PREDICTION_ROW_BYTES + n_counts * PREDICTION_COUNT_BYTES))
            per_step += (entries + pc_rows * n_counts) * PREDICTION_S
            per_step += tracker.prediction_seconds
    if tracker_bytes:
        parts["tracker"] = tracker_bytes
    return Estimate(sum(parts.values()), RUN_S + steps * per_step, parts)


# --------------------------------------------------------------- available memory
def _meminfo_available() -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return float(line.split()[1]) * 1024.0
    except (OSError, ValueError, IndexError):
        pass
    try:
        return float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def _cgroup_available() -> float | None:
    root = Path("/sys/fs/cgroup")
    try:
        limit = (root / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return float(limit) - float((root / "memory.current").read_text().strip())
    except (OSError, ValueError):
        return None


def available_memory() -> float | None:
    """Bytes of memory available to new work now (see the module docstring), or None."""
    env = os.environ.get(MEMORY_ENV, "").strip()
    if env:
        try:
            value = float(env)
        except ValueError:
            raise UsageError(f"{MEMORY_ENV}={env!r} is not a number of gigabytes") from None
        if not (math.isfinite(value) and value > 0):
            raise UsageError(f"{MEMORY_ENV}={env!r} is not allowed: expected a number > 0")
        return value * 2**30
    found = [v for v in (_meminfo_available(), _cgroup_available()) if v is not None]
    return min(found) if found else None


def fmt_bytes(n: float) -> str:
    """``n`` bytes as ``'7.28 TiB'`` (binary units, three significant digits)."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"):
        if abs(n) < 1024.0 or unit == "EiB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{n:.0f} B"
        n /= 1024.0
    raise AssertionError("unreachable")


def fmt_seconds(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    if s < 2 * 86400:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.1f} days"


def _describe(job: Any) -> str:
    sc = job.scenario
    where = f"scenario {sc.name!r}"
    if isinstance(sc.model.sensor, RayleighGridSensor):
        g = sc.model.grid
        where += f" ({g.nx}x{g.ny} grid, {sc.n_steps} steps)"
    else:
        where += f" ({sc.n_steps} steps)"
    return f"{where} with tracker {job.tracker.label}"


# ------------------------------------------------------------------------ checks
def check_jobs(jobs: list[Any], workers: int, available: float | None = None) -> list[str]:
    """Refuse (:class:`~mttbench.benchmarks.engine.specs.UsageError`, one line) a sweep whose
    largest job cannot fit in the memory of one worker, or whose results table cannot
    fit in the main process; return warning lines (a sweep estimated to be very slow).

    ``available`` None means :func:`available_memory`; ``workers`` the worker processes
    asked for (at most one per job runs at once).
    """
    if not jobs:
        return []
    estimates = [estimate_job(j) for j in jobs]
    at_once = max(1, min(int(workers), len(jobs)))
    available = available_memory() if available is None else available
    if available is not None:
        per_worker = available / at_once
        worst = max(range(len(jobs)), key=lambda i: estimates[i].memory)
        est = estimates[worst]
        if est.memory > per_worker:
            limit = (f"the {fmt_bytes(per_worker)} per worker ({fmt_bytes(available)} "
                     f"available / {at_once} workers); use fewer particles or looks, fewer "
                     "--steps or fewer --workers" if at_once > 1 else
                     f"the {fmt_bytes(available)} available; use fewer particles or looks "
                     "or fewer --steps")
            raise UsageError(
                f"{_describe(jobs[worst])}: one run needs about {fmt_bytes(est.memory)} of "
                f"memory (mostly the {est.largest_part()}, {fmt_bytes(max(est.parts.values()))}"
                f"), more than {limit}")
        rows = sum(j.scenario.n_steps for j in jobs)
        table = rows * RESULT_ROW_BYTES
        if table > available:
            raise UsageError(
                f"the results table of {len(jobs)} runs ({rows} steps) needs about "
                f"{fmt_bytes(table)} of memory, more than the {fmt_bytes(available)} "
                "available; run fewer seeds, scenarios or --steps per sweep")
    total = sum(e.seconds for e in estimates) / at_once
    if total > SLOW_SWEEP_S:
        slow = max(range(len(jobs)), key=lambda i: estimates[i].seconds)
        return [f"warning: this sweep may take about {fmt_seconds(total)} on {at_once} "
                f"worker(s) (a rough upper estimate; the slowest run, "
                f"{_describe(jobs[slow])}, about {fmt_seconds(estimates[slow].seconds)})"]
    return []


#: the least default wall-time limit of one run (seconds), and its factor over the
#: sweep's slowest estimated run (:func:`default_run_timeout`)
RUN_TIMEOUT_FLOOR_S = 60.0
RUN_TIMEOUT_FACTOR = 10.0
#: the least default limit while the compiled kernels' disk cache is cold: a worker's
#: first run then compiles the kernels it uses (all of them: about 130 s of CPU on a quiet
#: 2-core machine, several times that on a loaded one, both workers at once)
RUN_TIMEOUT_COLD_FLOOR_S = 600.0


def default_run_timeout(jobs: Sequence[Any]) -> float:
    """The default wall-time limit of one run (``--run-timeout``; tune and reproduce
    always): 10x the slowest run's time estimate (:func:`estimate_job`), at least 60 s,
    or at least 600 s while a compiled kernel module has nothing in numba's disk cache
    (:func:`mttbench.trackers.compiled.cold_modules`: a fresh install not warmed by
    ``make``). A limit given on the command line is used as given."""
    slowest = 0.0
    for job in jobs:
        with contextlib.suppress(Exception):  # no estimate: the floor
            slowest = max(slowest, float(estimate_job(job).seconds))
    floor = RUN_TIMEOUT_COLD_FLOOR_S if cold_modules() else RUN_TIMEOUT_FLOOR_S
    return max(floor, RUN_TIMEOUT_FACTOR * slowest)

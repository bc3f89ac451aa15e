"""Resource checks before a sweep: refuse runs that cannot fit in memory, warn about slow ones.

A sweep is checked before its first run (and before its output folder is touched):
every job's peak memory is estimated from the scenario and the tracker and policy
parameters, and a job that cannot fit in the memory one worker may use is refused
with one line naming the estimate and the limit. A sweep estimated to take more than
:data:`SLOW_SWEEP_S` of wall time gets a one-line warning. Both estimates are simple,
deliberately conservative (upper) bounds of the current code's behaviour, not
predictions; the constants below were measured on a 2-core x86-64 Linux machine
(peak RSS of one ``run_job`` through ``getrusage``, wall time of whole runs) and
rounded up.

Memory of one job, in bytes (``S`` steps, ``C`` cells, ``M`` looks per step)::

    WORKER_BASE                                 interpreter, numpy/pandas, numba kernels
    + RUN_BASE                                   a run's fixed working memory
    + S * R * C * 8                              sensor world: the simulator keeps R rows of
                                                 C uniforms per step (``Run._uniform_rows``)
    + (R + 2) * C * 8                            the same rows stacked, the cell counts
    + C * CELL_BYTES                             per-cell arrays of the tracker and policy
    + C * n_counts * 8 * PREDICTION_COPIES       P_c(t) and the gain tables, only when the
                                                 policy uses the tracker's prediction
    + tracker state                              JMPD: N * t_max * JMPD_SLOT_BYTES;
                                                 GPF: max_particles * GPF_PARTICLE_BYTES
                                                      + max_combinations * max_particles * 32
    + S * (T * 48 + 256)                         the truth: T targets (initial + births)
    + S * ROW_BYTES                              the result rows of the run

``R``, the rows of uniforms per step, is the most looks one cell can get in a step:
``ceil(M / C)`` for a policy that spreads its looks (a raster that wraps), ``M`` for a
policy with a true ``repeats`` parameter (every look may go to one cell). ``n_counts``
is the tracker's ``n_counts`` parameter, else ``t_max + 1``, at least 4. Trackers
named by class path and unknown policies count as having no state of their own.

The limit per worker is the memory available now (``MemAvailable`` of
``/proc/meminfo``, lowered to the cgroup's ``memory.max - memory.current`` when one is
set; ``os.sysconf`` elsewhere; the environment variable ``MTTBENCH_MEMORY_LIMIT_GB``
overrides it) divided by the number of runs that execute at once. The main process
also holds the whole results table, ``RESULT_ROW_BYTES`` per step of every run, which
must fit in what is available. If the available memory cannot be read, nothing is
refused.

Wall time of one job, in seconds: ``S * (STEP_S + C * R * CELL_S + prediction +
tracker)``, with ``C * n_counts * PREDICTION_CELL_S`` per step for a policy that uses
the prediction, ``N * t_max * JMPD_SLOT_S`` (``JMPD_IP_FACTOR`` times that for the IP
proposal, times ``1 + move_steps``) for the JMPD and ``max_particles * GPF_PARTICLE_S`` for the GPF.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..scenarios.model import RayleighGridSensor
from .specs import UsageError

# ----------------------------------------------------------------- memory constants
#: resident memory of a worker before its first run: ~170 MB of imports plus ~160 MB
#: of numba-compiled JMPD kernels, measured
WORKER_BASE = 384 * 2**20
#: fixed growth of the peak RSS during any run (frames, metrics, allocator slack): ~20 MB
#: measured on a 12x12 grid as on a 600x600 one
RUN_BASE = 32 * 2**20
#: per-cell arrays of the tracker (undetected-target field, look counts) and the policy
CELL_BYTES = 16
#: copies of ``P_c(t)``-sized arrays alive while a policy uses the prediction
PREDICTION_COPIES = 16
#: bytes per JMPD particle slot (states, their move and resampling buffers, cells, keys,
#: the estimate's alignment work): peaks of ~800 B per slot measured on ``large`` with
#: t_max = 30 (jmpd-ip, N = 2e4: 901 MB; jmpd, N = 1e5: 2.3 GB)
JMPD_SLOT_BYTES = 1024
#: bytes per GPF particle (mean, covariance and their working copies)
GPF_PARTICLE_BYTES = 2048
#: one step's result row inside the worker (a dict of ~45 entries, then a DataFrame row)
ROW_BYTES = 4096
#: one step's result row in the main process (parts read back, concatenated, sorted)
RESULT_ROW_BYTES = 4096

# ------------------------------------------------------------------- time constants
STEP_S = 1e-3
CELL_S = 1e-7
PREDICTION_CELL_S = 3e-7
#: seconds per JMPD slot and step (bootstrap; measured 0.22 s at N = 2e4, t_max = 30)
JMPD_SLOT_S = 4e-7
#: the IP proposal's cost relative to the bootstrap (measured 0.9 s against 0.22 s there)
JMPD_IP_FACTOR = 4.0
GPF_PARTICLE_S = 1e-4
KFNN_STEP_S = 5e-4
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
            from .. import trackers
            cls = trackers.get_class(name)
        else:
            from . import policies
            cls = policies.get_policy_class(name)
        return {**cls.param_defaults(), **given}, cls
    except Exception:  # noqa: BLE001 - an unknown class has no known cost
        return dict(given), None


def _number(params: dict[str, Any], key: str, default: float) -> float:
    v = params.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
        return float(default)
    return float(v)


def rows_per_step(n_looks: int, n_cells: int, repeats: bool) -> int:
    """Rows of uniforms the simulator keeps per step: the most looks one cell can get."""
    if n_looks <= 0 or n_cells <= 0:
        return 1
    return max(1, n_looks if repeats else math.ceil(n_looks / n_cells))


def estimate_job(job: Any) -> Estimate:
    """The memory and time estimate of one :class:`~mttbench.benchmarks.harness.Job`
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
    seconds_per_step = STEP_S

    tparams, _ = _params("tracker", job.tracker.name, dict(job.tracker.params))
    tname = job.tracker.name
    if tname.startswith("jmpd"):
        slots = _number(tparams, "n_particles", 2000) * _number(tparams, "t_max", 5)
        parts["tracker"] = slots * JMPD_SLOT_BYTES
        factor = JMPD_IP_FACTOR if tparams.get("proposal") == "ip" else 1.0
        seconds_per_step += slots * JMPD_SLOT_S * factor * (1 + _number(tparams, "move_steps", 0))
    elif tname == "gpf":
        n = _number(tparams, "max_particles", 100)
        parts["tracker"] = n * GPF_PARTICLE_BYTES + _number(
            tparams, "max_combinations", 512) * n * 32.0
        seconds_per_step += n * GPF_PARTICLE_S
    elif tname == "kfnn":
        seconds_per_step += KFNN_STEP_S

    if isinstance(model.sensor, RayleighGridSensor):
        cells = float(model.grid.n_cells)
        looks = int(job.looks_per_step if job.looks_per_step is not None
                    else model.sensor.looks_per_step)
        pparams, pcls = _params("policy", job.policy.name, dict(job.policy.params))
        rows = rows_per_step(looks, int(min(cells, 2**62)), bool(pparams.get("repeats", False)))
        parts["sensor world"] = steps * rows * cells * 8.0
        parts["per-cell arrays"] = (rows + 2) * cells * 8.0 + cells * CELL_BYTES
        seconds_per_step += cells * rows * CELL_S
        if pcls is not None and getattr(pcls, "uses_prediction", False):
            n_counts = max(4.0, _number(tparams, "n_counts", 0),
                           _number(tparams, "t_max", 0) + 1)
            parts["predicted cell counts"] = cells * n_counts * 8.0 * PREDICTION_COPIES
            seconds_per_step += cells * n_counts * PREDICTION_CELL_S
    return Estimate(sum(parts.values()), steps * seconds_per_step, parts)


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
    """Refuse (:class:`~mttbench.benchmarks.specs.UsageError`, one line) a sweep whose
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
                     f"available / {at_once} workers); use a smaller grid, fewer --steps or "
                     "fewer --workers" if at_once > 1 else
                     f"the {fmt_bytes(available)} available; use a smaller grid or fewer "
                     "--steps")
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

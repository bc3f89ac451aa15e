"""Resource checks before a sweep: refuse runs that cannot fit in memory, warn about slow ones.

A sweep is checked before its first run (and before its output folder is touched):
every job's peak memory is estimated from the scenario and the tracker and policy
parameters, and a job that cannot fit in the memory one worker may use is refused
with one line naming the estimate and the limit. A sweep estimated to take more than
:data:`SLOW_SWEEP_S` of wall time gets a one-line warning. Both estimates are simple,
deliberately conservative (upper) bounds of the current code's behaviour, not
predictions; the constants below were measured on a 2-core x86-64 Linux machine and
rounded up: the peak RSS of one ``run_job`` in a fresh process (``getrusage``, the
high-water mark reset after the imports and a warm-up run) and its wall time, with
``docs/resources_memory.py`` (every command, the tables and what is still ``O(cells)``:
docs/resources.md), for example::

    python docs/resources_memory.py --sides 12 50 2000 100000 --steps 20
    python docs/resources_memory.py --sides 100000 --looks 2500 --steps 100 \
        --trackers null kfnn truth-aided gpf jmpd-ap ss-gnn

Since issue 16 a run's step costs ``O(looks + targets + particles)`` unless its policy
asks for every cell, so the estimate is in steps ``S``, looks per step ``M``, targets ``T``
and particles;
the grid's ``C`` cells enter only as a cap (``min(C, .)``: there are no more distinct
cells than that), through the bits of a look's position in the simulator's stream,
and where the code is ``O(cells)``: the ``all`` policy (``M = C`` looks) and renyi's
dense path on grids of at most ``DENSE_CELLS`` = 2,500 cells
(:data:`~mttbench.benchmarks.engine.information.DENSE_CELLS`). Memory of one job, in bytes::

    WORKER_BASE                                  interpreter, numpy/pandas, numba kernels
    + RUN_BASE                                   a run's fixed working memory
    + S * (T * 48 + 256)                         the truth (simulated up front)
    + S * ROW_BYTES                              the result rows of the run
    + JUMP_TABLE_BYTES * tables + M * LOOK_BYTES simulator: one jump table per 16 bits of
                                                 the largest stream position R * C, and
                                                 each look's arrays (tracker's included)
    + min(C, 50 M) * 8                           random and oracle: numpy's choice
                                                 shuffles all cells unless C > 50 M
    + min(C, S * m) * LOOKED_CELL_BYTES          kfnn, ss-gnn, gpf, jmpd-ap: the
                                                 undetected field keeps a value for every
                                                 cell looked at so far
    + tracker                                    below
    + prediction                                 below, only when the policy reads P_c(t)

``m = min(M, C)`` distinct cells are looked at per step. ``R``, the most looks one cell
can get in a step, is ``ceil(M / C)`` for a policy that spreads its looks (a raster that
wraps), ``M`` for a policy with a true ``repeats`` parameter (:func:`rows_per_step`);
``tables = ceil(bits(R C) / 16)``. ``T`` counts the initial targets and the expected
births over the run. The tracker's own state:

* jmpd, jmpd-ip: ``N t_max (JMPD_SLOT_BYTES + t_max * JMPD_SLOT_T_BYTES)`` (the IP
  proposal: ``JMPD_IP_SLOT_T_BYTES`` per unit of ``t_max``, as measured) ``+ m (t_max +
  1) * JMPD_LOOK_BYTES`` (the look tables keyed by the looked cells);
* jmpd-ap: ``N t_max * AP_SLOT_BYTES + m (t_max + 1) * JMPD_LOOK_BYTES``, ``t_max`` its
  automatic slots when not given (``trackers.jmpd.ap._auto_slots``);
* gpf: ``G * GPF_GAUSSIAN_BYTES + max_combinations * max_particles * 32`` with
  ``G = max_particles * max_components`` Gaussians, and on the grid ``g min(BOX_CELLS, m)
  * PAIR_BYTES + m * GPF_LOOK_BYTES``: its update's (Gaussian, looked cell) pairs in the
  Gaussians' boxes (``g = min(G, 2 T + 16)`` Gaussians, as for ``P_c`` below) and a birth
  candidate per looked cell;
* truth-aided: ``(2 T + 16) min(BOX_CELLS, m) * PAIR_BYTES`` (its targets' images'
  pairs);
* others (kfnn, null, Stone Soup's peers, trackers named by class path): nothing beyond
  the terms above.

The prediction (``P_c(t)`` and renyi's gains): ``E * ENTRY_BYTES + rows *
(PREDICTION_ROW_BYTES + n_counts * PREDICTION_COUNT_BYTES)``, with ``E`` the entries
``P_c`` is built from -- ``N t_max`` particle slots for the JMPDs, ``BOX_CELLS`` cells
for each of ``2 T + 16`` Gaussians (capped at the gpf's ``G`` and ss-gmphd's
``max_components``) for the Gaussian trackers, none for null -- and ``rows = min(C, E +
looked so far)`` (the cells with a row of their own; the looked cells only for the four
trackers with a field) plus ``C`` on the dense path (``C <= DENSE_CELLS``).
``n_counts``: ``t_max + 1`` for jmpd and jmpd-ip, ``min(t_max, 4) + 1`` for jmpd-ap,
the gpf's ``n_counts``, 4 for the other Gaussian trackers, 2 for null, else the
``n_counts`` parameter or ``t_max + 1``, at least 4. ``(2 T + 16) * BOX_CELLS`` covers
the entries the Gaussians' 6-sd boxes held under renyi on the presets and on ``large``
over 1e5 x 1e5 (at most 8,701, gpf on ``large``: 45 Gaussians of 193 cells on average,
against 66 x 256 counted). It is not a bound: the box of a Gaussian left unobserved for
many steps grows with its sd (``(12 sd + 1)^2`` cells, at most the grid).

The limit per worker is the memory available now (``MemAvailable`` of
``/proc/meminfo``, lowered to the cgroup's ``memory.max - memory.current`` when one is
set; ``os.sysconf`` elsewhere; the environment variable ``MTTBENCH_MEMORY_LIMIT_GB``
overrides it) divided by the number of runs that execute at once. The main process
also holds the whole results table, ``RESULT_ROW_BYTES`` per step of every run, which
must fit in what is available. If the available memory cannot be read, nothing is
refused.

Wall time of one job, in seconds: ``RUN_S + S * (STEP_S + M * LOOK_S + tracker +
prediction)`` with ``T * TARGET_S`` for the Gaussian trackers (``PEER_TARGET_S`` for
Stone Soup's), ``min(C, S m) * LOOKED_CELL_S`` for the four trackers with a field (a step's
``O(cells looked so far)``, taken at the run's end), ``N t_max (JMPD_SLOT_S + t_max *
JMPD_SLOT_T_S)`` for jmpd (``JMPD_IP_FACTOR`` times that for the IP proposal, times
``1 + move_steps``), ``N t_max * AP_SLOT_S`` for jmpd-ap, ``max_particles *
GPF_PARTICLE_S + pairs * PAIR_S + m * GPF_LOOK_S`` for the gpf, ``pairs * PAIR_S`` for
truth-aided (``pairs`` as in the memory terms), ``KFNN_STEP_S`` for kfnn; the prediction
``(E + rows * n_counts) * PREDICTION_S``, and for the JMPDs ``N t_max log2(t_max + 1) *
JMPD_SLOT_T_S`` (their in-particle counts, from sorted runs).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ...scenarios.model import RayleighGridSensor
from ..engine.information import DENSE_CELLS
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
#: per cell looked at so far, for the trackers with an undetected field (a value per
#: such cell, inserted with a copy): 25 (kfnn), 27 (ss-gnn), 76 (jmpd-ap) and 96 B
#: (gpf, its box test included) more than null's growth, over 250,000 looked cells
#: (raster, 2,500 looks x 100 steps on 1e5 x 1e5)
LOOKED_CELL_BYTES = 128
#: bytes per JMPD particle slot, plus per slot and per unit of ``t_max``: bootstrap 268 B
#: per slot at t_max = 5 (N = 5e4), 478 B at t_max = 30 (N = 2e4); the IP proposal
#: 282 B and 1,197 B there
JMPD_SLOT_BYTES = 256
JMPD_SLOT_T_BYTES = 16
JMPD_IP_SLOT_T_BYTES = 48
#: bytes per jmpd-ap slot: 138 B (N = 5000 on ``large``, t_max 54) and 253 B (``scale``,
#: N = 500, t_max 2,004) measured
AP_SLOT_BYTES = 384
#: per looked cell and count column of a JMPD's look tables: 22 B measured (jmpd-ap,
#: ``all`` on 700x700)
JMPD_LOOK_BYTES = 32
#: bytes per GPF Gaussian (mean, covariance and their working copies)
GPF_GAUSSIAN_BYTES = 2048
#: per (Gaussian, looked cell) pair: its quadrature's temporaries (16 arrays of up to
#: 24 nodes) and moments
PAIR_BYTES = 3072
#: per looked cell of the gpf: its birth candidate (a uniform row with its 4x4
#: covariance) and the update's per-cell arrays: 970-1,400 B measured above null (the
#: ``all`` policy on 300x300 and 700x700)
GPF_LOOK_BYTES = 2048
#: per looked cell of the gpf and step (its birth candidate): 3.4 us measured (``all`` on
#: 700x700: 5.0 s for 3 steps)
GPF_LOOK_S = 4e-6
#: per entry P_c(t) is built from (a particle slot or a Gaussian's cell in its box)
ENTRY_BYTES = 192
#: per row of P_c(t) and per row and count column: the rows, their copies and renyi's
#: gain tables: 454 B per row at 4 columns (kfnn: 250,000 looked cells under renyi),
#: 581 B at 5 (jmpd-ap, the same) and 2,650 B at 31 (jmpd, 48,041 rows) measured
PREDICTION_ROW_BYTES = 384
PREDICTION_COUNT_BYTES = 96
#: cells of a Gaussian's 6-sd box counted per Gaussian (module docstring)
BOX_CELLS = 256
#: one step's result row inside the worker (a dict of ~45 entries, then a DataFrame row)
#: and its truth: 2.5-4.0 KB per step measured over 20,000 steps (null, kfnn on 12x12)
ROW_BYTES = 6144
#: one step's result row in the main process (parts read back, concatenated, sorted)
RESULT_ROW_BYTES = 4096

# ------------------------------------------------------------------- time constants
STEP_S = 1e-3
#: per look: the simulator's ~1 us and the trackers' per-look work
LOOK_S = 2e-6
#: per cell looked at so far and step (the undetected field's update)
LOOKED_CELL_S = 1e-8
#: per JMPD slot and step, plus per slot and unit of t_max (the O(N t_max^2) passes):
#: 50-66 ms per step measured at N = 2000, t_max = 30
JMPD_SLOT_S = 5e-7
JMPD_SLOT_T_S = 2e-8
#: the IP proposal's cost relative to the bootstrap (measured 0.9 s against 0.22 s there)
JMPD_IP_FACTOR = 4.0
#: per jmpd-ap slot and step: 0.35 s for 1e6 slots (``scale``), ~25 ms for 27,000
AP_SLOT_S = 1e-6
GPF_PARTICLE_S = 1e-4
#: per target and step of the trackers with a Gaussian per target (kfnn, truth-aided,
#: gpf): truth-aided 3 ms per step with 25 targets on 12x12
TARGET_S = 2e-4
#: per target and step of Stone Soup's peers (Python objects per track and detection):
#: ss-gmphd 210 ms per step with 25 targets on 12x12, ss-gnn 26 ms
PEER_TARGET_S = 1e-2
#: per run: the truth's simulation, the tracker's reset, the rows' DataFrame
RUN_S = 0.1
#: per (Gaussian, looked cell) pair: its truncated moments (gpf on ``large``: 3-5 ms for
#: 4,000 pairs) or a birth candidate's update
PAIR_S = 1e-6
KFNN_STEP_S = 5e-4
#: per entry and per row and column of the prediction (kfnn under renyi: ~60 ms per
#: step with 250,000 rows of 4 columns)
PREDICTION_S = 1e-7
#: a sweep estimated to take longer than this on its workers gets a warning
SLOW_SWEEP_S = 3600.0

MEMORY_ENV = "MTTBENCH_MEMORY_LIMIT_GB"

#: trackers whose undetected field (and P_c rows) keeps every cell looked at so far
FIELD_TRACKERS = frozenset({"kfnn", "ss-gnn", "gpf", "jmpd-ap"})
#: trackers whose P_c(t) comes from Gaussians' boxes
GAUSSIAN_TRACKERS = frozenset({"kfnn", "ss-gnn", "ss-gmphd", "gpf", "truth-aided"})


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


def _number(params: dict[str, Any], key: str, default: float) -> float:
    v = params.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
        return float(default)
    return float(v)


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


def _slots(name: str, params: dict[str, Any], model: Any) -> tuple[float, float]:
    """``(N, t_max)`` of a JMPD; jmpd-ap's automatic ``t_max`` when none is given."""
    n = _number(params, "n_particles", 2000)
    t_max = params.get("t_max")
    if name == "jmpd-ap" and t_max is None:
        from ...trackers.jmpd.ap import _auto_slots
        return n, float(_auto_slots(model))
    return n, _number(params, "t_max", 5)


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

    tname = job.tracker.name
    if tname in ("ss-gnn", "ss-gmphd"):
        per_step += targets * PEER_TARGET_S
    elif tname in GAUSSIAN_TRACKERS:
        per_step += targets * TARGET_S
    tparams, _ = _params("tracker", tname, dict(job.tracker.params))
    jmpd = tname in ("jmpd", "jmpd-ip", "jmpd-ap")
    n, t_max = _slots(tname, tparams, model) if jmpd else (0.0, 0.0)
    gaussians = 0.0
    tracker_bytes = 0.0
    if tname == "jmpd-ap":
        tracker_bytes = n * t_max * AP_SLOT_BYTES
        per_step += n * t_max * AP_SLOT_S
    elif jmpd:
        ip = tname == "jmpd-ip" or tparams.get("proposal") == "ip"
        per_t = JMPD_IP_SLOT_T_BYTES if ip else JMPD_SLOT_T_BYTES
        tracker_bytes = n * t_max * (JMPD_SLOT_BYTES + t_max * per_t)
        per_step += (n * t_max * (JMPD_SLOT_S + t_max * JMPD_SLOT_T_S)
                     * (JMPD_IP_FACTOR if ip else 1.0)
                     * (1 + _number(tparams, "move_steps", 0)))
    elif tname == "gpf":
        particles = _number(tparams, "max_particles", 100)
        gaussians = particles * max(1.0, _number(tparams, "max_components", 1))
        tracker_bytes = (gaussians * GPF_GAUSSIAN_BYTES
                         + _number(tparams, "max_combinations", 512) * particles * 32.0)
        per_step += particles * GPF_PARTICLE_S
    elif tname == "kfnn":
        per_step += KFNN_STEP_S

    if isinstance(model.sensor, RayleighGridSensor):
        cells = float(model.grid.n_cells)
        pname = job.policy.name
        pparams, pcls = _params("policy", pname, dict(job.policy.params))
        looks = float(job.looks_per_step if job.looks_per_step is not None
                      else model.sensor.looks_per_step)
        if pname == "all":
            looks = cells
        distinct = min(looks, cells)  # distinct cells looked at per step
        looked = min(cells, steps * distinct)  # by the run's end
        repeats = bool(pparams.get("repeats", False))
        rows = rows_per_step(int(min(looks, 2**62)), int(min(cells, 2**62)), repeats)
        parts["simulator"] = (jump_tables(int(rows * cells)) * JUMP_TABLE_BYTES
                              + looks * LOOK_BYTES)
        per_step += looks * LOOK_S
        if pname in ("random", "oracle"):
            parts["policy"] = min(cells, 50.0 * looks) * 8.0
        field = tname in FIELD_TRACKERS
        if field:
            parts["looked cells"] = looked * LOOKED_CELL_BYTES
            per_step += looked * LOOKED_CELL_S
        if jmpd:
            tracker_bytes += distinct * (t_max + 1) * JMPD_LOOK_BYTES
        elif tname in ("gpf", "truth-aided"):
            present = 2.0 * targets + 16.0  # Gaussians (or target images) at once
            if tname == "gpf":
                present = min(present, gaussians)
            pairs = present * min(float(BOX_CELLS), distinct)
            tracker_bytes += pairs * PAIR_BYTES
            per_step += pairs * PAIR_S
            if tname == "gpf":
                tracker_bytes += distinct * GPF_LOOK_BYTES
                per_step += distinct * GPF_LOOK_S
        if pcls is not None and getattr(pcls, "uses_prediction", False):
            n_counts, entries = _prediction_size(tname, tparams, n, t_max, targets, gaussians)
            own = min(cells, entries + (looked if field else 0.0))
            pc_rows = own + (cells if cells <= DENSE_CELLS else 0.0)
            parts["predicted cell counts"] = (
                entries * ENTRY_BYTES
                + pc_rows * (PREDICTION_ROW_BYTES + n_counts * PREDICTION_COUNT_BYTES))
            per_step += (entries + pc_rows * n_counts) * PREDICTION_S
            if jmpd:
                per_step += n * t_max * math.log2(t_max + 1.0) * JMPD_SLOT_T_S
    if tracker_bytes:
        parts["tracker"] = tracker_bytes
    return Estimate(sum(parts.values()), RUN_S + steps * per_step, parts)


def _prediction_size(tname: str, tparams: dict[str, Any], n: float, t_max: float,
                     targets: float, gpf_gaussians: float) -> tuple[float, float]:
    """``(n_counts, entries)`` of a tracker's ``P_c(t)`` (module docstring)."""
    if tname in ("jmpd", "jmpd-ip"):
        return t_max + 1, n * t_max
    if tname == "jmpd-ap":
        return min(t_max, 4) + 1, n * t_max
    if tname == "null":
        return 2.0, 0.0
    gaussians = 2.0 * targets + 16.0
    if tname == "gpf":
        gaussians = min(gaussians, gpf_gaussians)
    elif tname == "ss-gmphd":
        gaussians = min(gaussians, _number(tparams, "max_components", 200))
    if tname in GAUSSIAN_TRACKERS:
        n_counts = _number(tparams, "n_counts", 4) if tname == "gpf" else 4.0
        return max(2.0, n_counts), gaussians * BOX_CELLS
    # a tracker named by class path: its parameters' counts, Gaussians' boxes
    return (max(4.0, _number(tparams, "n_counts", 0), _number(tparams, "t_max", 0) + 1),
            gaussians * BOX_CELLS)


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

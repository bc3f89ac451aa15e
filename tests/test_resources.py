"""Resource estimates (``benchmarks/app/resources.py``): the formulas, the refusal, the warning,
and that the memory estimate bounds what a run really takes -- on a 1e5 x 1e5 grid too,
which the estimate must accept and a run must not need ``O(cells)`` memory for."""

from __future__ import annotations

import ctypes
import ctypes.util
import dataclasses
import gc
import math
import multiprocessing
import re
import resource
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from mttbench import scenarios, trackers
from mttbench.benchmarks.app import resources
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.app.compare import default_tracker_texts
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.information import DENSE_CELLS
from mttbench.benchmarks.engine.loop import Job, build_jobs, run_job
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec, resolve_trackers
from mttbench.scenarios import simulator
from mttbench.scenarios.model import Grid
from mttbench.scenarios.spec import dumps
from mttbench.trackers.jmpd.ap import _auto_slots

GIB = 2.0**30
MIB = 2.0**20
HUGE = 100_000  # a 1e5 x 1e5 grid: 1e10 cells


def scenario(nx: int, ny: int | None = None, steps: int = 100, looks: int | None = None,
             preset: str = "default"):
    sc = scenarios.get(preset)
    sensor = sc.model.sensor if looks is None else dataclasses.replace(sc.model.sensor,
                                                                       looks_per_step=looks)
    model = dataclasses.replace(sc.model, grid=Grid(nx, ny or nx), sensor=sensor)
    return dataclasses.replace(sc, model=model, n_steps=steps, name=f"grid{nx}")


def job(sc, tracker="null", policy="raster", looks=None, policy_params=None, **params) -> Job:
    return Job(sc, TrackerSpec(tracker, params), PolicySpec(policy, policy_params or {}),
               looks, 0)


# ------------------------------------------------------------------ the formulas
def test_simulator_term_is_jump_tables_and_looks():
    """10,000 x 20,000 cells: positions below 2e8 take two 16-bit jump tables; the
    looks' arrays are per look, the grid's cells add nothing."""
    est = resources.estimate_job(job(scenario(10_000, 20_000, steps=7)))
    assert est.parts["simulator"] == 2 * resources.JUMP_TABLE_BYTES + 24 * resources.LOOK_BYTES
    assert resources.JUMP_TABLE_BYTES == 2 * MIB
    assert est.memory == pytest.approx(sum(est.parts.values()))
    assert est.largest_part() == "worker"
    small = resources.estimate_job(job(scenario(12, steps=7)))
    assert small.parts["simulator"] == resources.JUMP_TABLE_BYTES + 24 * resources.LOOK_BYTES


@pytest.mark.parametrize(("looks", "cells", "repeats", "rows"), [
    (24, 144, False, 1), (144, 144, False, 1), (145, 144, False, 2), (312, 144, False, 3),
    (24, 144, True, 24), (0, 144, False, 1),
])
def test_rows_per_step(looks, cells, repeats, rows):
    assert resources.rows_per_step(looks, cells, repeats) == rows


@pytest.mark.parametrize("n", [1, 2, 2**16 - 1, 2**16, 2**16 + 1, 144 * 312, 10**10,
                               2**48 - 1, 2**48])
def test_jump_tables_are_those_the_simulator_builds(monkeypatch, n):
    """:func:`resources.jump_tables` against the tables ``pcg64_uniforms`` asks for when
    it draws the last position below ``n``."""
    asked = []
    real = simulator._jump_table

    def spy(i):
        asked.append(i)
        return real(i)

    monkeypatch.setattr(simulator, "_jump_table", spy)
    simulator.pcg64_uniforms(12345, 6789, [n - 1])
    assert resources.jump_tables(n) == max(asked) + 1


def test_no_term_grows_with_the_grid_past_the_dense_path():
    """Every registered tracker under raster and renyi: a 1e5 x 1e5 grid costs what a
    3000 x 3000 one does (both above DENSE_CELLS), but for the simulator's jump tables
    (three against two); on a grid within the dense path renyi adds its dense rows."""
    assert 3000**2 > DENSE_CELLS
    extra_tables = resources.jump_tables(HUGE**2) - resources.jump_tables(3000**2)
    assert extra_tables == 1
    for name in trackers.available():
        for policy in ("raster", "renyi"):
            small = resources.estimate_job(job(scenario(3000, preset="large"), name, policy))
            huge = resources.estimate_job(job(scenario(HUGE, preset="large"), name, policy))
            assert small.parts.keys() == huge.parts.keys(), (name, policy)
            for part, value in huge.parts.items():
                more = extra_tables * resources.JUMP_TABLE_BYTES if part == "simulator" else 0
                assert value == small.parts[part] + more, (name, policy, part)
    dense = resources.estimate_job(job(scenario(50), "null", "renyi"))
    sparse = resources.estimate_job(job(scenario(51), "null", "renyi"))
    per_row = resources.PREDICTION_ROW_BYTES + 2 * resources.PREDICTION_COUNT_BYTES
    assert dense.parts["predicted cell counts"] == 2500 * per_row  # null: no own rows
    assert sparse.parts["predicted cell counts"] == 0


def test_tracker_and_prediction_terms_follow_the_parameters():
    sc = scenario(12)  # 24 looks on 144 cells, 3 targets, 100 steps
    r = resources
    small = r.estimate_job(job(sc, "jmpd", n_particles=1000))
    big = r.estimate_job(job(sc, "jmpd", n_particles=4000, t_max=10))
    assert small.parts["tracker"] == (1000 * 5 * (r.JMPD_SLOT_BYTES + 5 * r.JMPD_SLOT_T_BYTES)
                                      + 24 * 6 * r.JMPD_LOOK_BYTES)
    assert big.parts["tracker"] == (4000 * 10 * (r.JMPD_SLOT_BYTES + 10 * r.JMPD_SLOT_T_BYTES)
                                    + 24 * 11 * r.JMPD_LOOK_BYTES)
    ip = r.estimate_job(job(sc, "jmpd-ip", n_particles=1000))
    assert ip.parts["tracker"] == (1000 * 5 * (r.JMPD_SLOT_BYTES + 5 * r.JMPD_IP_SLOT_T_BYTES)
                                   + 24 * 6 * r.JMPD_LOOK_BYTES)
    assert ip.seconds > small.seconds
    assert "predicted cell counts" not in small.parts
    # jmpd-ap without t_max: its automatic slots
    t_ap = _auto_slots(sc.model)
    ap = r.estimate_job(job(sc, "jmpd-ap"))
    assert ap.parts["tracker"] == 500 * t_ap * r.AP_SLOT_BYTES + 24 * (t_ap + 1) * r.JMPD_LOOK_BYTES
    # renyi on 144 cells (the dense path): the gpf's 2 T + 16 = 22 Gaussians' boxes, its
    # own rows capped by the grid, plus the dense rows
    renyi = r.estimate_job(job(sc, "gpf", "renyi", n_counts=7))
    entries = 22 * r.BOX_CELLS
    rows = min(144, entries + 144) + 144
    assert renyi.parts["predicted cell counts"] == (
        entries * r.ENTRY_BYTES + rows * (r.PREDICTION_ROW_BYTES + 7 * r.PREDICTION_COUNT_BYTES))
    # the fields of the cells looked at so far: 24 per step, at most the grid
    assert renyi.parts["looked cells"] == 144 * r.LOOKED_CELL_BYTES
    huge = r.estimate_job(job(scenario(HUGE, steps=10), "kfnn"))
    assert huge.parts["looked cells"] == 10 * 24 * r.LOOKED_CELL_BYTES
    assert "looked cells" not in r.estimate_job(job(scenario(HUGE), "truth-aided")).parts
    # renyi with repeats: a cell may take all 24 looks, positions up to 24 x 1e10
    repeats = r.estimate_job(job(scenario(HUGE), "null", "renyi", policy_params={"repeats": True}))
    assert repeats.parts["simulator"] == (r.jump_tables(24 * HUGE**2) * r.JUMP_TABLE_BYTES
                                          + 24 * r.LOOK_BYTES)
    # the all policy looks at every cell: O(cells) by definition
    every = r.estimate_job(job(scenario(300, steps=3), "null", "all"))
    assert every.parts["simulator"] == r.JUMP_TABLE_BYTES * 2 + 300**2 * r.LOOK_BYTES
    # random: numpy's choice shuffles every cell when there are fewer than 50 per look
    assert r.estimate_job(job(scenario(12), "null", "random")).parts["policy"] == 144 * 8
    assert r.estimate_job(job(scenario(HUGE), "null", "random")).parts["policy"] == 50 * 24 * 8


def test_a_job_that_cannot_fit_is_refused_on_any_machine():
    """JMPD with 1e9 particles of 5 slots: about 1.5 TiB of particles, refused with one line
    even with 1 TiB available (512 GiB per worker)."""
    jobs = build_jobs([scenario(12)], [TrackerSpec("jmpd", {"n_particles": 10**9})], None,
                      None, [0, 1])
    with pytest.raises(ConfigError) as err:
        resources.check_jobs(jobs, workers=2, available=1024 * GIB)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith("scenario 'grid12' (12x12 grid, 100 steps) with tracker "
                          "jmpd(n_particles=1000000000): one run needs about ")
    assert re.search(r"needs about 1\.\d\d TiB of memory \(mostly the tracker, 1\.\d\d TiB\), "
                     r"more than the 512 GiB per worker \(1 TiB available / 2 workers\); use "
                     r"fewer particles or looks, fewer --steps or fewer --workers$", msg), msg
    # looking at every cell of a 1e6 x 1e6 grid is O(cells): refused too
    every = build_jobs([scenario(10**6)], [TrackerSpec("null")], [PolicySpec("all")], None, [0])
    with pytest.raises(ConfigError, match=r"mostly the simulator, [\d.]+ TiB"):
        resources.check_jobs(every, workers=1, available=1024 * GIB)


def test_huge_grids_are_accepted_for_every_tracker():
    """1e5 x 1e5 and 1e6 x 1e6 grids, 100 steps of large's 25 targets and 250 looks: every
    registered tracker under raster and renyi fits in 1 GiB per worker."""
    for side in (HUGE, 10**6):
        sc = scenario(side, preset="large")
        jobs = build_jobs([sc], [TrackerSpec(n) for n in trackers.available()],
                          [PolicySpec("raster"), PolicySpec("renyi")], None, [0, 1])
        resources.check_jobs(jobs, workers=2, available=2 * GIB)
        worst = max(resources.estimate_job(j).memory for j in jobs)
        assert worst < 1 * GIB, worst / MIB


def test_limit_is_shared_by_the_runs_that_execute_at_once():
    sc = scenario(12, steps=100)
    need = resources.estimate_job(job(sc, "jmpd", n_particles=10**6)).memory  # ~1.9 GiB
    jobs = build_jobs([sc], [TrackerSpec("jmpd", {"n_particles": 10**6})], None, None,
                      [0, 1, 2])
    resources.check_jobs(jobs, workers=3, available=3.01 * need)
    with pytest.raises(ConfigError, match="per worker"):
        resources.check_jobs(jobs, workers=3, available=2.99 * need)
    # more workers than jobs: only three runs at once
    resources.check_jobs(jobs, workers=64, available=3.01 * need)
    resources.check_jobs(jobs[:1], workers=64, available=1.01 * need)


def test_results_table_must_fit_in_the_main_process():
    jobs = build_jobs([scenario(12, steps=1000)], [TrackerSpec("null")], None, None,
                      list(range(1000)))
    table = 1000 * 1000 * resources.RESULT_ROW_BYTES
    assert table > 4 * resources.estimate_job(jobs[0]).memory  # the table is the limit here
    resources.check_jobs(jobs, workers=1, available=1.01 * table)
    with pytest.raises(ConfigError, match=r"results table of 1000 runs \(1000000 steps\)"):
        resources.check_jobs(jobs, workers=1, available=0.99 * table)


def test_slow_sweeps_warn_and_the_default_compare_does_not():
    default = build_jobs([scenarios.get(n) for n in ("default", "crossing", "births", "paper")],
                         resolve_trackers(default_tracker_texts()), None, None, list(range(10)))
    assert resources.check_jobs(default, workers=2, available=64 * GIB) == []
    slow = build_jobs([scenario(12, steps=50_000)], [TrackerSpec("jmpd", {"n_particles": 10**5})],
                      None, None, list(range(4)))
    warnings = resources.check_jobs(slow, workers=2, available=64 * GIB)
    assert len(warnings) == 1 and "\n" not in warnings[0]
    assert warnings[0].startswith("warning: this sweep may take about ")
    assert "jmpd(n_particles=100000)" in warnings[0]


def test_memory_override_and_available_memory(monkeypatch):
    monkeypatch.setenv(resources.MEMORY_ENV, "1.5")
    assert resources.available_memory() == 1.5 * GIB
    for bad in ("lots", "0", "-1", "nan", "inf"):
        monkeypatch.setenv(resources.MEMORY_ENV, bad)
        with pytest.raises(ConfigError, match=resources.MEMORY_ENV):
            resources.available_memory()
    monkeypatch.delenv(resources.MEMORY_ENV)
    found = resources.available_memory()
    if sys.platform.startswith("linux"):
        assert found is not None and found > 0


@pytest.mark.parametrize(("n", "text"), [
    (0, "0 B"), (1023, "1023 B"), (1024, "1 KiB"), (1536, "1.5 KiB"), (8 * 10**12, "7.28 TiB"),
    (2.0**70, "1.02e+03 EiB"),
])
def test_fmt_bytes(n, text):
    assert resources.fmt_bytes(n) == text


# ------------------------------------------------------- the estimate bounds reality
def _status_mb(key: str) -> float:
    text = Path("/proc/self/status").read_text()
    return int(re.search(key + r":\s+(\d+)", text).group(1)) / 1024.0


def _peak_growth(warm: Job, j: Job) -> float:
    """Bytes the peak RSS grows by while ``j`` runs, in a process forked from a warm one.
    ``warm`` runs first in the child too (the pages of code and data the parent shares
    are mapped into the child as they are touched: ~19 MB that are the fork's, not the
    run's), the allocator's free memory goes back to the system (``malloc_trim``: what
    earlier tests freed would otherwise hide the run's arrays), then the high-water mark
    is reset (``/proc/self/clear_refs``) and compared with the resident size before the
    run. The address space may grow by 4 GiB at most,
    so that an ``O(cells)`` array on a huge grid fails at once (MemoryError: an error
    row)."""
    room = int((_status_mb("VmSize") + 4096) * MIB)
    resource.setrlimit(resource.RLIMIT_AS, (room, room))
    run_job(warm)
    gc.collect()
    # the free memory earlier tests left in the allocator's heap back to the system, so
    # that the run's arrays are counted when they touch it again
    ctypes.CDLL(ctypes.util.find_library("c")).malloc_trim(0)
    Path("/proc/self/clear_refs").write_text("5")
    before = _status_mb("VmRSS")
    rows = run_job(j)
    assert (rows["status"] == "ok").all(), rows["error"].unique()
    return (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0 - before) * MIB


MEASURED = [  # (tracker, params, policy, grid side, steps)
    ("kfnn", {}, "raster", HUGE, 5),  # the huge grid: nothing per cell
    ("kfnn", {}, "renyi", HUGE, 5),  # P_c and renyi's sparse path, three jump tables
    ("gpf", {}, "renyi", HUGE, 5),
    ("jmpd", {}, "renyi", HUGE, 5),  # int64 cells, P_c rows for the particles' cells
    ("jmpd", {"n_particles": 50_000}, "raster", 12, 5),  # the particles
    ("null", {}, "all", 300, 3),  # 90,000 looks per step
    ("gpf", {}, "all", 300, 3),  # a birth candidate per look, pairs in the boxes only
]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and fork")
@pytest.mark.parametrize(("tracker", "params", "policy", "side", "steps"), MEASURED,
                         ids=[f"{m[0]}-{m[2]}-{m[3]}" for m in MEASURED])
def test_estimate_bounds_the_measured_peak(tracker, params, policy, side, steps):
    """The estimate (worker base aside) is at least the measured growth of the peak RSS
    of one run, and not wildly above it (at most 4x + 48 MiB: the constants are rounded
    up from measurements, not arbitrary; RUN_BASE alone is 16 MiB). On the 1e5 x 1e5 grid
    the sweep check must accept the run with 256 MiB beyond the worker's base."""
    warm = job(scenario(12, steps=2), tracker, policy)  # imports, numba kernels
    run_job(warm)
    if side > 46_340:  # more than 2^31 - 1 cells: the int64 kernels
        run_job(job(scenario(side, steps=2), tracker, policy))
    j = job(scenario(side, steps=steps), tracker, policy, **params)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("fork")) as pool:
        measured = pool.submit(_peak_growth, warm, j).result()
    est = resources.estimate_job(j).memory - resources.WORKER_BASE
    assert measured <= est, (measured / MIB, est / MIB)
    assert est <= 4 * measured + 48 * MIB, (measured / MIB, est / MIB)
    assert math.isfinite(measured)
    if side == HUGE:
        resources.check_jobs([j], workers=1, available=resources.WORKER_BASE + 256 * MIB)


def test_mttbench_run_accepts_and_runs_a_huge_grid(monkeypatch, tmp_path, capsys):
    """The command line on a 1e5 x 1e5 grid (kfnn, 3 steps) under a 1 GiB limit: accepted,
    run, its rows written."""
    monkeypatch.setenv(resources.MEMORY_ENV, "1")
    sc = scenario(HUGE, steps=3, preset="large")
    path = tmp_path / "huge.toml"
    path.write_text(dumps(dataclasses.replace(sc, name="huge")), encoding="utf-8")
    rc = main(["run", "--scenarios", str(path), "--trackers", "kfnn", "--seeds", "1",
               "--workers", "1", "--no-progress", "--out", str(tmp_path / "out")])
    assert rc == 0, capsys.readouterr().err
    assert any((tmp_path / "out").rglob("*.parquet"))

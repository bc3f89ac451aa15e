"""Resource estimates (``benchmarks/resources.py``): the formulas, the refusal, the warning,
and that the memory estimate bounds what a run really takes."""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import resource
import sys
from concurrent.futures import ProcessPoolExecutor

import pytest

from mttbench import scenarios
from mttbench.benchmarks import resources
from mttbench.benchmarks.compare import default_tracker_texts
from mttbench.benchmarks.harness import Job, build_jobs, run_job
from mttbench.benchmarks.specs import PolicySpec, TrackerSpec, UsageError, resolve_trackers
from mttbench.scenarios.model import Grid

GIB = 2.0**30


def scenario(nx: int, ny: int | None = None, steps: int = 100, looks: int | None = None):
    sc = scenarios.get("default")
    sensor = sc.model.sensor if looks is None else dataclasses.replace(sc.model.sensor,
                                                                       looks_per_step=looks)
    model = dataclasses.replace(sc.model, grid=Grid(nx, ny or nx), sensor=sensor)
    return dataclasses.replace(sc, model=model, n_steps=steps, name=f"grid{nx}")


def job(sc, tracker="null", policy="raster", looks=None, **params) -> Job:
    return Job(sc, TrackerSpec(tracker, params), PolicySpec(policy), looks, 0)


def test_world_term_is_steps_rows_cells_doubles():
    est = resources.estimate_job(job(scenario(10_000, 20_000, steps=7)))
    assert est.parts["sensor world"] == 7 * 1 * 10_000 * 20_000 * 8
    assert est.memory == pytest.approx(sum(est.parts.values()))
    assert est.largest_part() == "sensor world"


@pytest.mark.parametrize(("looks", "cells", "repeats", "rows"), [
    (24, 144, False, 1), (144, 144, False, 1), (145, 144, False, 2), (312, 144, False, 3),
    (24, 144, True, 24), (0, 144, False, 1),
])
def test_rows_per_step(looks, cells, repeats, rows):
    assert resources.rows_per_step(looks, cells, repeats) == rows


def test_tracker_and_prediction_terms_follow_the_parameters():
    sc = scenario(12)
    small = resources.estimate_job(job(sc, "jmpd", n_particles=1000))
    big = resources.estimate_job(job(sc, "jmpd", n_particles=4000, t_max=10))
    assert big.parts["tracker"] == 8 * small.parts["tracker"]
    assert small.parts["tracker"] == 1000 * 5 * resources.JMPD_SLOT_BYTES
    assert "predicted cell counts" not in small.parts
    renyi = resources.estimate_job(job(sc, "gpf", "renyi", n_counts=7))
    assert renyi.parts["predicted cell counts"] == 144 * 7 * 8 * resources.PREDICTION_COPIES
    repeats = Job(sc, TrackerSpec("null"), PolicySpec("renyi", {"repeats": True}), 24, 0)
    assert resources.estimate_job(repeats).parts["sensor world"] == 100 * 24 * 144 * 8


def test_a_million_by_a_million_grid_is_refused_on_any_machine():
    jobs = build_jobs([scenario(10**6)], [TrackerSpec("null")], None, None, [0, 1])
    with pytest.raises(UsageError) as err:
        resources.check_jobs(jobs, workers=2, available=1024 * GIB)  # even with 1 TiB
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith("scenario 'grid1000000' (1000000x1000000 grid, 100 steps) with "
                          "tracker null: one run needs about ")
    assert "TiB of memory (mostly the sensor world, 728 TiB), more than the 512 GiB per " \
           "worker (1 TiB available / 2 workers)" in msg


def test_limit_is_shared_by_the_runs_that_execute_at_once():
    sc = scenario(1000, steps=100)  # world 800 MB
    need = resources.estimate_job(job(sc)).memory
    jobs = build_jobs([sc], [TrackerSpec("null")], None, None, [0, 1, 2])
    resources.check_jobs(jobs, workers=3, available=3.01 * need)
    with pytest.raises(UsageError, match="per worker"):
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
    with pytest.raises(UsageError, match=r"results table of 1000 runs \(1000000 steps\)"):
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
        with pytest.raises(UsageError, match=resources.MEMORY_ENV):
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
def _peak_growth(j: Job) -> float:
    """Bytes the peak RSS grows by while ``j`` runs, in a process forked from a warm one
    (its high-water mark starts at the parent's resident size)."""
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    rows = run_job(j)
    assert (rows["status"] == "ok").all(), rows["error"].unique()
    return (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) * 1024.0


MEASURED = [  # (tracker, params, policy, grid side, steps)
    ("null", {}, "raster", 300, 60),  # the sensor world dominates
    ("kfnn", {}, "raster", 300, 30),  # the tracker's per-cell arrays
    ("jmpd", {"n_particles": 50_000}, "raster", 12, 5),  # the particles
    ("null", {}, "renyi", 200, 5),  # the predicted cell counts and the gain
]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="ru_maxrss in KiB and fork")
@pytest.mark.parametrize(("tracker", "params", "policy", "side", "steps"), MEASURED,
                         ids=[f"{m[0]}-{m[2]}-{m[3]}" for m in MEASURED])
def test_estimate_bounds_the_measured_peak(tracker, params, policy, side, steps):
    """The estimate (worker base aside) is at least the measured growth of the peak RSS
    of one run, and not wildly above it (at most 4x + 48 MiB: the constants are rounded
    up from measurements, not arbitrary; RUN_BASE alone is 32 MiB)."""
    run_job(job(scenario(12, steps=2), tracker, policy, **params))  # warm: imports, numba
    j = job(scenario(side, steps=steps), tracker, policy, **params)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("fork")) as pool:
        measured = pool.submit(_peak_growth, j).result()
    est = resources.estimate_job(j).memory - resources.WORKER_BASE
    assert measured <= est, (measured / 2**20, est / 2**20)
    assert est <= 4 * measured + 48 * 2**20, (measured / 2**20, est / 2**20)
    assert math.isfinite(measured)

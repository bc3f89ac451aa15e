"""Rules of the memory and time estimates (``benchmarks/app/resources.py``) where a slip
shows: looks that wrap a grid by a fraction, stream positions one past a 16-bit digit,
fewer jobs than workers, a run that fits exactly, a results table larger than one
worker's share, the unit boundaries of the printed sizes and times, the cap of the
looked cells at the grid's cells, a sweep whose time is shared by its workers. The
expected values are the documented formulas worked out by hand."""

from __future__ import annotations

import dataclasses

import pytest

from mttbench import scenarios
from mttbench.benchmarks.app import resources
from mttbench.benchmarks.app.usage import UsageError
from mttbench.benchmarks.engine.loop import build_jobs
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec


def _jobs(tracker: str = "null", n_steps: int = 10, seeds=(0,)):
    sc = dataclasses.replace(scenarios.get("default"), n_steps=n_steps)
    return build_jobs([sc], [TrackerSpec(tracker)], [PolicySpec("raster")], None, list(seeds))


def test_rows_per_step_rounds_a_wrapping_raster_up():
    assert resources.rows_per_step(30, 12, False) == 3  # ceil(2.5)
    assert resources.rows_per_step(24, 12, False) == 2
    assert resources.rows_per_step(5, 12, False) == 1
    assert resources.rows_per_step(30, 12, True) == 30


def test_one_jump_table_per_started_16_bits():
    assert resources.jump_tables(2**16 - 1) == 1  # 16 bits
    assert resources.jump_tables(2**16) == 2  # 17 bits
    assert resources.jump_tables(2**32) == 3
    assert resources.jump_tables(0) == 1


def test_memory_is_shared_by_the_runs_that_execute_at_once():
    """One job on four workers runs alone: it has all the memory."""
    jobs = _jobs()
    need = resources.estimate_job(jobs[0]).memory
    assert resources.check_jobs(jobs, 4, available=need * 1.5) == []
    assert resources.check_jobs(jobs, 1, available=need) == []  # fits exactly
    with pytest.raises(UsageError, match="one run needs about"):
        resources.check_jobs(jobs, 1, available=need * 0.99)


def test_the_results_table_is_checked_against_all_the_memory():
    """Two runs of 10^6 steps on two workers: each worker's share holds a run but not
    the whole table (2 x 10^6 x RESULT_ROW_BYTES), which the main process holds in all
    the memory available."""
    jobs = _jobs(n_steps=1_000_000, seeds=(0, 1))
    need = resources.estimate_job(jobs[0]).memory
    table = 2 * 1_000_000 * resources.RESULT_ROW_BYTES
    available = 2 * need
    assert need < table <= available
    resources.check_jobs(jobs, 2, available=available)
    # one worker with room for a run but not for the table
    with pytest.raises(UsageError, match="the results table"):
        resources.check_jobs(jobs, 1, available=(need + table) / 2)


@pytest.mark.parametrize(("n", "text"), [(1023, "1023 B"), (1024, "1 KiB"),
                                         (1536, "1.5 KiB"), (2**20, "1 MiB")])
def test_fmt_bytes_units(n, text):
    assert resources.fmt_bytes(n) == text


@pytest.mark.parametrize(("s", "text"), [(119, "119 s"), (120, "2 min"), (3600, "60 min"),
                                         (7199, "120 min"), (7200, "2.0 h"),
                                         (2 * 86400, "2.0 days")])
def test_fmt_seconds_units(s, text):
    assert resources.fmt_seconds(s) == text


def test_the_available_memory_is_the_least_of_what_is_known(monkeypatch):
    monkeypatch.delenv(resources.MEMORY_ENV, raising=False)
    monkeypatch.setattr(resources, "_meminfo_available", lambda: 8e9)
    monkeypatch.setattr(resources, "_cgroup_available", lambda: 2e9)
    assert resources.available_memory() == 2e9
    monkeypatch.setattr(resources, "_cgroup_available", lambda: None)
    assert resources.available_memory() == 8e9


def test_the_looked_cells_are_capped_at_the_grids_cells():
    """kfnn keeps a value per looked cell: 24 looks a step on 144 cells, over 100 steps
    min(144, 2400) = 144 cells."""
    job = _jobs("kfnn", n_steps=100)[0]
    est = resources.estimate_job(job)
    model = job.scenario.model
    terms = type(job.tracker.make()).resource_terms(
        {**type(job.tracker.make()).param_defaults()}, model, 24.0, 3.0)
    assert est.parts["looked cells"] == pytest.approx(144 * terms.looked_cell_bytes)


def test_the_slow_sweep_warning_divides_the_time_among_the_workers():
    jobs = _jobs(n_steps=3_000_000, seeds=(0, 1))
    each = resources.estimate_job(jobs[0]).seconds
    assert 1800 < each < 3600  # two of them exceed an hour, one does not
    assert resources.check_jobs(jobs, 2, available=1e18) == []
    warn = resources.check_jobs(jobs, 1, available=1e18)
    assert len(warn) == 1 and warn[0].startswith("warning: this sweep may take about")

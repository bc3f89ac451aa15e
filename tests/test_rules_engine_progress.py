"""The command line's progress (benchmarks/app/progress.py): the one-line-per-tenth
callback for a log file, checked against the tenths computed in integers by hand, and
which callback ``run_sweep`` hands the engine (none, tenths, or a tqdm bar) with the
default run time limit filled in."""

from __future__ import annotations

import io

import pytest

from mttbench.benchmarks.app import progress, resources
from mttbench.benchmarks.engine.loop import Job
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.scenarios import get as get_scenario


def _tenths_by_hand(total: int) -> list[str]:
    """A line each time ``10 * finished // total`` reaches a new decile above 0."""
    lines, last = [], 0
    for finished in range(total + 1):
        decile = 10 * finished // total
        if decile > last:
            last = decile
            lines.append(f"runs: {100 * finished // total}% ({finished}/{total})\n")
    return lines


@pytest.mark.parametrize("total", [1, 3, 7, 10, 20, 33])
def test_tenths_writes_one_line_per_tenth_passed(total):
    out = io.StringIO()
    show = progress.tenths(out)
    for finished in range(total + 1):
        show(finished, total)
    assert out.getvalue().splitlines(keepends=True) == _tenths_by_hand(total)


def test_tenths_of_a_resumed_sweep_and_of_nothing():
    out = io.StringIO()
    show = progress.tenths(out)
    show(0, 0)  # no run at all: no line
    assert out.getvalue() == ""
    show(6, 10)  # resumed with 6 of 10 done: one line for 60%, then on from there
    show(7, 10)
    show(7, 10)  # the same count again: no new line
    assert out.getvalue() == "runs: 60% (6/10)\nruns: 70% (7/10)\n"


class _Stream(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self._tty = tty

    def isatty(self) -> bool:
        return self._tty


@pytest.fixture
def jobs():
    return [Job(get_scenario("single-clean"), TrackerSpec("null"), seed=s) for s in (0, 1)]


@pytest.mark.parametrize("how", ["none", "log", "terminal"])
def test_run_sweep_hands_the_engine_the_callback_and_the_default_limit(how, jobs, tmp_path,
                                                                      monkeypatch):
    calls = []

    def fake_sweep(jobs_, out_dir, **options):
        calls.append(options)
        if options.get("progress") is not None:
            options["progress"](0, len(jobs_))
            options["progress"](len(jobs_), len(jobs_))
        return "table"

    stream = _Stream(tty=how == "terminal")
    monkeypatch.setattr(progress.sweep, "run_sweep", fake_sweep)
    monkeypatch.setattr(progress.sys, "stderr", stream)
    assert progress.run_sweep(jobs, tmp_path, progress=how != "none", workers=2) == "table"
    (options,) = calls
    assert options["workers"] == 2
    assert options["run_timeout"] == resources.default_run_timeout(jobs)
    assert options["run_timeout"] >= resources.RUN_TIMEOUT_FLOOR_S
    if how == "none":
        assert "progress" not in options and stream.getvalue() == ""
    elif how == "log":
        assert stream.getvalue() == "runs: 100% (2/2)\n"
    else:  # the tqdm bar, drawn on the terminal and closed at 2 of 2
        drawn = stream.getvalue()
        assert "\r" in drawn and "| 2/2 [" in drawn and "runs: 100% (2/2)" not in drawn


def test_a_given_run_limit_is_kept(jobs, tmp_path, monkeypatch):
    seen = []
    monkeypatch.setattr(progress.sweep, "run_sweep",
                        lambda jobs_, out_dir, **options: seen.append(options))
    progress.run_sweep(jobs, tmp_path, progress=False, run_timeout=7.5)
    assert seen == [{"run_timeout": 7.5}]

"""Runtime benchmarks (pytest-benchmark): collection of ``bench_*.py`` and shared fixtures.

Files here are named ``bench_*.py`` so the correctness run (``pytest`` over ``tests/``)
never picks them up; this conftest collects them when ``benchmarks/bench`` is given
explicitly. Commands (see the README, "Runtime benchmarks")::

    pytest benchmarks/bench --benchmark-only                       # time everything
    pytest -q benchmarks/bench --benchmark-disable                 # CI: run once, untimed
    pytest benchmarks/bench --benchmark-only \\
        --benchmark-storage=.benchmarks/baseline --benchmark-compare=0001 \\
        --benchmark-compare-fail=min:150%                          # regression check
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass

import numpy as np
import pytest

from mttbench.benchmarks.harness import play
from mttbench.benchmarks.metrics import step_metrics
from mttbench.scenarios.model import Looks
from mttbench.scenarios.spec import Scenario
from mttbench.trackers.base import Tracker


def pytest_collect_file(file_path, parent):
    """Collect ``bench_*.py`` as test modules (unless pytest's own collector already does:
    a file named on the command line, or one matching ``python_files``)."""
    if file_path.suffix != ".py" or not file_path.name.startswith("bench_"):
        return None
    if parent.session.isinitpath(file_path):
        return None
    patterns = parent.config.getini("python_files")
    if any(fnmatch.fnmatch(file_path.name, p) for p in patterns):
        return None
    return pytest.Module.from_parent(parent, path=file_path)


@dataclass
class Warm:
    """A tracker after ``n_steps`` untimed steps, and what the timed step will see."""

    tracker: Tracker  # state after the warm-up (copy it before timing: never mutate)
    looks: Looks  # the looks of step ``n_steps`` (the timed step)
    truth: np.ndarray  # (n, 4) true states at the timed step
    warm_ospa: float  # mean OSPA (c = 2, p = 2) over the warm-up steps


def warm_up(scenario: Scenario, tracker: Tracker, n_steps: int, seed: int = 0) -> Warm:
    """Play ``n_steps`` raster steps of ``seed`` through the harness's step loop
    (:func:`mttbench.benchmarks.harness.play`), so a timed step starts from a realistic
    state; skips the benchmark if the tracker cannot run the scenario."""
    reason = tracker.unsupported_reason(scenario.model)
    if reason:
        pytest.skip(f"{tracker.name} cannot run {scenario.name}: {reason}")
    playback = play(scenario, tracker, seed, n_steps=n_steps)
    ospa = []
    for rec in playback:
        states = np.asarray(rec.estimate.states, dtype=float).reshape(-1, 4)
        ospa.append(step_metrics(rec.truth[:, [0, 2]], states[:, [0, 2]],
                                 float(rec.estimate.count))["ospa"])
    looks = playback.world.look(n_steps, playback.policy.select(n_steps))
    return Warm(tracker, looks, playback.world.states[n_steps].copy(), float(np.mean(ospa)))


@pytest.fixture(name="warm_up")
def warm_up_fixture():
    """:func:`warm_up`, for benchmark modules (which cannot import this conftest)."""
    return warm_up


_RATIOS: list[tuple[str, float, float]] = []  # (benchmark, paired ratio, noise median s)


@pytest.fixture
def record_ratio(request):
    """``record_ratio(ratio, noise_s)``: list a paired step / noise ratio in the
    terminal summary (``bench_jmpd.test_jmpd_bootstrap_step``)."""
    def record(ratio: float, noise_s: float) -> None:
        _RATIOS.append((request.node.name, ratio, noise_s))
    return record


def pytest_terminal_summary(terminalreporter):
    if not _RATIOS:
        return
    terminalreporter.section("JMPD bootstrap step / its noise draw (paired, median of rounds)")
    for name, ratio, noise_s in _RATIOS:
        terminalreporter.write_line(f"{name:45s} {ratio:5.2f}x   (draw {noise_s * 1e3:6.1f} ms)")

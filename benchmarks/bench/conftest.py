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

import pytest


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

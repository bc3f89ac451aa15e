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

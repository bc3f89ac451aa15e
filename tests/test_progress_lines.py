"""The progress bar when the output is not a terminal: a line per tenth of the runs."""

from __future__ import annotations

import io

import pytest

from mttbench.benchmarks.app import progress


@pytest.mark.parametrize("total", [1, 3, 10, 37, 250])
def test_a_line_per_tenth(total):
    """Every run finished one by one (and the call before the first): one line each time
    the finished share passes another 10%, the last at 100%; never two for one tenth."""
    out = io.StringIO()
    show = progress.tenths(out)
    for finished in range(total + 1):
        show(finished, total)
    lines = out.getvalue().splitlines()
    tenths_passed = {int(10 * f / total + 1e-9) for f in range(1, total + 1)} - {0}
    assert len(lines) == len(tenths_passed) <= 10
    assert lines[-1] == f"runs: 100% ({total}/{total})"
    shares = [int(line.split("%")[0].split()[-1]) for line in lines]
    assert shares == sorted(set(shares))


def test_sweep_writes_lines_not_redraws(monkeypatch, tmp_path):
    """Through :func:`progress.run_sweep` with a non-terminal stderr: 40 runs reported one
    by one give 10 lines, not 40 updates."""
    err = io.StringIO()
    monkeypatch.setattr(progress.sys, "stderr", err)

    def fake_sweep(jobs, out_dir, progress=None, **options):
        for k in range(41):
            progress(k, 40)

    monkeypatch.setattr(progress.sweep, "run_sweep", fake_sweep)
    progress.run_sweep([], tmp_path, run_timeout=60.0)
    lines = err.getvalue().splitlines()
    assert len(lines) == 10 and lines[0] == "runs: 10% (4/40)"

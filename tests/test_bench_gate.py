"""The runtime regression gate (benchmarks/bench/gate.py, conftest.py; docs/bench_gates.md).

The decision on synthetic timing samples (no clock involved): stored ratios recorded from
five noisy unchanged runs pass a sixth unchanged run and fail one whose step is 1.3 times
slower; a benchmark without a stored ratio fails outside the recording mode. Then the
plumbing, once, for real: a tiny benchmark (the harness's ``play`` loop) recorded in one
subprocess and gated in another with a 3x injected slowdown, which must fail it. No test
asserts a time of this machine: only that 3x stays above a tolerance of 1.5x.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent


def _load_gate():
    spec = importlib.util.spec_from_file_location("bench_gate", ROOT / "benchmarks/bench/gate.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


gate = _load_gate()


def synthetic_run(rng, true_ratio, noise, ref_s=3e-3, rounds=20, refs=40, slow=1.0):
    """One benchmark's timing samples: the reference's runs and the step's rounds, each
    ``lognormal(noise)`` around its true time, a run-wide factor ``exp(N(0, noise))``
    on the step alone (the load's uneven effect, which the reference does not cancel),
    and ``slow`` times slower steps."""
    ref = ref_s * np.exp(np.abs(rng.normal(0, noise, refs)))
    run_factor = math.exp(rng.normal(0, noise))
    step = slow * run_factor * true_ratio * ref_s * np.exp(np.abs(rng.normal(0, noise, rounds)))
    return step, ref


def test_ratio_is_fastest_round_over_fastest_reference():
    assert gate.ratio([3.0, 2.0, 5.0], [4.0, 1.0, 8.0]) == 2.0
    with pytest.raises(ValueError):
        gate.ratio([1.0], [0.0])


def test_spreads_tolerance_catches():
    assert gate.spreads([1.0, 1.1, 0.95, 1.0, 1.05]) == pytest.approx(
        (math.log(1.1), math.log(1 / 0.95)))
    assert gate.tolerance(0.0) == pytest.approx(gate.FLOOR)  # floored
    assert gate.tolerance(0.05, k=2.0, floor=1.0) == pytest.approx(math.exp(0.1))
    assert gate.tolerance(5.0) == gate.CAP
    assert gate.catches(1.2, math.log(1.05)) == pytest.approx(1.26)


@pytest.mark.parametrize("noise", [0.005, 0.02])
def test_unchanged_passes_and_slowed_by_1_3_fails(noise):
    """For noise well below the tolerance floor: five recorded unchanged runs, then five
    unchanged runs (all pass) and five 1.3x slower (all fail), on synthetic samples."""
    rng = np.random.default_rng(28)
    true_ratio = 0.8
    runs = [gate.ratio(*synthetic_run(rng, true_ratio, noise)) for _ in range(gate.RUNS)]
    entry = gate.entry_from_runs(runs, "test")
    assert entry.catches < 1.3
    for _ in range(5):
        unchanged = gate.ratio(*synthetic_run(rng, true_ratio, noise))
        slowed = gate.ratio(*synthetic_run(rng, true_ratio, noise, slow=1.3))
        assert gate.decide("b", unchanged, entry).ok
        v = gate.decide("b", slowed, entry)
        assert not v.ok and v.factor > entry.tol
        assert "tolerance" in v.message


def test_noisy_benchmark_gets_a_wider_tolerance():
    """Recorded runs up to 0.1 above their median (in ln) and 0.1 below: tolerance
    exp(0.2), and a 1.3x slowdown is no longer caught for sure (``catches`` says what
    is)."""
    entry = gate.entry_from_runs([1.0, 1.1052, 0.9048, 1.0, 1.02], "test")
    assert (entry.up, entry.down) == pytest.approx((0.1, 0.1), abs=1e-4)
    assert entry.tol == pytest.approx(math.exp(2 * 0.1), rel=1e-3)
    assert entry.catches == pytest.approx(math.exp(0.3), rel=1e-3)
    assert gate.decide("b", 1.2, entry).ok
    assert not gate.decide("b", 1.25, entry).ok


def test_no_stored_ratio_fails_except_when_recording():
    v = gate.decide("bench_x.py::test_y", 1.0, None)
    assert not v.ok and "no stored ratio" in v.message
    assert gate.decide("bench_x.py::test_y", 1.0, None, recording=True).ok
    entry = gate.entry_from_runs([1.0] * 5, "test")
    assert gate.decide("b", 5.0, entry, recording=True).ok  # recording never fails


def test_faster_passes():
    entry = gate.entry_from_runs([1.0] * 5, "test")
    assert gate.decide("b", 0.5, entry).ok


def test_ratios_file_round_trip(tmp_path):
    path = tmp_path / "ratios.toml"
    entries = {"bench_a.py::test_b[x-1]": gate.entry_from_runs([1.0, 1.02, 0.99, 1.01, 1.0],
                                                              "abc1234")}
    gate.dump({"timer": gate.GATE_TIMER, "recorded": {"cpu": "x", "cores": 2}}, entries, path)
    header, loaded = gate.load(path)
    assert header["timer"] == gate.GATE_TIMER and header["recorded"]["cores"] == 2
    (key, e), = loaded.items()
    assert key == "bench_a.py::test_b[x-1]" and e.moved_by == "abc1234"
    assert e.ratio == pytest.approx(1.0) and e.tol == pytest.approx(entries[key].tol, abs=1e-4)
    assert gate.load(tmp_path / "missing.toml") == ({}, {})


BENCH = "benchmarks/bench/bench_harness.py::test_play_loop"


def _bench_run(tmp_path, name, *extra):
    log = tmp_path / f"{name}.jsonl"
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:xdist",
           "-p", "no:hypothesispytest",
           BENCH, "--benchmark-only", f"--benchmark-timer={gate.GATE_TIMER}",
           f"--gate-log={log}", f"--ratios-file={tmp_path / 'ratios.toml'}", *extra]
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST_")}
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=env, timeout=120)
    rows = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    return proc, rows


def test_injected_slowdown_fails_a_real_benchmark(tmp_path):
    """The plumbing end to end: record the ratio of a real tiny benchmark (recording mode:
    passes without a stored ratio), store it with a tolerance of 1.5, then gate a run
    slowed 8 times (``--inject-slowdown 8``): it must fail and say by how much. How much
    is a timing of two runs seconds apart, so it is not asserted beyond what the gate's
    verdict means: above the stored ratio times its tolerance. The two runs drift apart
    under load: beside the suite's other xdist worker the recording's ratio was once 2.3
    times the later run's own (6.17 against 8.10 / 3 = 2.70, quiet 3.7-3.9), which hid a
    threefold slowdown; eight times leaves room for a drift up to 8 / 1.5 = 5.3."""
    proc, rows = _bench_run(tmp_path, "record", "--record-ratios")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    (row,) = rows
    assert row["inject"] == 1.0 and not row["gated"]
    entry = gate.Entry(row["ratio"], 1.5, 0.0, 0.0, (row["ratio"],), "test")
    gate.dump({}, {row["key"]: entry}, tmp_path / "ratios.toml")
    proc, rows = _bench_run(tmp_path, "slowed", "--inject-slowdown=8")
    assert proc.returncode == 1, proc.stdout[-2000:]
    (row,) = rows
    assert row["gated"] and not row["ok"] and row["inject"] == 8.0
    assert row["ratio"] > entry.ratio * entry.tol
    assert "times the stored" in proc.stdout


def test_re_recording_keeps_the_larger_spreads():
    """A benchmark re-recorded in a quiet minute keeps the spread its first recording
    measured over a loaded half hour; a new wider spread counts too."""
    first = gate.entry_from_runs([1.0, 1.2, 0.95, 1.0, 1.02], "first")
    quiet = gate.entry_from_runs([2.0, 2.01, 1.99, 2.0, 2.0], "moved", first)
    assert quiet.ratio == 2.0 and quiet.moved_by == "moved"
    assert (quiet.up, quiet.down) == (first.up, first.down) and quiet.tol == first.tol
    wide = gate.entry_from_runs([2.0, 3.0, 1.0, 2.0, 2.0], "moved", first)
    assert wide.up == pytest.approx(math.log(1.5)) and wide.down == pytest.approx(math.log(2))

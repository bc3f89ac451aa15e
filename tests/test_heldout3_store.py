"""Resume keeps the part of an unsupported run (its one row, at step -1, as the step loop
writes it): nothing is recomputed or rewritten, and the rows equal the first sweep's."""

from __future__ import annotations

import dataclasses

import pandas as pd
from test_result_store import _rows

from mttbench import scenarios
from mttbench.benchmarks.engine.loop import build_jobs
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.benchmarks.engine.sweep import run_sweep


def test_resume_keeps_an_unsupported_runs_part(tmp_path, capsys):
    sup = dataclasses.replace(scenarios.get("superposition"), n_steps=3)
    jobs = build_jobs([sup], [TrackerSpec("kfnn"), TrackerSpec("null")], None, None, [0])
    out = tmp_path / "out"
    fresh = run_sweep(jobs, out, store="parts")
    rows = pd.concat([pd.read_parquet(p) for p in sorted((out / "parts").glob("*.parquet"))])
    unsupported = rows[rows["status"] == "unsupported"]
    assert len(unsupported) == 1 and unsupported["step"].tolist() == [-1]
    before = {p: p.stat().st_mtime_ns for p in (out / "parts").glob("*.parquet")}
    capsys.readouterr()
    again = run_sweep(jobs, out, store="parts", resume=True)
    assert "damaged" not in capsys.readouterr().err
    assert {p: p.stat().st_mtime_ns for p in (out / "parts").glob("*.parquet")} == before
    pd.testing.assert_frame_equal(_rows(again), _rows(fresh), check_exact=True)

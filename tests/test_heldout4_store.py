"""The batched dataset's checks on resume, against batch files built by hand: which runs
of a file count as whole (the rule written out here from docs/result_store.md), a run
whose rows name another run, and a folder holding batches without its manifest."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from mttbench import scenarios
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.loop import build_jobs
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.benchmarks.engine.store import (
    RUN_KEY,
    SWEEP_MANIFEST,
    batch_frame,
    batch_name,
    check_batch,
)
from mttbench.benchmarks.engine.sweep import run_sweep

N = 3  # steps of every run here

#: a run's rows as (step, status) pairs; "e" an error row, "u" unsupported, else ok
RUNS = {
    "ok": [0, 1, 2],
    "ok-short": [0, 1],
    "ok-long": [0, 1, 2, 3],
    "ok-shifted": [1, 2, 3],
    "error-at-0": ["e0"],
    "error-at-1": [0, "e1"],
    "error-at-last": [0, 1, "e2"],
    "error-past-the-end": [0, 1, 2, "e3"],
    "error-after-a-gap": [0, "e2"],
    "error-before-the-first-step": ["e-1"],
    "unsupported": ["u-1"],
    "unsupported-at-0": ["u0"],
}


def _frame(spec: list) -> pd.DataFrame:
    steps, status = [], []
    for s in spec:
        if isinstance(s, str):
            steps.append(int(s[1:]))
            status.append({"e": "error", "u": "unsupported"}[s[0]])
        else:
            steps.append(s)
            status.append("ok")
    return pd.DataFrame({"step": np.array(steps, dtype=np.int64), "status": status})


def _whole(spec: list, n: int) -> bool:
    """docs/result_store.md's rule: steps 0..n-1 all ok; or the one row -1 unsupported (or
    an error before the first step); or steps 0..k-1 ok then the error row at k < n."""
    df = _frame(spec)
    steps, status = list(df["step"]), list(df["status"])
    if "error" not in status and "unsupported" not in status:
        return steps == list(range(n))
    if status == ["unsupported"]:
        return steps == [-1]
    k = steps[-1]
    return (status[-1] == "error" and steps == [*range(max(k, 0)), k] and k < n
            and all(s == "ok" for s in status[:-1]))


def _write(folder, runs: list[tuple[str, pd.DataFrame]]):
    name = batch_name([k for k, _ in runs])
    path = folder / f"batch-{name}.parquet"
    batch_frame(runs, name).to_parquet(path, index=False)
    return path


def test_a_batch_runs_count_as_whole_by_the_documented_rule(tmp_path):
    runs = [(key, _frame(spec)) for key, spec in RUNS.items()]
    path = _write(tmp_path, runs)
    good, listed, problem = check_batch(path, lambda key: N)
    want = [key for key, spec in RUNS.items() if _whole(spec, N)]
    assert want == ["ok", "error-at-0", "error-at-1", "error-at-last",
                    "error-before-the-first-step", "unsupported"]
    assert good == want
    assert listed == len(RUNS)
    assert problem.startswith("run ok-short: incomplete")


def test_a_run_whose_rows_name_another_run_is_not_whole(tmp_path):
    a, b = _frame([0, 1, 2]), _frame([0, 1, 2])
    name = batch_name(["a", "b"])
    df = batch_frame([("a", a), ("b", b)], name)
    df.loc[2, RUN_KEY] = "b"  # a's last row says it is b's
    path = tmp_path / f"batch-{name}.parquet"
    df.to_parquet(path, index=False)
    good, listed, problem = check_batch(path, lambda key: N)
    assert (good, listed) == (["b"], 2)
    assert problem == "run a: its rows name another run"


def test_a_folder_holding_dataset_batches_without_its_manifest_is_refused(tmp_path):
    """As for parts: batches without ``sweep.json`` (removed, or never written by a killed
    sweep) are another sweep's runs unless --resume; with --resume they are checked and
    kept."""
    import test_heldout4_sweep as h

    sc = dataclasses.replace(scenarios.get("default"), n_steps=N)
    jobs = build_jobs([sc], [TrackerSpec.parse("null")], None, None, [0, 1])
    for store in ("parts", "dataset"):
        out = tmp_path / store
        first = run_sweep(jobs, out, store=store, executor=h.InProcess())
        (out / SWEEP_MANIFEST).unlink()
        with pytest.raises(ConfigError, match="already holds the runs of a sweep"):
            run_sweep(jobs, out, store=store, executor=h.InProcess())
        ex = h.InProcess()
        again = run_sweep(jobs, out, store=store, executor=ex, resume=True)
        assert all(sizes == [] for _, sizes in ex.rounds)  # every run kept
        assert len(again) == len(first)

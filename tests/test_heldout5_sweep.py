"""The dataset sweep's batches and checkpoints, and a resume over batch files that hold
the same run twice.

Each rule is checked against the documented numbers (docs/result_store.md, the
docstrings of ``make_batches`` and ``run_batch``) or against the jobs' own keys, not
against another sweep's output.
"""

from __future__ import annotations

import json

import pandas as pd
import pyarrow.parquet as pq
import pytest
from test_result_store import _jobs  # the runs on default, cut short

from mttbench.benchmarks.engine.store import RUN_KEY, batch_frame, batch_name, read_batch_identity
from mttbench.benchmarks.engine.sweep import make_batches, run_batch, run_sweep


@pytest.mark.parametrize(("n_steps", "per_batch"), [
    (100, 500),      # 50,000 rows aimed at: 500 runs of 100 steps
    (20, 1000),      # 2,500 runs of 20 steps would fit: at most 1,000 runs per batch
    (80_000, 1),     # one run is more than 50,000 rows: one run per batch
])
def test_the_default_batch_is_about_fifty_thousand_rows_within_one_and_a_thousand_runs(
        tmp_path, n_steps, per_batch):
    """Without ``runs_per_batch`` a batch holds 50,000 // n_steps runs, at least 1 and at
    most 1,000 (the numbers written out, not read from the module): the jobs of one
    scenario and tracker are cut in order into batches of that size."""
    jobs = _jobs(("null",), n_steps=n_steps, seeds=range(per_batch + 1))
    keys = [job.key(None, 2.0) for job in jobs]
    batches = make_batches(jobs, keys, tmp_path)
    assert [len(b) for b, _ in batches] == [per_batch, 1]
    assert [k for b, _ in batches for k in b.keys] == keys


def test_each_checkpoint_holds_only_the_runs_finished_since_the_last_one(tmp_path):
    """With a checkpoint interval of 0 the task writes a checkpoint after every run but
    the last: each a batch file of exactly one run (its identity lists that run and its
    rows are that run's), and the whole batch lists them as the files it replaces."""
    jobs = _jobs(("null",), n_steps=2, seeds=range(4))
    keys = [job.key(None, 2.0) for job in jobs]
    (batch, path), = make_batches(jobs, keys, tmp_path, runs_per_batch=4, checkpoint_s=0.0)
    path.parent.mkdir(parents=True)
    frame = run_batch(batch)
    written = sorted(path.parent.glob("batch-*.parquet"))
    assert len(written) == 3
    listed = []
    for f in written:
        ident = read_batch_identity(f)
        assert len(ident["runs"]) == 1
        key = ident["runs"][0][0]
        listed.append(key)
        rows = pd.read_parquet(f)
        assert set(rows[RUN_KEY]) == {key}
        assert len(rows) == ident["runs"][0][1] == 2
    assert sorted(listed) == sorted(keys[:3])
    assert len(frame.attrs["mttbench.batch"]["replaces"]) == 3


def test_a_run_whole_in_two_batch_files_is_indexed_once_on_resume(tmp_path):
    """A killed dataset sweep can leave a run whole in two files (a checkpoint and the
    batch that replaced it, when the writer died between the two). On resume the run is
    kept from one file only: the manifest lists each run once, and the per-run table has
    one row per job."""
    jobs = _jobs(("null",), n_steps=2, seeds=range(3))
    out = tmp_path / "o"
    first = run_sweep(jobs, out, store="dataset", runs_per_batch=3)
    (batch_file,) = sorted((out / "dataset").rglob("batch-*.parquet"))
    # a second file holding the first run again, named by its key as a checkpoint is
    rows = pd.read_parquet(batch_file)
    key0 = rows[RUN_KEY].iloc[0]
    one = rows[rows[RUN_KEY] == key0].reset_index(drop=True)
    name = batch_name([key0])
    copy = batch_frame([(key0, one.drop(columns=[RUN_KEY]))], name)
    copy.to_parquet(batch_file.parent / f"batch-{name}.parquet", index=False)
    (out / "dataset" / "manifest.json").unlink()
    (out / "runs.parquet").unlink()
    again = run_sweep(jobs, out, store="dataset", runs_per_batch=3, resume=True)
    manifest = json.loads((out / "dataset" / "manifest.json").read_text())
    listed = [k for entry in manifest["files"] for k in entry["runs"]]
    assert sorted(listed) == sorted(job.key(None, 2.0) for job in jobs)
    assert len(again) == len(jobs) == len(first)
    assert pq.read_metadata(out / "runs.parquet").num_rows == len(jobs)

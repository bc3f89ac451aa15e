"""Rules of the result store (benchmarks/engine/store.py) on small real tables: the temp
files' names, the output folder's preparation, the folder lock's owner checks and its
refusal in a forked child, the manifest's shape, a part's and a batch's completeness,
mixed parameter types, partition names, checkpoint removal and the per-run table."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess

import numpy as np
import pandas as pd
import pytest

from mttbench.benchmarks.engine import store
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.loop import Job, run_job
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.scenarios import get as get_scenario


@pytest.fixture(scope="module")
def sc():
    return dataclasses.replace(get_scenario("single-clean"), n_steps=5)


def test_an_atomic_write_goes_through_a_temp_file_that_a_later_sweep_recognises(tmp_path):
    seen = []
    target = tmp_path / "results.parquet"
    store._write_atomic(target, lambda tmp: (seen.append(tmp.name), tmp.write_text("x")))
    assert seen == [f".results.parquet.{os.getpid()}.tmp"] and target.read_text() == "x"
    # the same name left by a writer that is gone is removed by the next sweep
    dead = _dead_pid()
    left = tmp_path / f".results.parquet.{dead}.tmp"
    left.write_text("half")
    assert store.remove_stale_temp_files(tmp_path) == [left] and not left.exists()


def _dead_pid() -> int:
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


def test_prepare_makes_parts_only_when_asked(tmp_path):
    store.prepare_out_dir(tmp_path / "a", parts=False)
    assert (tmp_path / "a").is_dir() and not (tmp_path / "a" / "parts").exists()
    store.prepare_out_dir(tmp_path / "b")
    assert (tmp_path / "b" / "parts").is_dir()
    (tmp_path / "f").write_text("")
    with pytest.raises(ConfigError, match="not a folder"):
        store.prepare_out_dir(tmp_path / "f")


def _lock_file(tmp_path, text: str) -> int:
    path = tmp_path / "lock"
    path.write_text(text)
    return os.open(path, os.O_RDWR)


def test_a_lock_owner_is_judged_gone_only_on_this_host(tmp_path):
    dead = _dead_pid()
    here = os.uname().nodename
    fd = _lock_file(tmp_path, f"{dead} {here} -\n")
    try:
        assert store._owner_gone(fd) == dead
    finally:
        os.close(fd)
    fd = _lock_file(tmp_path, f"{dead} not-{here} -\n")
    try:
        assert store._owner_gone(fd) is None  # another host's pid says nothing here
    finally:
        os.close(fd)
    fd = _lock_file(tmp_path, f"{os.getpid()} {here} -\n")
    try:
        assert store._owner_gone(fd) is None  # alive
    finally:
        os.close(fd)


def test_a_forked_child_does_not_share_its_parents_lock(tmp_path):
    with store.sweep_lock(tmp_path):
        pid = os.fork()
        if pid == 0:  # the child: another process, refused at once
            code = 3
            try:
                with store.sweep_lock(tmp_path):
                    code = 1
            except ConfigError:
                code = 0
            finally:
                os._exit(code)
        _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0


def test_a_manifest_without_its_job_list_is_refused(tmp_path):
    (tmp_path / store.SWEEP_MANIFEST).write_text(json.dumps({"format": 1, "c": None}))
    with pytest.raises(ConfigError, match="cannot read"):
        store.read_sweep_manifest(tmp_path)


@pytest.fixture(scope="module")
def crashed(sc):
    """A run that fails at step 3 (crashing_tracker.Crash): ok rows 0-2, the error at 3."""
    job = Job(sc, TrackerSpec("crashing_tracker:Crash"))
    return job, run_job(job)


def test_a_failed_part_fits_only_a_run_longer_than_its_error_step(crashed, tmp_path):
    job, rows = crashed
    assert rows["step"].tolist() == [0, 1, 2, 3] and rows["status"].iloc[-1] == "error"
    path = tmp_path / "k.parquet"
    store._write_part(rows, path)
    assert len(store._read_part(path, "k", 4)) == 4  # the error at step 3 of 4
    with pytest.raises(ValueError, match="incomplete"):
        store._read_part(path, "k", 3)  # a run of 3 steps has no step 3


def test_an_unsupported_run_is_its_one_row():
    steps, status = np.array([-1]), np.array(["unsupported"])
    assert store._rows_fit(steps, status, "unsupported", 5)
    assert not store._rows_fit(np.array([-1, 0]), np.array(["unsupported", "ok"]),
                               "unsupported", 5)


def test_a_parameter_of_two_value_types_becomes_text(sc):
    a = run_job(Job(sc, TrackerSpec("null"), seed=0)).assign(param_x=1)
    b = run_job(Job(sc, TrackerSpec("null"), seed=1)).assign(param_x="a")
    df = store._concat([a, b])
    assert set(df["param_x"]) == {"1", "a"}
    same = store._concat([a, a.assign(seed=1)])
    assert set(same["param_x"]) == {1}


@pytest.mark.parametrize("value, folder", [("..", "%2E."), (".", "%2E"), (".x", "%2Ex"),
                                           ("a/b", "a%2Fb"), ("x.y", "x.y")])
def test_a_partition_value_never_names_a_parent_or_nested_folder(value, folder):
    assert store._path_value(value) == folder


def test_a_batch_removes_the_checkpoints_it_replaces_but_never_itself(sc, tmp_path):
    rows = run_job(Job(sc, TrackerSpec("null")))
    name, other = "ab" * 12, "cd" * 12
    path = tmp_path / f"batch-{name}.parquet"
    (tmp_path / f"batch-{other}.parquet").write_text("checkpoint")
    store.write_batch(store.batch_frame([("k", rows)], name, replaces=[other, name]), path)
    assert path.is_file() and not (tmp_path / f"batch-{other}.parquet").exists()
    assert store.read_batch_identity(path)["runs"] == [("k", 5, "ok")]


def test_the_per_run_table_means_the_selection_time_and_drops_scores_of_failed_runs(crashed,
                                                                                    sc):
    _, failed = crashed
    ok = run_job(Job(sc, TrackerSpec("null"), seed=2))
    ok = ok.assign(select_wall_s=[1.0, 2.0, 6.0, 0.5, 0.5], ospa2=0.25)
    failed = failed.assign(ospa2=0.75)
    runs = store.runs_of(pd.concat([ok, failed], ignore_index=True)).set_index("tracker")
    assert runs.loc["null", "select_wall_s"] == 2.0  # (1 + 2 + 6 + 0.5 + 0.5) / 5
    assert runs.loc["null", "ospa2"] == 0.25
    assert runs.loc["crashing_tracker:Crash", "status"] == "error"
    assert np.isnan(runs.loc["crashing_tracker:Crash", "ospa2"])

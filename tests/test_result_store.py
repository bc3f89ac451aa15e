"""The batched result store: runs batched per worker task into a partitioned
Parquet dataset with a manifest, resume at run granularity, and the per-run table computed
file by file.

References are independent of the code under test: the per-run parts store's table (the
same jobs run one part each), the app's ``summary.per_run`` (a per-group Python loop)
against the store's vectorised ``runs_of``, and tampered files built by hand.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest

from mttbench import scenarios
from mttbench.benchmarks.app.summary import per_run, summarize
from mttbench.benchmarks.engine import sweep as sweep_module
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.loop import TIMING_COLUMNS, build_jobs
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.benchmarks.engine.store import (
    BATCH_META_KEY,
    DATASET_DIR,
    DATASET_MANIFEST,
    PART_META_KEY,
    RUN_KEY,
    RUNS_FILE,
    _write_part,
    check_batch,
    dataset_runs,
    load_results,
    load_runs,
    read_batch_identity,
    runs_of,
)
from mttbench.benchmarks.engine.sweep import run_sweep

N_STEPS = 6
TIMES = [*TIMING_COLUMNS, "peak_rss_mb"]
RUN_TIMES = ["tracker_wall_s", "tracker_wall_p95_s", "tracker_wall_max_s", "tracker_cpu_s",
             "select_wall_s", "peak_rss_mb"]


def _jobs(trackers=("null", "kfnn"), seeds=range(5), n_steps=N_STEPS):
    """The runs of ``trackers`` x ``seeds`` on ``default`` cut to ``n_steps``."""
    sc = dataclasses.replace(scenarios.get("default"), n_steps=n_steps)
    return build_jobs([sc], [TrackerSpec.parse(t) for t in trackers], None, None, list(seeds))


def _rows(df: pd.DataFrame) -> pd.DataFrame:
    return df.drop(columns=TIMES).reset_index(drop=True)


def _runs(df: pd.DataFrame) -> pd.DataFrame:
    return df.drop(columns=RUN_TIMES).reset_index(drop=True)


def _batches(out: Path) -> list[Path]:
    return sorted((out / DATASET_DIR).rglob("batch-*.parquet"))


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The same jobs with one part per run (the parts store): rows and per-run."""
    out = tmp_path_factory.mktemp("parts") / "out"
    rows = run_sweep(_jobs(), out, workers=2, store="parts")
    return _rows(rows), per_run(rows)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("dataset") / "out"
    runs = run_sweep(_jobs(), out, workers=2, store="dataset", runs_per_batch=2)
    return out, runs


def test_dataset_rows_equal_the_parts_rows(reference, dataset):
    out, _ = dataset
    pd.testing.assert_frame_equal(_rows(load_results(out)), reference[0], check_exact=True)
    assert not (out / "parts").exists() and not (out / "results.parquet").exists()


def test_batches_partitioned_with_identity_and_manifest(dataset):
    out, _ = dataset
    files = _batches(out)
    # 5 runs per tracker in batches of 2: 3 files per tracker, one folder per partition
    assert len(files) == 6
    assert {f.parent.relative_to(out / DATASET_DIR).as_posix() for f in files} == {
        "scenario=default/tracker=null", "scenario=default/tracker=kfnn"}
    listed = json.loads((out / DATASET_DIR / DATASET_MANIFEST).read_text())["files"]
    assert sorted(e["path"] for e in listed) == sorted(
        f.relative_to(out / DATASET_DIR).as_posix() for f in files)
    keys = set()
    for f in files:
        ident = read_batch_identity(f)
        table = pd.read_parquet(f)
        # the identity lists each run with its rows, in file order
        assert [k for k, _, _ in ident["runs"]] == list(dict.fromkeys(table[RUN_KEY]))
        assert [n for _, n, _ in ident["runs"]] == list(
            table.groupby(RUN_KEY, sort=False).size())
        keys |= set(table[RUN_KEY])
    manifest = json.loads((out / "sweep.json").read_text())
    assert manifest["store"] == "dataset" and sorted(keys) == manifest["jobs"]


def test_per_run_table_equals_the_summary_loop(reference, dataset):
    out, runs = dataset
    ref = reference[1]
    assert list(runs.columns) == list(ref.columns)
    pd.testing.assert_frame_equal(_runs(runs), _runs(ref), check_exact=False, rtol=1e-12)
    pd.testing.assert_frame_equal(load_runs(out), runs)
    # the timing statistics too, against the loop on the dataset's own rows
    rows = load_results(out)
    pd.testing.assert_frame_equal(runs_of(rows), per_run(rows), check_exact=False,
                                  rtol=1e-12)
    # and the summary the command line writes from it
    pd.testing.assert_frame_equal(summarize(runs).drop(columns=[]),
                                  summarize(per_run(rows)), check_exact=False, rtol=1e-12)


def test_runs_of_error_and_unsupported_runs(tmp_path):
    """A run that fails part-way and one the tracker cannot run: status, error, n_steps
    and NaN means as the loop has them (the reference)."""
    sc = dataclasses.replace(scenarios.get("default"), n_steps=N_STEPS)
    sup = dataclasses.replace(scenarios.get("superposition"), n_steps=N_STEPS)
    jobs = build_jobs([sc, sup], [TrackerSpec.parse("crashing_tracker:Crash"),
                                  TrackerSpec("kfnn")], None, None, [0, 1])
    runs = run_sweep(jobs, tmp_path / "d", store="dataset")
    rows = load_results(tmp_path / "d")
    assert set(runs["status"]) == {"error", "unsupported", "ok"}
    pd.testing.assert_frame_equal(runs, per_run(rows), check_exact=False, rtol=1e-12)


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    (dst / DATASET_DIR / DATASET_MANIFEST).unlink()  # as an interrupted sweep leaves it
    (dst / RUNS_FILE).unlink()
    return dst


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _drop_last_rows(path: Path) -> None:
    """Rewrite the batch without its last two rows, identity kept (a partial batch)."""
    df = pd.read_parquet(path)
    attrs = df.attrs
    df = df.iloc[:-2]
    df.attrs = attrs
    df.to_parquet(path, index=False)


def _cut_run_consistently(path: Path) -> None:
    """Cut the first run to 2 rows and make the identity agree: only the row check (its
    steps against the scenario's) can tell."""
    df = pd.read_parquet(path)
    ident = df.attrs[BATCH_META_KEY]
    first = ident["runs"][0][0]
    keep = (df[RUN_KEY] != first) | (df["step"] < 2)
    ident["runs"][0][1] = 2
    df = df[keep].reset_index(drop=True)
    df.attrs = {BATCH_META_KEY: ident}
    df.to_parquet(path, index=False)


def _swap(path: Path) -> None:
    """Replace the batch by a copy of another batch (of the other tracker)."""
    other = next(p for p in _batches(path.parents[3]) if p.parent != path.parent)
    shutil.copyfile(other, path)


@pytest.mark.parametrize("tamper, recomputed", [
    (_truncate, 2), (_drop_last_rows, 2), (_cut_run_consistently, 1), (_swap, 2),
    (Path.unlink, 2)], ids=["torn", "partial", "short-run", "swapped", "missing"])
def test_resume_recomputes_only_the_runs_not_whole(tmp_path, reference, dataset, capsys,
                                                   tamper, recomputed):
    out = _copy(dataset[0], tmp_path / "out")
    target = next(p for p in _batches(out) if len(read_batch_identity(p)["runs"]) == 2)
    tamper(target)
    before = {p: p.stat().st_mtime_ns for p in _batches(out)}
    with pytest.raises(ConfigError, match="finish it with --resume"):
        run_sweep(_jobs(), out, store="dataset", runs_per_batch=2)
    capsys.readouterr()
    runs = run_sweep(_jobs(), out, store="dataset", runs_per_batch=2, resume=True)
    err = capsys.readouterr().err
    assert ("damaged batch file" in err) == (tamper is not Path.unlink)
    # the other batches were not rewritten; the runs not whole went to new files (the
    # same name when the same runs are batched again)
    assert all(p.stat().st_mtime_ns == t for p, t in before.items() if p != target)
    new = [p for p in _batches(out) if before.get(p) != p.stat().st_mtime_ns]
    assert sum(len(read_batch_identity(p)["runs"]) for p in new) == recomputed
    pd.testing.assert_frame_equal(_rows(load_results(out)), reference[0], check_exact=True)
    pd.testing.assert_frame_equal(_runs(runs), _runs(reference[1]), check_exact=False,
                                  rtol=1e-12)


def test_foreign_batch_is_ignored(tmp_path, reference, dataset):
    """A batch of another sweep (other seeds) dropped into the dataset: none of its runs
    is this sweep's, so it neither counts nor is reported."""
    other = tmp_path / "other"
    run_sweep(_jobs(seeds=[7, 8]), other, store="dataset")
    out = _copy(dataset[0], tmp_path / "out")
    foreign = _batches(other)[0]
    shutil.copyfile(foreign, out / DATASET_DIR / foreign.relative_to(other / DATASET_DIR))
    good, listed, problem = check_batch(
        _batches(other)[0], lambda key: None)
    assert good == [] and listed == 2 and problem == ""
    runs = run_sweep(_jobs(), out, store="dataset", runs_per_batch=2, resume=True)
    pd.testing.assert_frame_equal(_rows(load_results(out)), reference[0], check_exact=True)
    assert len(runs) == len(reference[1])


def test_a_lost_batch_goes_again_one_run_per_task(tmp_path, monkeypatch):
    """A run that kills its worker loses its whole batch: the executor runs it again (the
    local pool: alone, so a run that killed it once is then ok and the batch is whole);
    a batch lost for good goes again one run per task, so a run that kills every time
    gets its own error row (not stored: --resume runs it again) and the others stay."""
    import test_executors as te

    monkeypatch.setenv(te.KILL_DIR_ENV, str(tmp_path))
    monkeypatch.setenv(te.KILL_SPARE_ENV, str(os.getpid()))
    sc = dataclasses.replace(scenarios.get("default"), n_steps=N_STEPS)
    jobs = build_jobs([sc], [TrackerSpec.parse("test_executors:KillOnce"),
                             TrackerSpec.parse("test_executors:KillAlways")],
                      None, None, [0, 1, 2])
    runs = run_sweep(jobs, tmp_path / "o", store="dataset", runs_per_batch=3,
                     executor=sweep_module.LocalExecutor(1, retries=0))
    once = runs[runs["tracker"].str.endswith("KillOnce")]
    always = runs[runs["tracker"].str.endswith("KillAlways")]
    assert list(once["status"]) == ["ok"] * 3
    assert list(always["status"]) == ["error"] * 3
    assert always["error"].str.contains("worker failed").all()
    # stored: KillOnce's batch whole, after its worker's one death; KillAlways's nothing
    files = _batches(tmp_path / "o")
    assert len(files) == 1 and len(read_batch_identity(files[0])["runs"]) == 3
    assert len(list(tmp_path.glob("KillAlways.*"))) >= 1 + 3  # the batch, then each run


def test_store_is_chosen_by_the_environment_and_kept_on_resume(tmp_path, monkeypatch):
    monkeypatch.setenv(sweep_module.STORE_ENV, "dataset")
    run_sweep(_jobs(seeds=[0, 1]), tmp_path / "big")
    assert _batches(tmp_path / "big") and not (tmp_path / "big" / "parts").exists()
    run_sweep(_jobs(seeds=[0, 1]), tmp_path / "tune", extend=True, resume=True)
    assert (tmp_path / "tune" / "results.parquet").is_file()  # tune's sweeps keep parts
    monkeypatch.delenv(sweep_module.STORE_ENV)
    run_sweep(_jobs(trackers=("null",), seeds=[0, 1]), tmp_path / "small")
    assert (tmp_path / "small" / "results.parquet").is_file()
    # resumed without a choice: the manifest's layout is kept
    run_sweep(_jobs(seeds=[0, 1]), tmp_path / "big", resume=True)
    assert not (tmp_path / "big" / "results.parquet").exists()
    with pytest.raises(ConfigError, match="another sweep"):
        run_sweep(_jobs(seeds=[0, 1]), tmp_path / "big", resume=True, store="parts")
    monkeypatch.setenv(sweep_module.STORE_ENV, "rows")
    with pytest.raises(ConfigError, match="store 'rows'"):
        run_sweep(_jobs(seeds=[0, 1]), tmp_path / "x")


def test_streaming_runs_read_one_file_at_a_time(dataset, monkeypatch):
    """dataset_runs reads each batch with only the columns it needs."""
    out, runs = dataset
    seen = []
    real = pd.read_parquet

    def spy(path, columns=None, **kw):
        seen.append((Path(path), columns))
        return real(path, columns=columns, **kw)

    monkeypatch.setattr(pd, "read_parquet", spy)
    again = dataset_runs(out)
    pd.testing.assert_frame_equal(again, runs)
    assert sorted(p for p, _ in seen) == _batches(out)
    assert all(cols is not None and "ospa_loc" in cols and "tracker_params" not in cols
               for _, cols in seen)
    assert all(pq.read_metadata(p).num_rows <= 2 * N_STEPS for p in _batches(out))


def test_dataset_on_dask_equals_the_local_pool(tmp_path, dataset):
    """The batches on a 2-worker Dask LocalCluster (their Parquet bytes come back to the
    client, which writes them): the same files, runs and rows as the local pool's."""
    pytest.importorskip("distributed")
    from mttbench.benchmarks.engine.executors import DaskExecutor

    with DaskExecutor(workers=2) as executor:
        runs = run_sweep(_jobs(), tmp_path / "dask", store="dataset", runs_per_batch=2,
                         executor=executor)
    local = dataset[0]
    assert [p.relative_to(tmp_path / "dask") for p in _batches(tmp_path / "dask")] == [
        p.relative_to(local) for p in _batches(local)]
    pd.testing.assert_frame_equal(_rows(load_results(tmp_path / "dask")),
                                  _rows(load_results(local)), check_exact=True)
    pd.testing.assert_frame_equal(_runs(runs), _runs(dataset[1]), check_exact=True)


def test_the_command_line_writes_a_dataset_and_resumes_it(tmp_path, capsys):
    """``mttbench run --store dataset``: batch files by scenario and tracker, runs.parquet,
    the same per-run table as the default layout; ``--resume`` of the finished folder runs
    nothing again and keeps the table."""
    from mttbench.benchmarks.app.cli import main

    args = ["run", "--scenarios", "default", "--trackers", "null", "kfnn", "--seeds", "3",
            "--steps", "4", "--workers", "1", "--no-progress"]
    assert main([*args, "--store", "dataset", "--out", str(tmp_path / "d")]) == 0
    assert main([*args, "--out", str(tmp_path / "p")]) == 0
    assert "dataset/ (the rows" in capsys.readouterr().out
    files = sorted((tmp_path / "d" / "dataset").rglob("*.parquet"))
    assert {f.parent.name for f in files} == {"tracker=null", "tracker=kfnn"}
    rows = load_results(tmp_path / "d").sort_values(["tracker", "seed", "step"])
    want = pd.read_parquet(tmp_path / "p" / "results.parquet").sort_values(
        ["tracker", "seed", "step"])
    pd.testing.assert_series_equal(rows["ospa"].reset_index(drop=True),
                                   want["ospa"].reset_index(drop=True))
    before = {f: f.stat().st_mtime_ns for f in files}
    assert main([*args, "--store", "dataset", "--resume", "--out", str(tmp_path / "d")]) == 0
    assert {f: f.stat().st_mtime_ns for f in files} == before


def test_a_run_held_whole_by_two_batch_files_comes_back_once(tmp_path, reference, dataset):
    """A run in two whole batch files (a checkpoint left beside its batch by a sweep killed
    between the two writes): resume runs nothing again and the run's rows come back once."""
    from mttbench.benchmarks.engine.store import batch_frame, batch_name

    out = _copy(dataset[0], tmp_path / "out")
    target = next(p for p in _batches(out) if len(read_batch_identity(p)["runs"]) == 2)
    df = pd.read_parquet(target)
    key = read_batch_identity(target)["runs"][0][0]
    rows = df[df[RUN_KEY] == key].drop(columns=[RUN_KEY]).reset_index(drop=True)
    name = batch_name([key])
    batch_frame([(key, rows)], name).to_parquet(target.parent / f"batch-{name}.parquet",
                                                index=False)
    before = {p: p.stat().st_mtime_ns for p in _batches(out)}
    runs = run_sweep(_jobs(), out, store="dataset", runs_per_batch=2, resume=True)
    assert {p: p.stat().st_mtime_ns for p in _batches(out)} == before  # nothing ran
    pd.testing.assert_frame_equal(_rows(load_results(out)), reference[0], check_exact=True)
    pd.testing.assert_frame_equal(_runs(runs), _runs(reference[1]), check_exact=False,
                                  rtol=1e-12)


# ------------------------------------------------- the parts store: a part's own checks
def _part_claims_a_row_more(path: Path) -> None:
    """The identity says one row more than the file holds (rows, steps, status intact)."""
    df = pd.read_parquet(path)
    df.attrs[PART_META_KEY]["rows"] += 1
    df.to_parquet(path, index=False)


def _part_steps_shifted(path: Path) -> None:
    """Steps 1..n instead of 0..n-1, the identity rewritten to agree (rows and status)."""
    df = pd.read_parquet(path)
    df["step"] += 1
    _write_part(df, path)


@pytest.mark.parametrize("tamper", [_part_claims_a_row_more, _part_steps_shifted],
                         ids=["rows-disagree", "steps-shifted"])
def test_resume_recomputes_a_part_whose_rows_are_not_its_runs(tmp_path, capsys, tamper):
    """A part file is kept on resume only if its identity's row count is its row count and
    its steps are 0..n-1 (an ok run); else it is recomputed. Reference: the fresh sweep's
    rows, and the part's identity as a fresh write gives it."""
    jobs = _jobs(trackers=("null",), seeds=range(2))
    out = tmp_path / "out"
    fresh = _rows(run_sweep(jobs, out, store="parts"))
    target = sorted((out / "parts").glob("*.parquet"))[0]
    identity = pd.read_parquet(target).attrs[PART_META_KEY]
    tamper(target)
    capsys.readouterr()
    again = run_sweep(jobs, out, store="parts", resume=True)
    assert "1 damaged part file(s) will be recomputed" in capsys.readouterr().err
    assert pd.read_parquet(target).attrs[PART_META_KEY] == identity
    pd.testing.assert_frame_equal(_rows(again), fresh, check_exact=True)


def test_an_extended_sweeps_manifest_gathers_every_batchs_jobs(tmp_path):
    """tune's sweeps grow batch by batch (``extend``): the folder's manifest lists the
    union of the jobs of every batch, each once (reference: the jobs' own keys)."""
    from mttbench.benchmarks.engine.store import read_sweep_manifest

    first, second = _jobs(("null",), seeds=[0, 1]), _jobs(("null",), seeds=[1, 2])
    out = tmp_path / "tune"
    for jobs in (first, second):
        run_sweep(jobs, out, extend=True, resume=True)
    want = sorted({job.key(None, 2.0) for job in [*first, *second]})
    assert len(want) == 3
    assert read_sweep_manifest(out)["jobs"] == want
    assert sorted(p.stem for p in (out / "parts").glob("*.parquet")) == want

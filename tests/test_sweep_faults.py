"""A sweep that cannot be fooled or frozen, in-process through the command line.

Resume checks every part's identity (its job key, row count and status in the Parquet
metadata): a part swapped with another run's, or cut short, is reported in one line and
recomputed, and the tables equal an uninterrupted run's. A folder is one sweep's
(``sweep.json``) and one process's at a time (its lock). A tracker that hangs, exits,
kills its process or reports a non-finite or negative estimate gets an error row; the
other runs are kept and the exit status is 1, at one worker and at two.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

import pandas as pd
import pytest

from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.engine.store import LOCK_FILE, SWEEP_MANIFEST

SMALL = ["--seeds", "2", "--steps", "3", "--no-progress", "--retries", "0"]
TIMING = ["tracker_wall_s", "tracker_cpu_s", "select_wall_s", "select_cpu_s", "peak_rss_mb"]


def sweep(out: Path, *trackers: str, workers: int = 1, extra: tuple[str, ...] = ()) -> int:
    return main(["run", "--scenarios", "default", "--trackers", *trackers, *SMALL,
                 "--workers", str(workers), "--out", str(out), *extra])


def table(out: Path) -> pd.DataFrame:
    return pd.read_parquet(out / "results.parquet").drop(columns=TIMING)


def err_lines(capsys) -> list[str]:
    return [x for x in capsys.readouterr().err.splitlines() if x.strip()]


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> pd.DataFrame:
    """An uninterrupted sweep's table."""
    out = tmp_path_factory.mktemp("reference") / "out"
    assert sweep(out, "null", "kfnn") == 0
    return table(out)


def _parts_by_seed(out: Path, tracker: str) -> dict[int, Path]:
    found = {}
    for part in (out / "parts").glob("*.parquet"):
        df = pd.read_parquet(part)
        if df["tracker_label"].iloc[0] == tracker:
            found[int(df["seed"].iloc[0])] = part
    return found


def _swap(part: Path, other: Path) -> None:
    part.write_bytes(other.read_bytes())  # another run's part under this run's name


def _cut_keeping_identity(part: Path, other: Path) -> None:
    df = pd.read_parquet(part)  # its attrs (the identity) come along
    df.head(1).to_parquet(part, index=False)


def _cut_without_identity(part: Path, other: Path) -> None:
    df = pd.read_parquet(part)
    df.attrs = {}
    df.head(1).to_parquet(part, index=False)


def _rows_of_another_tracker(part: Path, other: Path) -> None:
    df = pd.read_parquet(other)  # the other's identity, rewritten with this run's rows
    rows = pd.read_parquet(part)
    rows.attrs = df.attrs
    rows.to_parquet(part, index=False)


@pytest.mark.parametrize("tamper, says", [
    (_swap, "another run"),
    (_cut_keeping_identity, "incomplete"),
    (_cut_without_identity, "no job identity"),
    (_rows_of_another_tracker, "another run"),
], ids=["swapped-part", "short-part", "short-part-without-identity", "foreign-identity"])
def test_resume_recomputes_a_part_that_is_not_its_jobs(tmp_path, capsys, reference, tamper,
                                                         says):
    out = tmp_path / "out"
    assert sweep(out, "null", "kfnn") == 0
    kfnn = _parts_by_seed(out, "kfnn")
    tamper(kfnn[1], _parts_by_seed(out, "null")[0] if tamper is _rows_of_another_tracker
           else kfnn[0])
    capsys.readouterr()
    assert sweep(out, "null", "kfnn", extra=("--resume",)) == 0
    err = err_lines(capsys)
    reported = [x for x in err if "will be recomputed" in x]
    assert len(reported) == 1 and says in reported[0] and kfnn[1].name in reported[0], err
    assert "Traceback" not in "\n".join(err)
    pd.testing.assert_frame_equal(table(out), reference)


def test_a_folder_of_another_sweep_is_refused(tmp_path, capsys):
    out = tmp_path / "out"
    assert sweep(out, "null") == 0
    before = snapshot(out)
    capsys.readouterr()
    for extra in ((), ("--resume",)):
        assert sweep(out, "kfnn", extra=extra) == 2
        err = err_lines(capsys)
        assert len(err) == 1 and "another sweep" in err[0] and "--resume" in err[0] \
            and "--out" in err[0], err
    assert snapshot(out) == before
    assert (out / SWEEP_MANIFEST).is_file()


def test_the_same_sweep_twice_needs_resume(tmp_path, capsys, reference):
    out = tmp_path / "out"
    assert sweep(out, "null", "kfnn") == 0
    before = snapshot(out)
    capsys.readouterr()
    assert sweep(out, "null", "kfnn") == 2
    err = err_lines(capsys)
    assert len(err) == 1 and "already holds this sweep" in err[0] and "--resume" in err[0], err
    assert snapshot(out) == before
    assert sweep(out, "null", "kfnn", extra=("--resume",)) == 0  # runs nothing again
    pd.testing.assert_frame_equal(table(out), reference)


def test_a_folder_in_use_by_another_process_is_refused(tmp_path, capsys):
    out = tmp_path / "out"
    assert sweep(out, "null") == 0
    capsys.readouterr()
    fd = os.open(out / LOCK_FILE, os.O_RDWR)  # another open file: flock conflicts with it
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert sweep(out, "null", extra=("--resume",)) == 2
    finally:
        os.close(fd)
    err = err_lines(capsys)
    assert len(err) == 1 and "in use by another mttbench process" in err[0], err
    assert sweep(out, "null", extra=("--resume",)) == 0  # released


FAULTS = [
    ("faulty_tracker:Hang", "timed out"),
    ("faulty_tracker:Exit", "SystemExit"),
    ("faulty_tracker:Kill", "worker failed"),
    ("faulty_tracker:NanCount", "count nan"),
    ("faulty_tracker:NegativeCount", "count -1.0"),
    ("faulty_tracker:NanState", "states are not all finite"),
    ("faulty_tracker:Interrupt", "KeyboardInterrupt"),
]


#: every fault at one worker; at two only those that end the run's worker process (a hang
#: killed past its limit, a kill): the pool's recovery then differs with a second worker
#: running beside it, while the others end inside the run, the same at any number
FAULT_CASES = [(t, says, 1) for t, says in FAULTS] + [
    (t, says, 2) for t, says in FAULTS if t.endswith((":Hang", ":Kill"))]


@pytest.mark.parametrize("tracker, says, workers", FAULT_CASES,
                         ids=[f"{t.split(':')[1]}-workers-{w}" for t, _, w in FAULT_CASES])
def test_a_faulty_tracker_gets_an_error_row_and_the_sweep_goes_on(tmp_path, capsys, tracker,
                                                                   says, workers):
    out = tmp_path / "out"
    rc = sweep(out, "null", tracker, workers=workers, extra=("--run-timeout", "1.5"))
    err = err_lines(capsys)
    assert rc == 1, err
    assert "Traceback" not in "\n".join(err)
    assert err[-1].startswith("2 of 4 runs failed; first error: ") and says in err[-1], err
    df = pd.read_parquet(out / "results.parquet")
    null = df[df["tracker_label"] == "null"]
    assert len(null) == 6 and (null["status"] == "ok").all()  # 2 seeds x 3 steps, kept
    bad = df[df["tracker_label"] == tracker]
    errors = bad[bad["status"] == "error"]
    assert sorted(errors["seed"]) == [0, 1]
    assert errors["error"].str.contains(says, regex=False).all(), list(errors["error"])


BAD_COUNTS = [
    ("faulty_tracker:CountsUnnormalised", "have a row summing to 2, not 1"),
    ("faulty_tracker:CountsNan", "are not all finite"),
    ("faulty_tracker:CountsNegative", "have a negative entry (-0.5)"),
    ("faulty_tracker:CountsShape", "are (143, 2), not (n_cells = 144, n_counts >= 2)"),
]


@pytest.mark.parametrize("tracker, says", BAD_COUNTS, ids=[t.split(":")[1] for t, _ in BAD_COUNTS])
def test_malformed_predicted_counts_under_renyi_are_an_error_row(tmp_path, capsys, tracker,
                                                                 says):
    out = tmp_path / "out"
    rc = sweep(out, "null", tracker, extra=("--policy", "renyi"))
    err = err_lines(capsys)
    assert rc == 1, err
    df = pd.read_parquet(out / "results.parquet")
    assert (df[df["tracker_label"] == "null"]["status"] == "ok").all()
    bad = df[df["tracker_label"] == tracker]
    errors = bad[bad["status"] == "error"]
    assert sorted(errors["seed"]) == [0, 1] and (errors["step"] == 1).all()
    assert errors["error"].str.contains("predicted cell counts P_c(t) " + says,
                                        regex=False).all(), list(errors["error"])

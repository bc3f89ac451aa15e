"""The store's choices and checks that a user relies on without seeing them: the layout an
``extend`` sweep takes whatever ``MTTBENCH_STORE`` says, a resume refused under another
OSPA order, a batch file with more rows than its identity lists, and a lock whose
recorded holder is gone (reaped, its pid no longer in use).

References: the rules written in ``resolve_store``'s and ``check_sweep``'s docstrings and
docs/result_store.md, applied by hand to each case."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys

import pandas as pd
import pytest

from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.store import (
    LOCK_FILE,
    STORE_ENV,
    batch_frame,
    batch_name,
    check_sweep,
    read_batch_identity,
    resolve_store,
    sweep_lock,
    write_sweep_manifest,
)


@pytest.mark.parametrize(("env", "store", "extend", "want"), [
    ("dataset", None, False, "dataset"),   # the environment chooses ...
    ("dataset", None, True, "parts"),      # ... but an extend sweep (tune's) stays parts
    ("dataset", "parts", False, "parts"),  # the caller's choice wins
    ("parts", "dataset", True, "dataset"),
    ("", None, True, "parts"),
])
def test_the_layout_follows_the_caller_then_the_environment_but_extend_stays_parts(
        tmp_path, monkeypatch, env, store, extend, want):
    monkeypatch.setenv(STORE_ENV, env)
    assert resolve_store(tmp_path, store, extend) == want


@pytest.mark.parametrize("change", ["p", "c", "extend"])
def test_a_folder_is_resumed_only_with_its_own_c_p_and_kind(tmp_path, change):
    """The manifest written by a sweep with c = 2, p = 2; resuming it with another p, c
    or kind is refused in one line; with its own it is accepted."""
    keys = ["a", "b"]
    write_sweep_manifest(tmp_path, check_sweep(tmp_path, keys, 2.0, 2.0, resume=False))
    assert check_sweep(tmp_path, keys, 2.0, 2.0, resume=True)["jobs"] == keys
    c, p, extend = {"p": (2.0, 1.0, False), "c": (3.0, 2.0, False),
                    "extend": (2.0, 2.0, True)}[change]
    with pytest.raises(ConfigError, match="holds another sweep"):
        check_sweep(tmp_path, keys, c, p, resume=True, extend=extend)


@pytest.mark.parametrize("extra", [-1, 1])
def test_a_batch_file_whose_rows_are_not_its_listed_runs_is_refused(tmp_path, extra):
    """A batch whose identity lists runs of 3 rows and 2 rows holds 5 rows; the same file
    with one row fewer (torn) or one more (not the batch it says) is refused, naming both
    counts."""
    runs = [("k1", pd.DataFrame({"step": [0, 1, 2], "status": ["ok"] * 3})),
            ("k2", pd.DataFrame({"step": [0, 1], "status": ["ok"] * 2}))]
    name = batch_name([k for k, _ in runs])
    frame = batch_frame(runs, name)
    path = tmp_path / f"batch-{name}.parquet"
    frame.to_parquet(path, index=False)
    assert [n for _, n, _ in read_batch_identity(path)["runs"]] == [3, 2]
    bad = frame.iloc[:-1] if extra < 0 else pd.concat([frame, frame.iloc[-1:]])
    bad = bad.reset_index(drop=True)
    bad.attrs = frame.attrs
    bad.to_parquet(path, index=False)
    with pytest.raises(ValueError, match=f"{5 + extra} rows, its identity lists 5"):
        read_batch_identity(path)


def _dead_pid() -> int:
    """The pid of a process that has ended and been reaped (no such process now)."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="flock semantics of Linux")
def test_a_lock_whose_recorded_holder_is_gone_is_taken_over(tmp_path, capsys):
    """The lock file is still locked (an open file of a leftover worker: here another open
    file of this process) but records a holder on this host whose pid no longer exists:
    the lock is stale, taken over with its one-line notice. The same file recording a
    live holder (this process) is respected."""
    out = tmp_path / "out"
    out.mkdir()
    path = out / LOCK_FILE
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        os.write(fd, f"{os.getpid()} {os.uname().nodename} -\n".encode())
        with pytest.raises(ConfigError, match="in use by another mttbench process"):
            with sweep_lock(out):
                pass
        dead = _dead_pid()
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{dead} {os.uname().nodename} -\n".encode(), 0)
        with sweep_lock(out):
            assert path.read_text().split()[0] == str(os.getpid())
        err = [x for x in capsys.readouterr().err.splitlines() if LOCK_FILE in x]
        assert len(err) == 1 and f"holder (pid {dead}) is gone" in err[0], err
    finally:
        os.close(fd)

"""The folder lock when its recorded holder is dead but not reaped (a zombie): the lock
file is still locked by a leftover child of the holder, and the holder's pid still
answers ``kill(pid, 0)``; ``/proc/<pid>/stat`` says it is a zombie, so the lock is stale
and is taken over with its one-line notice (as for a holder that is gone), whether or not
the lock file recorded the holder's start time (``-`` where ``/proc`` could not say)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_orphans import _LEAVE_AN_ORPHAN

from mttbench.benchmarks.engine.store import LOCK_FILE, sweep_lock

#: the orphan-leaving holder of test_orphans: its parent (this test) does not reap the
#: holder it starts, so the holder stays a zombie meanwhile
_HOLDER = _LEAVE_AN_ORPHAN


def _state(pid: int) -> str:
    text = Path(f"/proc/{pid}/stat").read_text()
    return text[text.rfind(")") + 2:].split()[0]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("recorded", ["start", "no-start"])
def test_a_lock_whose_holder_is_a_zombie_is_taken_over(tmp_path, capsys, recorded):
    out = tmp_path / "out"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", _HOLDER, str(out)],
                              stdout=subprocess.PIPE, text=True)
    orphan = int(holder.stdout.readline())
    try:
        deadline = time.monotonic() + 60
        while _state(holder.pid) != "Z":  # exited; not reaped: no wait() before the end
            assert time.monotonic() < deadline, "the holder did not exit"
            time.sleep(0.05)
        os.kill(holder.pid, 0)  # a zombie still answers: only its state tells
        pid, host, start = (out / LOCK_FILE).read_text().split()
        assert pid == str(holder.pid) and start != "-"
        if recorded == "no-start":
            (out / LOCK_FILE).write_text(f"{pid} {host} -\n")  # the file stays locked
        with sweep_lock(out):
            assert (out / LOCK_FILE).read_text().split()[0] == str(os.getpid())
        err = [x for x in capsys.readouterr().err.splitlines() if LOCK_FILE in x]
        assert len(err) == 1 and f"holder (pid {holder.pid}) is gone" in err[0], err
    finally:
        os.kill(orphan, signal.SIGKILL)
        holder.stdout.close()
        holder.wait()

"""Real signals to a real ``mttbench tune`` at chosen moments, then ``--resume``: exit 130
on Ctrl-C, and the resumed study's trials those of an uninterrupted one.

A driver process runs the command (``cli.main``) with one library call wrapped so that
its ``k``-th call (from a given caller) sends a signal to the process itself: while the
sampler draws a trial's parameters (between two parameters of a random trial; a TPE
trial asked beside a running one), inside a journal write (the line written, not yet
fsynced) and while the journal's lock is taken. One study is cut again and again: a
SIGKILL in a TPE draw (in a forked child, which it kills), then Ctrl-C at each point in
turn, each session resuming the last; then a plain ``--resume`` finishes it, and its
trials must be those of an uninterrupted study. The tracker (``crashing_tracker:Guess``)
costs nothing per run and its objective moves with each parameter, so trials differ.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from crashing_tracker import shell_like_signals

from mttbench.benchmarks.app.cli import EXIT_INTERRUPTED

TESTS = Path(__file__).resolve().parent
#: generous: the driver imports numpy, pandas, scipy, numba and optuna first
TIMEOUT_S = 300

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

DRIVER = r'''
import contextlib, fcntl, io, json, os, sys
import optuna
import pandas as pd
from mttbench.benchmarks.app import cli

#: where a signal can be sent: (module or class, function, the caller counted or None)
TARGETS = {
    "random-draw": (optuna.samplers.RandomSampler, "sample_independent", None),
    "tpe-draw": (optuna.samplers.TPESampler, "sample_relative", None),
    "journal-write": (os, "fsync", "append_logs"),
    "journal-lock": (fcntl, "flock", "acquire"),
}
ARGS = ["tune", "crashing_tracker:Guess", "--trials", "6", "--startup-trials", "2",
        "--batch-size", "2", "--tuning-seeds", "1", "--scenarios", "default", "--steps",
        "2", "--c", "1000", "--workers", "1", "--no-progress"]


def session(out, point=None, resume=False):
    """`mttbench tune ... --out out`, signalled at `point` = (target, k, signal)."""
    args = [*ARGS, "--out", out, "--tuned-dir", out + "-tuned", *(["--resume"] * resume)]
    owner = name = real = None
    calls = [0]
    if point:
        where, k, sig = point
        owner, name, caller = TARGETS[where]
        real = getattr(owner, name)

        def hooked(*a, **kw):
            if caller is None or sys._getframe(1).f_code.co_name == caller:
                calls[0] += 1
                if calls[0] == k:
                    os.kill(os.getpid(), sig)
            return real(*a, **kw)

        setattr(owner, name, hooked)
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            rc = cli.main(args)
    finally:
        if point:
            setattr(owner, name, real)
    trials = os.path.join(out, "crashing_tracker:Guess", "trials.csv")
    table = (pd.read_csv(trials, dtype=str, keep_default_na=False).values.tolist()
             if os.path.exists(trials) else None)
    return {"rc": rc, "err": err.getvalue(), "calls": calls[0], "trials": table}


report = []
for case in json.loads(sys.argv[1]):
    point = tuple(case["point"]) if case.get("point") else None
    if case.get("fork"):  # a session killed for good: in a child, whose end is reported
        pid = os.fork()
        if pid == 0:
            session(case["out"], point, case.get("resume", False))
            os._exit(0)
        _, status = os.waitpid(pid, 0)
        report.append({"signal": os.WTERMSIG(status) if os.WIFSIGNALED(status) else None})
        continue
    report.append(session(case["out"], point, case.get("resume", False)))
print(json.dumps(report))
'''


def _drive(cases: list[dict], tmp: Path) -> tuple[subprocess.CompletedProcess, dict]:
    path = os.pathsep.join(p for p in (str(TESTS), os.environ.get("PYTHONPATH", "")) if p)
    proc = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(cases)], cwd=tmp,
                          env={**os.environ, "PYTHONPATH": path}, capture_output=True,
                          text=True, timeout=TIMEOUT_S, preexec_fn=shell_like_signals)
    report = json.loads(proc.stdout) if proc.returncode == 0 else {}
    return proc, report


def _rows(table: list[list[str]]) -> list[list[str]]:
    """number, state, value and parameters (not the run-time columns)."""
    return [row[:3] + row[4:7] for row in table]


#: the sessions of the cut study, in turn: (target, k, signal), the signal sent at the k-th
#: call in that session
POINTS = [("random-draw", 5, signal.SIGKILL),  # trial 1's second parameter, beside trial 0
          ("journal-write", 3, signal.SIGINT), ("tpe-draw", 1, signal.SIGKILL),
          ("tpe-draw", 2, signal.SIGINT), ("journal-lock", 4, signal.SIGINT),
          ("journal-write", 5, signal.SIGINT)]


def test_ctrl_c_or_a_kill_at_any_moment_of_a_tune_resumes_to_the_same_trials(tmp_path):
    cases = [{"out": "cut", "point": [where, k, int(sig)], "resume": i > 0,
              "fork": sig == signal.SIGKILL} for i, (where, k, sig) in enumerate(POINTS)]
    cases += [{"out": "cut", "resume": True}, {"out": "whole"}]
    proc, report = _drive(cases, tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    *cut, finished, whole = report
    for (where, k, sig), case in zip(POINTS, cut, strict=True):
        if sig == signal.SIGKILL:
            assert case["signal"] == signal.SIGKILL, (where, k, case)
            continue
        lines = [x for x in case["err"].splitlines() if x.strip()]
        assert case["calls"] >= k, (where, k, "the point was not reached")
        assert case["rc"] == EXIT_INTERRUPTED, (where, k, case["err"])
        assert "Traceback" not in case["err"] and "interrupted" in lines[-1], (where, k, lines)
    assert finished["rc"] == 0 and whole["rc"] == 0, (finished["err"], whole["err"])
    expected = _rows(whole["trials"])
    assert len(expected) == 6 and len({r[2] for r in expected}) > 3  # the values differ
    assert _rows(finished["trials"]) == expected

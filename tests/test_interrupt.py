"""Ctrl-C on ``mttbench compare`` (a real SIGINT to a subprocess), then the printed resume
command: the same report, finished parts not recomputed.

The sweep includes ``crashing_tracker:Slow`` (reports nothing, sleeps 0.05 s per step),
whose runs wait at their first step until the test creates a gate file, which it does
only after the signal: so the interrupt lands mid-sweep however slow the machine (a
timing window alone once let a loaded CI machine finish the sweep first).
"""

from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
from crashing_tracker import SLOW_GATE_ENV, gate_env, shell_like_signals

from mttbench.benchmarks.app.cli import EXIT_INTERRUPTED, main

TESTS = Path(__file__).resolve().parent
#: --untuned: the defaults, as `run` below (which knows no tuned files) runs them
ARGS = ["compare", "--untuned", "--scenarios", "default", "--trackers", "null", "kfnn",
        "crashing_tracker:Slow", "--seeds", "4", "--steps", "20", "--workers", "2",
        "--no-progress"]
TIMING = ["tracker_wall_s", "tracker_cpu_s", "select_wall_s", "select_cpu_s", "peak_rss_mb"]
#: generous: the subprocess imports numpy, pandas, scipy and numba before its first run
START_TIMEOUT_S = 120
#: a safety net for the resume, which runs the rest of the sweep and draws the report:
#: it took over 120 s at load 18 on 2 cores (two CPU hogs and three test suites beside)
RESUME_TIMEOUT_S = 900


def _env() -> dict[str, str]:
    path = os.pathsep.join(p for p in (str(TESTS), os.environ.get("PYTHONPATH", "")) if p)
    return {**os.environ, "PYTHONPATH": path}


def _lines(text: str) -> list[str]:
    return [x for x in text.splitlines() if x.strip()]


def _results(folder: Path) -> pd.DataFrame:
    return pd.read_parquet(folder / "results.parquet").drop(columns=TIMING)


def test_ctrl_c_then_the_printed_command_finishes_the_same_report(monkeypatch, tmp_path,
                                                                  capsys):
    # ---- interrupt: no --out, so the folder is reports/compare-<timestamp> under cwd
    gate = tmp_path / "gate"  # the slow runs wait for it: the sweep cannot finish first
    proc = subprocess.Popen([sys.executable, "-m", "mttbench", *ARGS], cwd=tmp_path,
                            env={**_env(), **gate_env(gate)},
                            preexec_fn=shell_like_signals,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + START_TIMEOUT_S
    parts: list[Path] = []
    while not parts:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no part written"
        time.sleep(0.01)
        parts = list(tmp_path.glob("reports/compare-*/parts/*.parquet"))
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=START_TIMEOUT_S)  # a safety net for a loaded machine
    gate.touch()  # from here on the slow runs run (the resume and the whole sweep below)
    monkeypatch.setenv(SLOW_GATE_ENV, str(gate))
    assert proc.returncode == EXIT_INTERRUPTED, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    interrupted = [x for x in _lines(err) if "interrupted" in x]
    assert len(interrupted) == 1 and _lines(err)[-1] == interrupted[0], err
    (folder,) = tmp_path.glob("reports/compare-*")
    folder = folder.relative_to(tmp_path)  # as printed; cwd is tmp_path from here on
    monkeypatch.chdir(tmp_path)
    assert f"finished runs are kept in {folder}/parts" in interrupted[0]
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "interrupted" and len(manifest["sessions"]) == 1
    done = {p: p.stat().st_mtime_ns for p in (folder / "parts").glob("*.parquet")}
    assert 1 <= len(done) < 12, len(done)
    assert not list(folder.rglob("*.tmp"))

    # ---- the printed command, exactly
    command = interrupted[0].split("resume with: ", 1)[1]
    words = shlex.split(command)
    assert words[:3] == [sys.executable, "-m", "mttbench"]
    assert words[3:] == [*ARGS, "--out", str(folder), "--resume"]
    # run as printed, in its own process as a user would (not forked from this process,
    # whose other threads could hold a lock at the fork of a worker)
    again = subprocess.run(words, cwd=tmp_path, env={**_env(), **gate_env(gate)},
                           capture_output=True, text=True, timeout=RESUME_TIMEOUT_S)
    assert again.returncode == 0, again.stderr
    assert "Traceback" not in again.stderr
    assert {p: p.stat().st_mtime_ns for p in done} == done  # not recomputed
    assert len(list((folder / "parts").glob("*.parquet"))) == 12
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "finished"
    walls = [s["wall_time_s"] for s in manifest["sessions"]]
    assert [s["status"] for s in manifest["sessions"]] == ["interrupted", "finished"]
    assert all(w > 0 for w in walls) and abs(manifest["wall_time_s"] - sum(walls)) < 2e-3
    assert "over 2 sessions" in (folder / "report.md").read_text()
    assert f"({manifest['wall_time_s']:.0f} s over 2 sessions)" in again.stdout
    for name in ("results.parquet", "summary.csv", "summary.md", "report.md", "report.html",
                 "figures", "manifest.json"):
        assert (folder / name).exists(), name

    # ---- the same numbers as an uninterrupted sweep of the same runs (in-process: tests/
    # is on sys.path; `run` makes compare's jobs without drawing the report)
    whole = Path("whole")
    assert main(["run", *ARGS[2:], "--out", str(whole)]) == 0
    pd.testing.assert_frame_equal(_results(folder), _results(whole))


def test_compare_resume_without_out_picks_the_latest_unfinished(monkeypatch, tmp_path, capsys):
    """Three folders as a Ctrl-C and a finished compare leave them (built cheaply: the
    parts by ``run``, which makes the same jobs, and a manifest)."""
    monkeypatch.chdir(tmp_path)
    sweep = ["--scenarios", "default", "--trackers", "null", "--seeds", "2", "--steps", "2",
             "--workers", "1", "--no-progress"]
    reports = tmp_path / "reports"
    folders = {status: reports / f"compare-2000010{i}T000000Z"
               for i, status in enumerate(("interrupted", "running", "finished"), 1)}
    for status, folder in folders.items():
        assert main(["run", *sweep, "--out", str(folder)]) == 0
        (folder / "manifest.json").write_text(json.dumps({"status": status, "sessions": [
            {"status": status, "wall_time_s": 1.5}]}))
    # the newest unfinished one: "running" (a session killed without a chance to write)
    target = folders["running"]
    mtimes = {p: p.stat().st_mtime_ns for p in (target / "parts").glob("*.parquet")}
    capsys.readouterr()
    assert main(["compare", *sweep, "--resume"]) == 0
    err = capsys.readouterr().err
    assert (f"resuming {target.relative_to(tmp_path)} (the most recent unfinished compare; "
            "2 runs already saved)") in err, err
    assert {p: p.stat().st_mtime_ns for p in mtimes} == mtimes
    man = json.loads((target / "manifest.json").read_text())
    assert man["status"] == "finished" and len(man["sessions"]) == 2
    assert man["wall_time_s"] == round(1.5 + man["sessions"][1]["wall_time_s"], 3)
    assert (target / "report.md").is_file()
    assert not (folders["interrupted"] / "report.md").exists()
    assert sorted(reports.iterdir()) == sorted(folders.values())


def test_run_resume_without_out_picks_the_latest_unfinished_run(monkeypatch, tmp_path, capsys):
    """``run`` folders are finished when they hold summary.md (written last)."""
    monkeypatch.chdir(tmp_path)
    sweep = ["run", "--scenarios", "default", "--trackers", "null", "--seeds", "3", "--steps",
             "2", "--workers", "1", "--no-progress"]
    finished = Path("reports/run-20000102T000000Z")
    cut = Path("reports/run-20000101T000000Z")
    for folder in (cut, finished):
        assert main([*sweep, "--out", str(folder)]) == 0
    for name in ("summary.md", "summary.csv", "results.parquet"):
        (cut / name).unlink()
    next(iter((cut / "parts").glob("*.parquet"))).unlink()  # one run never finished
    capsys.readouterr()
    assert main([*sweep, "--resume"]) == 0
    err = capsys.readouterr().err
    assert f"resuming {cut} (the most recent unfinished run; 2 runs already saved)" in err, err
    assert len(pd.read_parquet(cut / "results.parquet")) == 3 * 2
    assert sorted(Path("reports").iterdir()) == [cut, finished]

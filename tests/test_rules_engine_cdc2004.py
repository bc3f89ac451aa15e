"""The ``reproduce cdc2004`` command (benchmarks/app/cli_reproduce.py
``_reproduce_cdc2004``) end to end on a tiny setting: two policies, two seeds, the null
tracker, a few steps past the burn-in. What the command prints and writes, its cache,
its exit status (the check's verdict, computed here from the rows), its ``--trackers``
handling and the flags it refuses."""

from __future__ import annotations

import dataclasses

import pandas as pd
import pytest

from mttbench.benchmarks.app import reproduce_cdc2004 as cdc
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.engine.specs import TrackerSpec


@pytest.fixture
def tiny(monkeypatch):
    setting = dataclasses.replace(cdc.SETTINGS["reduced"], n_steps=cdc.BURN_IN + 3,
                                  seeds=(0, 1), trackers=("null",))
    monkeypatch.setitem(cdc.SETTINGS, "reduced", setting)
    return setting


def test_the_command_runs_writes_caches_and_exits_with_the_checks_verdict(tiny, tmp_path,
                                                                         capsys):
    out, cache = tmp_path / "out", tmp_path / "cache"
    argv = ["reproduce", "cdc2004", "--reduced", "--check", "--workers", "1",
            "--no-progress", "--out", str(out), "--cache-dir", str(cache)]
    code = main(argv)
    printed = capsys.readouterr()
    assert printed.out.startswith(f"wrote {out}/ (policies.csv, paired.csv, runs.csv, "
                                  "report.md, report.html; runs computed)\n")
    for name in ("policies.csv", "paired.csv", "runs.csv", "report.md", "report.html"):
        assert (out / name).is_file()
    runs = pd.read_csv(out / "runs.csv", keep_default_na=False)  # "null" is a name
    # one run per policy and seed, of the tracker the setting names
    assert sorted(zip(runs["policy"], runs["seed"], strict=True)) == [
        ("lookahead", 0), ("lookahead", 1), ("renyi", 0), ("renyi", 1)]
    assert set(runs["tracker_label"]) == {"null"}
    # the exit status is the check's verdict on these rows (0 passed, 1 failed)
    results = cdc.run_or_load(tiny, [TrackerSpec("null")], cache, workers=1,
                              progress=False)[0]
    verdict = cdc.check(tiny, [TrackerSpec("null")], results)
    assert code == (0 if verdict.passed else 1)
    if verdict.passed:
        assert f"check passed: {verdict.n_conditions} conditions" in printed.out
    else:
        assert f"check FAILED: {len(verdict.lines)} of {verdict.n_conditions}" in printed.err
    # the same command again reads the runs from the cache
    assert main(argv) == code
    assert "runs from the cache)" in capsys.readouterr().out


def test_the_trackers_option_is_checked_before_any_run(tiny, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["reproduce", "cdc2004", "--reduced", "--trackers", "no-such-tracker",
                 "--no-progress", "--out", str(out), "--cache-dir", str(tmp_path / "c")])
    err = capsys.readouterr().err
    assert code == 2
    assert "no-such-tracker" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("flag", [["--update-reference"], ["--reference-csv", "x.csv"]])
def test_the_reference_flags_are_refused(flag, tmp_path, capsys):
    code = main(["reproduce", "cdc2004", "--reduced", *flag, "--out", str(tmp_path / "x")])
    assert code == 2
    assert f"{flag[0]} does not apply to cdc2004" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()

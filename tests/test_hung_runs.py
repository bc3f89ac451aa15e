"""``--run-timeout`` on ``tune`` and ``reproduce`` (``run`` and ``compare``: test_sweep_faults,
test_executors): a run that hangs (``faulty_tracker:Hang``, ``HangWhenTold``) is ended
after the limit, becomes an error row or a failed trial, and the command goes on.
"""

from __future__ import annotations

import json

import pandas as pd
import pytest

from mttbench.benchmarks.app import reproduce, reproduce_cdc2004, reproduce_kreucher
from mttbench.benchmarks.app.cli import main

#: the limit of the hung runs: short, and far above what a run of these trackers takes
TIMEOUT = "1.5"


def _err(capsys) -> list[str]:
    return [x for x in capsys.readouterr().err.splitlines() if x.strip()]


def test_a_hung_run_fails_its_trial_and_the_tune_goes_on(tmp_path, capsys):
    out = tmp_path / "out"
    args = ["tune", "faulty_tracker:HangWhenTold", "--trials", "4", "--startup-trials", "4",
            "--tuning-seeds", "1", "--scenarios", "default", "--steps", "3", "--workers", "1",
            "--batch-size", "4", "--seed", "3", "--no-progress", "--run-timeout", TIMEOUT,
            "--out", str(out), "--tuned-dir", str(tmp_path / "tuned")]
    assert main(args) == 0, _err(capsys)
    trials = pd.read_csv(out / "faulty_tracker:HangWhenTold" / "trials.csv")
    hung = trials["param_mode"] == "hang"
    assert hung.any() and (~hung).any()  # this seed draws both
    assert trials.loc[hung, "state"].eq("FAIL").all()
    assert trials.loc[~hung, "state"].eq("COMPLETE").all()
    assert trials.loc[hung, "message"].str.contains(
        f"error: timed out: ended after {float(TIMEOUT):g} s of wall time (--run-timeout)",
        regex=False).all(), list(trials["message"])
    man = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    assert man["status"] == "finished"
    # the runs that finished are in the study's table; the hung ones are not (no part)
    runs = pd.read_parquet(out / "results.parquet").drop_duplicates("tracker_label")
    assert len(runs) == 1 + int((~hung).sum()) and (runs["status"] == "ok").all()


def test_reproduce_ends_a_hung_run_and_writes_what_it_can(tmp_path, capsys, monkeypatch):
    """The highlighted tracker hangs: its run is an error row, its snapshot is left out
    (not run again in the main process, where no limit holds), the rest is written."""
    tiny = reproduce.Setting("tiny", ("default",), 3, (0,), ("null", "faulty_tracker:Hang"),
                             "raster", "faulty_tracker:Hang", 0, (1,))
    monkeypatch.setitem(reproduce.SETTINGS, "reduced", tiny)
    out = tmp_path / "out"
    rc = main(["reproduce", "paper", "--reduced", "--no-cache", "--workers", "1",
               "--no-progress", "--run-timeout", TIMEOUT, "--out", str(out)])
    err = _err(capsys)
    assert rc == 1, err
    assert err[-1].startswith("1 of 2 runs failed; first error: ") and "timed out" in err[-1]
    assert any("snapshot of faulty_tracker:Hang on default left out" in x for x in err), err
    assert "Traceback" not in "\n".join(err)
    errors = pd.read_csv(out / "error_default.csv", keep_default_na=False)
    assert set(errors["tracker_label"]) == {"null"}, errors
    assert (out / "report.md").is_file()


def test_reproduce_kreucher_passes_the_limit_to_its_sweep(tmp_path, monkeypatch):
    seen = []

    def sweep(jobs, folder, **kw):
        seen.append(kw.get("run_timeout"))
        raise KeyboardInterrupt  # enough: the sweep was asked with its limit

    # the Kreucher and CDC 2004 reproductions sweep through reproduce.cached_sweep
    monkeypatch.setattr(reproduce, "run_sweep", sweep)
    specs, _ = reproduce.available_trackers(("null",))
    for module in (reproduce_kreucher, reproduce_cdc2004):
        setting = module.SETTINGS["reduced"]
        for use_cache in (True, False):
            with pytest.raises(KeyboardInterrupt):
                module.run_or_load(setting, specs, tmp_path / module.__name__,
                                   progress=False, use_cache=use_cache, run_timeout=2.5)
    assert seen == [2.5] * 4

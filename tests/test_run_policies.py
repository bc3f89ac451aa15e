"""``mttbench run`` under several policies: its summary.md gains the tracker x policy
section of ``compare`` (:mod:`mttbench.benchmarks.app.policy_axis`), with the paired
``policy - first`` differences recomputed here from the rows; one policy adds none."""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import stats

from mttbench.benchmarks.app.cli import main

SWEEP = ["--scenarios", "default", "--seeds", "3", "--steps", "4", "--workers", "1",
         "--no-progress"]


def _paired_text(results: pd.DataFrame, tracker: str, policy: str, base: str) -> str:
    """``mean ± half`` of ``policy - base`` for ``tracker``: each run's OSPA averaged over
    its steps, differenced seed by seed, Student-t 95% half-width."""
    mine = results[results["tracker_label"] == tracker]
    per_run = mine.groupby(["policy_label", "seed"])["ospa"].mean().unstack("policy_label")
    d = (per_run[policy] - per_run[base]).to_numpy(float)
    half = stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d))
    return f"{d.mean():+.3f} ± {half:.3f}"


def test_run_under_two_policies_reports_the_tracker_policy_section(tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(["run", *SWEEP, "--trackers", "null", "truth-aided", "kfnn",
               "--policies", "raster", "renyi", "--out", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    df = pd.read_parquet(out / "results.parquet")
    assert set(zip(df["tracker_label"], df["policy_label"], strict=True)) == {
        (t, p) for t in ("null", "truth-aided", "kfnn") for p in ("raster", "renyi")}
    md = (out / "summary.md").read_text()
    assert md in printed  # what is written is what the command prints
    assert "## Trackers x policies" in md
    section = md.split("## Trackers x policies", 1)[1]
    assert "### `default` (24 looks)" in section
    assert "| raster OSPA | raster gap closed | renyi OSPA | renyi gap closed |" in section
    assert "| renyi − raster |" in section
    assert "`default` (24 looks): best pair `kfnn` under `" in section
    for tracker in ("null", "kfnn"):
        row = next(line for line in section.splitlines() if line.startswith(f"| {tracker} |"))
        assert _paired_text(df, tracker, "renyi", "raster") in row, row


def test_the_first_policy_given_is_the_base_and_one_policy_adds_no_section(tmp_path):
    out = tmp_path / "reversed"
    assert main(["run", *SWEEP, "--trackers", "null", "kfnn", "--policy", "renyi,raster",
                 "--out", str(out)]) == 0
    md = (out / "summary.md").read_text()
    assert "## Trackers x policies" in md
    section = md.split("## Trackers x policies", 1)[1]
    assert "| raster − renyi |" in section and "renyi − raster" not in section
    df = pd.read_parquet(out / "results.parquet")
    row = next(line for line in section.splitlines() if line.startswith("| kfnn |"))
    assert _paired_text(df, "kfnn", "raster", "renyi") in row, row

    one = tmp_path / "one"
    assert main(["run", *SWEEP, "--trackers", "null", "kfnn", "--out", str(one)]) == 0
    assert "Trackers x policies" not in (one / "summary.md").read_text()

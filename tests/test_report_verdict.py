"""The report opens with the verdict (who leads where, by how much, the gaps, what cannot
be ranked, what each tracker costs) and ends with the settings; every section of before is
still there. The verdict's numbers are checked against scipy on synthetic runs whose
per-run means are chosen exactly."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mttbench.benchmarks.app import report, summary, verdict
from mttbench.benchmarks.engine.loop import COLUMNS

OFFSETS = np.array([-0.05, 0.05, -0.02, 0.02])  # a run's steps: mean 0
#: per scenario and tracker label, the per-seed mean OSPA of seeds 0..5
RUNS = {
    # gpf leads; pmb level with it (differences +0.1, -0.1, ...: mean 0.02); kfnn behind
    # beyond noise by 0.3 +- small
    ("clear", "null"): [2.0] * 6,
    ("clear", "truth-aided"): [0.5, 0.6, 0.4, 0.5, 0.55, 0.45],
    ("clear", "gpf"): [1.0, 1.2, 0.9, 1.1, 1.0, 0.95],
    ("clear", "pmb"): [1.1, 1.1, 1.0, 1.0, 1.12, 0.93],
    ("clear", "kfnn"): [1.31, 1.49, 1.2, 1.42, 1.29, 1.26],
    # gap 0.1: too small to rank
    ("tiny", "null"): [2.0] * 6,
    ("tiny", "truth-aided"): [1.9, 1.88, 1.92, 1.9, 1.9, 1.9],
    ("tiny", "gpf"): [1.95] * 6,
    ("tiny", "kfnn"): [1.97] * 6,
}


def frame(per_seed: dict[tuple[str, str], list[float]], wall_ms: dict[str, float]
          ) -> pd.DataFrame:
    rows = []
    for (sc, label), values in per_seed.items():
        for seed, v in enumerate(values):
            for step, off in enumerate(OFFSETS):
                rows.append({
                    "scenario": sc, "tracker": label, "tracker_label": label,
                    "tracker_params": "{}", "policy": "raster", "policy_label": "raster",
                    "policy_params": "{}", "tracker_uses_truth": label == "truth-aided",
                    "policy_uses_truth": False, "looks_per_step": 24, "seed": seed,
                    "step": step, "true_count": 3.0, "est_count": 3.0, "count_error": 0.0,
                    "own_count_error": 0.0, "ospa": v + off, "ospa_loc": v,
                    "ospa_card": 0.0, "gospa": v, "gospa_loc": v, "gospa_missed": 0.0,
                    "gospa_false": 0.0, "rmse": v, "n_looks": 24, "n_positive": 1,
                    "tracker_wall_s": wall_ms[label] * 1e-3 * (1 + 0.01 * step),
                    "tracker_cpu_s": 1e-3, "select_wall_s": 1e-5, "select_cpu_s": 1e-5,
                    "status": "ok", "error": "", "ospa_c": 2.0, "ospa_p": 2.0,
                    "peak_rss_mb": 100.0})
    df = pd.DataFrame(rows)
    assert set(COLUMNS) <= set(df.columns)
    return df


WALL_MS = {"null": 0.01, "truth-aided": 2.0, "gpf": 5.0, "pmb": 8.0, "kfnn": 0.1}


@pytest.fixture(scope="module")
def results() -> pd.DataFrame:
    return frame(RUNS, WALL_MS)


def _paired(a: str, b: str, sc: str = "clear") -> tuple[float, float]:
    """``a - b`` per seed: mean and 95% half-width by scipy's paired t interval."""
    x, y = np.array(RUNS[(sc, a)]), np.array(RUNS[(sc, b)])
    ci = stats.ttest_rel(x, y).confidence_interval(0.95)
    return float((x - y).mean()), float((ci.high - ci.low) / 2)


def test_leader_and_paired_differences_match_scipy(results):
    runs = summary.per_run(results)
    labels = verdict.contestants(runs)
    assert labels == {"gpf", "pmb", "kfnn"}  # no floor, no ceiling (truth)
    leader, mean, half, others = verdict.leader_comparison(
        runs[runs["scenario"] == "clear"], labels)
    assert leader == "gpf"
    want = np.array(RUNS[("clear", "gpf")])
    assert mean == pytest.approx(want.mean(), abs=1e-12)
    assert half == pytest.approx(stats.sem(want) * stats.t.ppf(0.975, 5), abs=1e-12)
    assert list(others["tracker_label"]) == ["pmb", "kfnn"]
    for r in others.itertuples(index=False):
        m, h = _paired(r.tracker_label, "gpf")
        assert r.diff_mean == pytest.approx(m, abs=1e-12)
        assert r.diff_ci95 == pytest.approx(h, abs=1e-12)
        assert r.n_pairs == 6


def test_verdict_lines_say_who_leads_by_how_much_and_what_cannot_rank(results):
    runs = summary.per_run(results)
    gc = summary.gap_closed(runs)
    lines = verdict.group_lines(runs, gc)
    assert len(lines) == 2
    clear, tiny = lines
    pmb_m, pmb_h = _paired("pmb", "gpf")
    kf_m, kf_h = _paired("kfnn", "gpf")
    assert pmb_m - pmb_h <= 0 < kf_m - kf_h  # the data: pmb level, kfnn behind
    assert clear.startswith("`clear` (raster, 24 looks): `gpf` leads, OSPA ")
    assert f"level within noise: `pmb` ({pmb_m:+.3f} ± {pmb_h:.3f})" in clear
    assert f"ahead of the next, `kfnn`, by {kf_m:.3f} ± {kf_h:.3f} (paired, 6 seeds)" in clear
    assert "cannot rank" not in clear
    row = gc.gaps.set_index("scenario").loc["clear"]
    assert f"Gap floor to ceiling {row['gap_mean']:.3f} ± {row['gap_ci95']:.3f}" in clear
    share = gc.shares[(gc.shares["scenario"] == "clear")
                      & (gc.shares["tracker_label"] == "gpf")].iloc[0]
    assert f"`gpf` closes {share['share_mean']:.2f} ± {share['share_ci95']:.2f} of the gap" \
        in clear
    assert tiny.startswith("`tiny` (raster, 24 looks): cannot rank trackers (the OSPA gap "
                           "between floor and ceiling, 0.100 ± ")
    assert "is below 0.15" in tiny and "`gpf` leads" in tiny


def test_cost_line_is_cheapest_first_with_the_range_over_scenarios(results):
    summ = summary.summarize(summary.per_run(results))
    line = verdict.cost_line(summ)
    order = re.findall(r"`([^`]+)` [\d.]+", line)
    assert order == ["null", "kfnn", "truth-aided", "gpf", "pmb"]
    ms = summ[summ["tracker_label"] == "gpf"]["tracker_wall_s_mean"].to_numpy() * 1e3
    assert f"`gpf` {ms.mean():.3g} ({ms.min():.3g}-{ms.max():.3g})" in line


def test_report_opens_with_the_verdict_and_ends_with_the_settings(results, tmp_path):
    files = report.build_report(
        results, tmp_path, reference="kfnn", intro=["INTRO PARAGRAPH"],
        settings={"seeds": "0-5"}, sections=[("h2", "Parameters"), ("p", "PARAMS TEXT")])
    md = files.markdown.read_text()
    heads = [ln for ln in md.splitlines() if ln.startswith("## ")]
    assert heads[0] == "## Verdict"
    order = ["## Verdict", "INTRO PARAGRAPH", "## Floor and ceiling", "## Accuracy",
             "## Runtime", "## Paired differences against kfnn", "## Figures",
             "## Settings", "- seeds: 0-5", "## Parameters", "PARAMS TEXT"]
    at = [md.index(s) for s in order]
    assert at == sorted(at), order
    first = md.split("## Verdict", 1)[1].split("\n## ", 1)[0]
    assert "OSPA with c = 2 world units, p = 2." in first  # not presets: no cell size
    runs = summary.per_run(results)
    for line in verdict.group_lines(runs, summary.gap_closed(runs)):
        assert f"- {line}" in first
    assert verdict.cost_line(summary.summarize(runs)) in first
    # the figure of the gap closed is in the verdict, and only there
    assert "gap_closed" in files.figures
    assert first.count("(figures/gap_closed.png)") == 1
    assert md.count("(figures/gap_closed.png)") == 1
    assert files.figures["gap_closed"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # nothing before the verdict but the title
    assert md.index("## Verdict") < md.index("|")


def test_without_a_ceiling_the_verdict_still_ranks_and_says_why_no_gap(tmp_path):
    runs_in = {k: v for k, v in RUNS.items() if k[1] != "truth-aided"}
    # flat: the only contestant scatters around the floor, so it does not beat it
    runs_in |= {("flat", "null"): [2.0] * 6, ("flat", "gpf"): [1.9, 2.1, 2.0, 1.95, 2.05, 2.0]}
    md = report.build_report(frame(runs_in, WALL_MS), tmp_path, reference="kfnn",
                             draw=False).markdown.read_text()
    first = md.split("## Verdict", 1)[1].split("\n## ", 1)[0]
    assert "Gap floor to ceiling" not in first
    assert "The ceiling `truth-aided` did not run" in first
    lines = {ln.split("`")[1]: ln for ln in first.splitlines() if ln.startswith("- `")}
    assert set(lines) == {"clear", "flat", "tiny"}
    assert "`gpf` leads" in lines["clear"] and "cannot rank" not in lines["clear"]
    # tiny: gpf 1.95 against the floor's 2.0 in every seed beats it (zero-width interval)
    assert "cannot rank" not in lines["tiny"]
    assert lines["flat"].startswith("- `flat` (raster, 24 looks): cannot rank trackers "
                                    "(no contestant beats the floor in the paired test); "
                                    "`gpf` leads")


def test_with_the_bayes_reference_the_verdict_gives_the_achievable_gap():
    """``bayes`` is a reference, not a contestant: the leader stays ``gpf`` and the line
    gives the floor-to-Bayes gap and the leader's share of it (the gap table's numbers)."""
    with_bayes = RUNS | {("clear", "bayes"): [0.8, 0.9, 0.75, 0.85, 0.8, 0.7],
                         ("tiny", "bayes"): [1.92] * 6}
    runs = summary.per_run(frame(with_bayes, WALL_MS | {"bayes": 1.0}))
    gc = summary.gap_closed(runs)
    assert gc.bayes_label == "bayes"
    assert "bayes" not in verdict.contestants(runs)
    clear = verdict.group_lines(runs, gc)[0]
    row = gc.gaps.set_index("scenario").loc["clear"]
    floor, bayes = np.array(RUNS[("clear", "null")]), np.array(with_bayes[("clear", "bayes")])
    assert row["achievable_mean"] == pytest.approx((floor - bayes).mean(), abs=1e-12)
    assert (f"achievable gap (floor to Bayes) {row['achievable_mean']:.3f} ± "
            f"{row['achievable_ci95']:.3f}") in clear
    share = gc.shares[(gc.shares["scenario"] == "clear")
                      & (gc.shares["tracker_label"] == "gpf")].iloc[0]
    assert (f"({share['achievable_mean']:.2f} ± {share['achievable_ci95']:.2f} of the "
            "achievable)") in clear
    assert "`gpf` leads" in clear

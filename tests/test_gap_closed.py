"""Floor, ceiling and each tracker's share of the gap closed in the compare report.

The share ``(F - X) / (F - C)`` of the per-seed means and its delta-method interval
are checked against hand computations on synthetic results tables whose per-run means
are chosen exactly (each run's steps scatter symmetrically around its value).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mttbench.benchmarks.app import compare, report, summary
from mttbench.benchmarks.engine.loop import COLUMNS, spec_uses_truth
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.trackers.base import register, unregister
from mttbench.trackers.null import NullTracker

TOL = 1e-12
OFFSETS = np.array([-0.05, 0.05, -0.02, 0.02])  # steps of a run: mean 0


def frame(per_seed: dict[tuple[str, str], list[float]], policy: str = "raster",
          truth: tuple[str, ...] = ("truth-aided",)) -> pd.DataFrame:
    """A results table with the harness columns: ``(scenario, tracker label) -> the
    per-run mean OSPA of seeds 0..n-1``. Trackers in ``truth`` carry
    ``tracker_uses_truth = True``, every run of the ``oracle`` policy
    ``policy_uses_truth = True``."""
    rows = []
    for (sc, label), values in per_seed.items():
        name = label.split("(")[0]
        for seed, v in enumerate(values):
            for step, off in enumerate(OFFSETS):
                rows.append({
                    "scenario": sc, "tracker": name, "tracker_label": label,
                    "tracker_params": "{}", "policy": policy, "policy_label": policy,
                    "policy_params": "{}", "tracker_uses_truth": name in truth,
                    "policy_uses_truth": policy == "oracle",
                    "looks_per_step": 24, "seed": seed, "step": step, "true_count": 3.0,
                    "est_count": 3.0, "count_error": 0.0, "own_count_error": 0.0,
                    "ospa": v + off, "ospa_loc": v,
                    "ospa_card": 0.0, "gospa": v, "gospa_loc": v, "gospa_missed": 0.0,
                    "gospa_false": 0.0, "rmse": v, "n_looks": 24, "n_positive": 1,
                    "tracker_wall_s": 1e-3, "tracker_cpu_s": 1e-3, "select_wall_s": 1e-5,
                    "select_cpu_s": 1e-5, "status": "ok", "error": "", "ospa_c": 2.0,
                    "ospa_p": 2.0, "peak_rss_mb": 100.0})
    df = pd.DataFrame(rows)
    assert set(COLUMNS) <= set(df.columns)
    return df


def _share_row(gc: summary.GapClosed, scenario: str, label: str) -> pd.Series:
    sel = gc.shares[(gc.shares["scenario"] == scenario) & (gc.shares["tracker_label"] == label)]
    assert len(sel) == 1, sel
    return sel.iloc[0]


# ------------------------------------------------------------ the share, by hand
def test_share_and_interval_match_the_closed_form_with_a_constant_gap():
    """F = 2, C = 1 in every seed (gap 1), X = 1.8, 1.6, 1.4, 1.2: the share is
    mean(F - X) / 1 = 0.5, and with a constant gap the delta-method interval is the t
    interval of F - X: t_{0.975, 3} * sd(0.2, 0.4, 0.6, 0.8) / 2."""
    gc = summary.gap_closed(frame({("s", "null"): [2.0] * 4, ("s", "truth-aided"): [1.0] * 4,
                                   ("s", "kfnn"): [1.8, 1.6, 1.4, 1.2]}))
    assert gc.available and gc.floor_label == "null" and gc.ceiling_label == "truth-aided"
    r = _share_row(gc, "s", "kfnn")
    assert r["share_mean"] == pytest.approx(0.5, abs=TOL)
    sd = math.sqrt((0.3**2 + 0.1**2 + 0.1**2 + 0.3**2) / 3)
    assert r["share_ci95"] == pytest.approx(stats.t.ppf(0.975, 3) * sd / 2, abs=TOL)
    lo, hi = stats.t.interval(0.95, 3, loc=0.5, scale=stats.sem([0.2, 0.4, 0.6, 0.8]))
    assert r["share_ci95"] == pytest.approx((hi - lo) / 2, abs=TOL)
    assert r["n_pairs"] == 4 and r["ospa_mean"] == pytest.approx(1.5, abs=TOL)
    # the floor closes none of the gap and the ceiling all of it, exactly
    assert tuple(_share_row(gc, "s", "null")[["share_mean", "share_ci95", "role"]]) == (
        0.0, 0.0, "floor")
    assert tuple(_share_row(gc, "s", "truth-aided")[["share_mean", "share_ci95", "role"]]) == (
        1.0, 0.0, "ceiling")
    (g,) = gc.gaps.itertuples(index=False)
    assert g.gap_mean == pytest.approx(1.0, abs=TOL) and g.gap_ci95 == pytest.approx(0, abs=TOL)
    assert g.rankable and g.reason == ""


def test_share_interval_is_the_delta_method_of_a_ratio_of_paired_means():
    """Varying floor and ceiling: Var(A/B) ~ (s_AA - 2 r s_AB + r^2 s_BB) / (n B^2)
    with A = F - X, B = F - C per seed (the gradient form of the delta method)."""
    rng = np.random.default_rng(np.random.SeedSequence(14))
    n = 9
    f = 2.0 - rng.uniform(0.0, 0.3, n)
    c = rng.uniform(0.3, 0.9, n)
    x = c + rng.uniform(0.1, 0.9, n) * (f - c)
    gc = summary.gap_closed(frame({("s", "null"): list(f), ("s", "truth-aided"): list(c),
                                   ("s", "gpf"): list(x)}))
    a, b = f - x, f - c
    ratio = a.sum() / b.sum()
    cov = np.cov(a, b, ddof=1)
    var = (cov[0, 0] - 2 * ratio * cov[0, 1] + ratio**2 * cov[1, 1]) / (n * b.mean() ** 2)
    r = _share_row(gc, "s", "gpf")
    assert r["share_mean"] == pytest.approx(ratio, abs=TOL)
    assert r["share_ci95"] == pytest.approx(stats.t.ppf(0.975, n - 1) * math.sqrt(var), abs=TOL)
    # the gap and its paired interval are those of ttest_rel(F, C)
    (g,) = gc.gaps.itertuples(index=False)
    ci = stats.ttest_rel(f, c).confidence_interval(0.95)
    assert g.gap_mean == pytest.approx(b.mean(), abs=TOL)
    assert g.gap_ci95 == pytest.approx((ci.high - ci.low) / 2, abs=TOL)
    assert g.floor_mean == pytest.approx(f.mean(), abs=TOL)
    assert g.ceiling_mean == pytest.approx(c.mean(), abs=TOL)


def test_only_seeds_where_floor_ceiling_and_tracker_are_ok_are_paired():
    df = frame({("s", "null"): [2.0] * 5, ("s", "truth-aided"): [1.0, 1.2, 0.8, 1.0, 9.0],
                ("s", "kfnn"): [1.5, 1.5, 1.0, 1.9, 1.0]})
    bad = ((df["tracker_label"] == "truth-aided") & (df["seed"] == 4)) | (
        (df["tracker_label"] == "kfnn") & (df["seed"] == 3) & (df["step"] == 2))
    df.loc[bad, "status"] = "error"
    gc = summary.gap_closed(df)
    r = _share_row(gc, "s", "kfnn")  # seeds 0, 1, 2
    assert r["n_pairs"] == 3
    assert r["share_mean"] == pytest.approx((0.5 + 0.5 + 1.0) / (1.0 + 0.8 + 1.2), abs=TOL)
    assert gc.gaps.iloc[0]["n_pairs"] == 4  # the gap needs floor and ceiling only


# ------------------------------------------------------------ scenarios that cannot rank
def _three_scenarios() -> pd.DataFrame:
    return frame({
        ("clear", "null"): [2.0] * 4, ("clear", "truth-aided"): [1.0, 1.1, 0.9, 1.0],
        ("clear", "kfnn"): [1.5] * 4,
        # gap 0.1 +- 0.02: far from 0 but below 0.15
        ("tiny", "null"): [2.0] * 4, ("tiny", "truth-aided"): [1.9, 1.88, 1.92, 1.9],
        ("tiny", "kfnn"): [1.95] * 4,
        # gap 0.3 on average, but 1.2, -0.6, 0.9, -0.3: its interval reaches 0
        ("noisy", "null"): [2.0] * 4, ("noisy", "truth-aided"): [0.8, 2.6, 1.1, 2.3],
        ("noisy", "kfnn"): [1.5] * 4,
    })


def test_a_small_or_uncertain_gap_is_flagged_with_its_reason():
    gc = summary.gap_closed(_three_scenarios())
    gaps = gc.gaps.set_index("scenario")
    assert gaps.loc["clear", "rankable"] and gaps.loc["clear", "reason"] == ""
    tiny, noisy = gaps.loc["tiny", "reason"], gaps.loc["noisy", "reason"]
    assert not gaps.loc["tiny", "rankable"] and not gaps.loc["noisy", "rankable"]
    assert tiny.startswith("this scenario cannot rank trackers: ")
    assert "0.100 ± " in tiny and "is below 0.15" in tiny and "reaches 0" not in tiny
    assert "0.300 ± " in noisy and "95% interval that reaches 0" in noisy
    assert "below" not in noisy
    notes = summary.gap_notes(gc)
    assert len(notes) == 2 and notes[0].startswith("`noisy` (raster, 24 looks): this scenario")
    # a higher threshold flags the clear one too
    assert not summary.gap_closed(_three_scenarios(), min_gap=1.5).gaps["rankable"].any()


def test_report_flags_the_scenarios_that_cannot_rank(tmp_path):
    md = report.build_report(_three_scenarios(), tmp_path, reference="kfnn",
                             draw=False).markdown.read_text()
    section = md.split("## Floor and ceiling: share of the gap closed", 1)[1].split("\n## ")[0]
    flagged = [ln for ln in section.splitlines() if "this scenario cannot rank trackers" in ln]
    assert len(flagged) == 2 and all(ln.startswith("- `") for ln in flagged)
    assert {ln.split("`")[1] for ln in flagged} == {"tiny", "noisy"}
    gap_rows = {ln.split(" | ")[0].lstrip("| "): ln for ln in section.splitlines()
                if ln.endswith(("| yes |", "| no |"))}
    assert gap_rows["clear"].endswith("| yes |") and gap_rows["tiny"].endswith("| no |")
    # floor first, ceiling last, the tracker's share with its interval in between
    rows = [ln for ln in section.splitlines() if ln.startswith("| clear |") and "(" in ln]
    assert rows[0].endswith("| 0 (floor) |") and rows[-1].endswith("| 1 (ceiling) |")
    assert "truth-aided (uses truth)" in rows[-1]
    assert "| kfnn | 4 | 1.500 ± 0 | 0.50 ± " in section
    assert md.index("## Floor and ceiling") < md.index("## Accuracy")


# ------------------------------------------------------------ floor or ceiling absent
@pytest.mark.parametrize(("labels", "missing"), [
    (("kfnn", "gpf"), ["floor `null`", "ceiling `truth-aided`"]),
    (("null", "kfnn"), ["ceiling `truth-aided`"]),
    (("truth-aided", "kfnn"), ["floor `null`"]),
])
def test_without_floor_or_ceiling_the_share_columns_are_absent_and_the_report_says_why(
        tmp_path, labels, missing):
    df = frame({("s", lab): [1.0, 1.5, 2.0] for lab in labels})
    gc = summary.gap_closed(df)
    assert not gc.available and gc.gaps.empty and gc.shares.empty
    assert gc.absent.startswith("The " + " and the ".join(missing) + " did not run, ")
    md = report.build_report(df, tmp_path, reference="kfnn", draw=False).markdown.read_text()
    section = md.split("## Floor and ceiling", 1)[1].split("\n## ")[0]
    assert gc.absent in section and "share of gap closed |" not in section
    text = summary.write_summary(df, tmp_path, "t")
    assert "gap closed" not in pd.read_csv(tmp_path / "summary.csv").columns.str.replace(
        "_", " ").str.cat(sep=",")
    assert "| gap closed |" not in text and gc.absent in text


def test_a_scenario_where_the_ceiling_failed_has_no_shares_and_says_so():
    df = frame({("a", "null"): [2.0] * 3, ("a", "truth-aided"): [1.0] * 3,
                ("a", "kfnn"): [1.5] * 3, ("b", "null"): [2.0] * 3,
                ("b", "truth-aided"): [1.0] * 3, ("b", "kfnn"): [1.5] * 3})
    failed = (df["scenario"] == "b") & (df["tracker_label"] == "truth-aided")
    df.loc[failed, "status"] = "unsupported"
    gc = summary.gap_closed(df)
    assert gc.available and set(gc.shares["scenario"]) == {"a"}
    b = gc.gaps.set_index("scenario").loc["b"]
    assert b["n_pairs"] == 0 and not b["rankable"]
    assert b["reason"] == "no OSPA gap here: the ceiling `truth-aided` has no ok run"
    summ = summary.with_gap_closed(summary.summarize(df), gc)
    assert summ.loc[summ["scenario"] == "a", "gap_closed_mean"].notna().all()
    assert summ.loc[summ["scenario"] == "b", "gap_closed_mean"].isna().all()


# ------------------------------------------------------------ uses the truth
def test_rows_that_use_the_truth_are_marked_in_every_table(tmp_path):
    vals = [1.0, 1.4, 1.2]
    df = pd.concat([
        frame({("s", "null"): [2.0] * 3, ("s", "truth-aided"): [0.5, 0.7, 0.6],
               ("s", "kfnn"): vals}),
        frame({("s", "kfnn"): vals}, policy="oracle"),
    ], ignore_index=True)
    assert summary.truth_labels(df) == ({"truth-aided"}, {"oracle"})
    summ = summary.summarize(df)
    table = report.summary_table(summ, report.ACCURACY_COLUMNS)
    cells = set(zip(table["tracker"], table["policy"], strict=True))
    assert cells == {("null", "raster"), ("kfnn", "raster"), ("kfnn", "oracle (uses truth)"),
                     ("truth-aided (uses truth)", "raster")}
    paired = report.paired_table(report.paired_differences(df, "kfnn"),
                                 summary.truth_labels(df))
    assert "truth-aided (uses truth)" in set(paired["tracker"])
    text = summary.to_markdown(summary.with_gap_closed(summ, summary.gap_closed(df)))
    assert "| s | truth-aided (uses truth) | raster |" in text
    assert "| s | kfnn | oracle (uses truth) |" in text and "| s | kfnn | raster |" in text
    md = report.build_report(df, tmp_path, reference="kfnn", draw=False).markdown.read_text()
    for head in ("## Floor and ceiling", "## Accuracy", "### GOSPA", "## Runtime",
                 "## Paired differences"):
        section = md.split(head, 1)[1].split("\n## ")[0]
        assert "truth-aided (uses truth)" in section, head
        assert "| truth-aided |" not in section, head


def test_the_oracle_alone_still_marks_the_policy_not_the_tracker():
    """Each side is marked from its own column, never from the registries: the oracle
    marks its policy only; a tracker flagged in its rows is marked whatever its name (one
    not registered here too), one not flagged is not (even the ceiling's name); a table
    without the columns marks nothing."""
    one = {("s", "kfnn"): [1.0]}
    assert summary.truth_labels(frame(one, policy="oracle")) == (set(), {"oracle"})
    assert summary.truth_labels(frame(one)) == (set(), set())
    told = frame({("s", "not-registered-here"): [1.0]}, truth=("not-registered-here",))
    assert summary.truth_labels(told) == ({"not-registered-here"}, set())
    assert summary.truth_labels(frame({("s", "truth-aided"): [1.0]}, truth=())) == (set(), set())
    unmarked = frame(one, policy="oracle").drop(columns=["tracker_uses_truth",
                                                         "policy_uses_truth"])
    assert summary.truth_labels(unmarked) == (set(), set())


def test_the_default_reference_never_uses_the_truth():
    class Told(NullTracker):
        name = "test-told-the-truth"
        uses_truth = True
        baseline = False

    register(Told)
    try:
        assert spec_uses_truth(TrackerSpec(Told.name))
        specs = [TrackerSpec(Told.name), TrackerSpec("truth-aided"), TrackerSpec("gpf"),
                 TrackerSpec("kfnn")]
        assert compare.default_reference(specs) == "kfnn"
        assert compare.default_reference(specs[:3]) == "gpf"
        assert compare.default_reference(specs[:2]) is None
    finally:
        unregister(Told.name)


def test_figures_draw_floor_and_ceiling(tmp_path):
    df = frame({("s", "null"): [2.0] * 3, ("s", "truth-aided"): [0.5, 0.7, 0.6],
                ("s", "kfnn"): [1.0, 1.4, 1.2]})
    files = report.build_report(df, tmp_path, reference="kfnn")
    for path in files.figures.values():
        assert path.read_bytes()[:4] == b"\x89PNG"


def test_a_wide_gap_that_no_contestant_beats_the_floor_on_cannot_rank():
    """Floor 2.0, ceiling 0.5 (a wide, certain gap); the contestants scatter around the
    floor, so none has a paired difference with the floor whose interval lies above 0:
    the scenario cannot rank. One that beats the floor on every seed makes it rankable.
    The truth-aided ceiling is not a contestant."""
    floor = [2.0, 2.0, 2.0, 2.0]
    base = {("s", "null"): floor, ("s", "truth-aided"): [0.5, 0.6, 0.4, 0.5]}
    level = {**base, ("s", "kfnn"): [2.1, 1.9, 2.05, 1.95], ("s", "gpf"): [1.8, 2.2, 2.0, 2.0]}
    gaps = summary.gap_closed(frame(level)).gaps.set_index("scenario")
    assert not gaps.loc["s", "rankable"]
    assert gaps.loc["s", "reason"] == ("this scenario cannot rank trackers: no contestant's "
                                       "OSPA beats the floor `null` within its 95% interval.")
    better = {**level, ("s", "gpf"): [1.5, 1.6, 1.4, 1.5]}
    gaps = summary.gap_closed(frame(better)).gaps.set_index("scenario")
    assert gaps.loc["s", "rankable"] and gaps.loc["s", "reason"] == ""


def test_tables_mark_the_rows_a_tuned_file_did_not_see():
    table = pd.DataFrame({"scenario": ["a", "b", "b"],
                          "tracker": ["gpf(tuned)", "gpf(tuned)", "kfnn"]})
    marked = report.mark_out_of_sample(table, {"gpf(tuned)": frozenset({"a"})})
    assert list(marked["tracker"]) == ["gpf(tuned)", "gpf(tuned)" + report.OUT_OF_SAMPLE_MARK,
                                       "kfnn"]
    assert report.mark_out_of_sample(table, None) is table


def test_runtime_per_run_keeps_the_slow_steps():
    """The median hides single slow steps: the run's 95th percentile and slowest step are
    numpy's over its ok steps."""
    df = frame({("s", "kfnn"): [1.0]})
    df["tracker_wall_s"] = [1e-3, 1e-3, 1e-3, 0.5]
    run = summary.per_run(df).iloc[0]
    wall = df["tracker_wall_s"].to_numpy()
    assert run["tracker_wall_s"] == np.median(wall)
    assert run["tracker_wall_p95_s"] == np.quantile(wall, 0.95)
    assert run["tracker_wall_max_s"] == 0.5

"""Rules of the report's tables (``benchmarks/app/report.py``) fed values where a slip
shows: a tiny mean beside a tinier half-width, a ``g`` format's trailing zeros, the
``all`` policy beside ``none``, metrics paired over different seed counts, a baseline
exactly on the edge of the best's interval, a contestant with one shared seed. Each
expected cell is written out from the inputs by hand (``format`` of the scaled value),
never read from the code's output."""

from __future__ import annotations

import math

import pandas as pd

from mttbench.benchmarks.app import report, summary


def _g3(x: float) -> str:
    """``x`` in three significant digits, trailing zeros kept (``1.00``)."""
    return format(x, "#.3g").rstrip(".")


# ------------------------------------------------------------------- fmt_pm
def test_fmt_pm_keeps_the_significant_zeros_of_a_g_format():
    assert report.fmt_pm(1.0, 0.5, 1.0, ".3g") == "1.00 ± 0.500"
    assert report.fmt_pm(0.25, 0.1, 1e3, ".3g") == "250 ± 100"


def test_fmt_pm_writes_a_real_half_width_of_a_tiny_mean():
    """Only a half-width below 1e-9 of its own mean is rounding noise; a mean of 1e-12
    with a half-width of 1e-13 keeps both."""
    assert report.fmt_pm(1e-12, 1e-13, 1.0, ".3g") == f"{_g3(1e-12)} ± {_g3(1e-13)}"
    assert report.fmt_pm(4.0, 4e-16, 1.0, ".3f") == "4.000 ± 0"


# ------------------------------------------------------------- summary_table
def _summ(**extra) -> pd.DataFrame:
    base = {"scenario": ["a", "a"], "tracker_label": ["kfnn", "gpf"], "n_seeds": [3, 3],
            "ospa_mean": [1.0, 0.5], "ospa_ci95": [0.1, 0.05]}
    base.update(extra)
    return pd.DataFrame(base)


def test_the_looks_cell_is_a_dash_only_without_looks():
    """``none`` (the superposition sensor) has no looks; ``all`` makes its own number
    of looks, shown beside the budget."""
    summ = _summ(policy_label=["none", "all"], looks_per_step=[200, 200],
                 looks_made=[float("nan"), 144.0])
    table = report.summary_table(summ, [])
    assert list(table["looks"]) == ["–", "200 (144 made)"]


def test_no_note_column_when_every_note_is_empty():
    table = report.summary_table(_summ(note=["", ""]), [])
    assert "note" not in table.columns
    table = report.summary_table(_summ(note=["", "failed in 1 of 3 runs: x"]), [])
    assert list(table["note"]) == ["", "failed in 1 of 3 runs: x"]


# -------------------------------------------------------------- paired_table
def _paired_rows() -> pd.DataFrame:
    rows = []
    for metric, mean, half, n in (("ospa", -0.25, 0.125, 5),
                                  ("tracker_wall_s", 0.002, 0.0005, 3)):
        rows.append({"scenario": "a", "policy_label": "raster", "looks_per_step": 24,
                     "tracker_label": "gpf", "reference_label": "kfnn", "metric": metric,
                     "diff_mean": mean, "diff_ci95": half, "n_seeds": n})
    return pd.DataFrame(rows)


def test_the_paired_time_column_is_in_milliseconds():
    table = report.paired_table(_paired_rows())
    assert table.loc[0, "Δ ms/step"] == f"{_g3(0.002 * 1e3)} ± {_g3(0.0005 * 1e3)}"


def test_the_pairs_column_is_the_fewest_pairs_of_any_metric():
    assert int(report.paired_table(_paired_rows()).loc[0, "pairs"]) == 3


# -------------------------------------------------------- out of sample mark
def test_the_out_of_sample_mark_goes_on_the_scenarios_not_tuned_on():
    table = pd.DataFrame({"scenario": ["a", "b", "a", "b"],
                          "tracker": ["gpf(tuned)", "gpf(tuned)", "kfnn", "kfnn"]})
    out = report.mark_out_of_sample(table, {"gpf(tuned)": frozenset({"a"})})
    mark = report.OUT_OF_SAMPLE_MARK
    assert list(out["tracker"]) == ["gpf(tuned)", "gpf(tuned)" + mark, "kfnn", "kfnn"]


# ------------------------------------------------------- floor and ceiling
def _gap_closed(shares: pd.DataFrame | None = None, bayes: bool = False) -> summary.GapClosed:
    gaps = pd.DataFrame([{
        "scenario": "a", "policy_label": "raster", "looks_per_step": 24,
        "floor_label": "null", "ceiling_label": "truth-aided", "n_pairs": 4,
        "floor_mean": 2.0, "floor_ci95": 0.125, "ceiling_mean": 0.5, "ceiling_ci95": 0.25,
        "gap_mean": 1.5, "gap_ci95": 0.375, "rankable": True, "reason": "",
        "bayes_mean": 0.75, "bayes_ci95": 0.0625, "achievable_mean": 1.25,
        "achievable_ci95": 0.1, "bayes_share_mean": 0.8, "bayes_share_ci95": 0.05,
        "problem_limited": False}])
    if shares is None:
        shares = pd.DataFrame(columns=[*summary.GAP_GROUP, "tracker_label", "role"])
    return summary.GapClosed("ospa", "null", "truth-aided", gaps, shares, "",
                             "bayes" if bayes else None)


def test_the_gap_table_shows_each_side_with_its_own_half_width():
    table = report.gap_table(_gap_closed())
    floor = [c for c in table.columns if c.startswith("floor ")][0]
    ceiling = [c for c in table.columns if c.startswith("ceiling ")][0]
    assert table.loc[0, floor] == "2.000 ± 0.125"
    assert table.loc[0, ceiling] == "0.500 ± 0.250"
    assert table.loc[0, "gap"] == "1.500 ± 0.375"


def _share_rows() -> pd.DataFrame:
    rows = []
    for label, role, mean, vs in (("null", "floor", 2.0, math.nan),
                                  ("gpf", "", 1.0, -0.2), ("kfnn", "", 1.5, -0.05),
                                  ("pmb", "", 1.25, 0.3),
                                  ("truth-aided", "ceiling", 0.5, math.nan)):
        rows.append({"scenario": "a", "policy_label": "raster", "looks_per_step": 24,
                     "tracker_label": label, "role": role, "n_pairs": 4, "ospa_mean": mean,
                     "ospa_ci95": 0.1, "share_mean": (2.0 - mean) / 1.5, "share_ci95": 0.1,
                     "achievable_mean": (2.0 - mean) / 1.25, "achievable_ci95": 0.1,
                     "vs_bayes_mean": vs, "vs_bayes_ci95": 0.1})
    return pd.DataFrame(rows)


def test_a_contestant_beats_the_bayes_reference_only_beyond_its_interval():
    """``gpf`` is below the reference by 0.2 ± 0.1 (beyond noise); ``kfnn`` by 0.05 ±
    0.1 (its interval reaches above 0: not beyond noise); ``pmb`` is above it."""
    notes = report.bayes_notes(_gap_closed(_share_rows(), bayes=True))
    named = [n for n in notes if "beats the Bayes reference" in n]
    assert len(named) == 1 and "`gpf`" in named[0]


def test_the_share_table_lists_floor_then_contestants_worst_first_then_ceiling():
    table = report.share_table(_gap_closed(_share_rows()))
    # worst first: the least share of the gap, i.e. the largest OSPA (kfnn 1.5, pmb 1.25,
    # gpf 1.0)
    assert list(table["tracker"]) == ["null", "kfnn", "pmb", "gpf", "truth-aided"]


# ------------------------------------------------------------ baseline notes
def test_a_baseline_on_the_edge_of_the_best_interval_is_within_it():
    """Without per-run rows the rule is: the baseline is within the best's 95% interval
    when ``baseline <= best + half`` (lower is better); 1.5 <= 1.0 + 0.5 exactly."""
    summ = pd.DataFrame({"scenario": ["a", "a"], "tracker": ["null", "kfnn"],
                         "tracker_label": ["null", "kfnn"], "n_seeds": [4, 4],
                         "ospa_mean": [1.5, 1.0], "ospa_ci95": [0.2, 0.5]})
    notes = report.baseline_notes(summ)
    assert len(notes) == 1 and "within the 95% interval" in notes[0]
    summ.loc[0, "ospa_mean"] = 1.625  # beyond the edge: beaten
    assert report.baseline_notes(summ) == []


def _runs(values: dict[str, dict[int, float]]) -> pd.DataFrame:
    rows = [{"scenario": "a", "policy_label": "raster", "looks_per_step": 24, "seed": s,
             "tracker": lab, "tracker_label": lab, "status": "ok", "ospa": v}
            for lab, per in values.items() for s, v in per.items()]
    return pd.DataFrame(rows)


def test_the_paired_baseline_test_needs_two_shared_seeds():
    """A contestant sharing one seed with the baseline has no interval: it enters no
    paired verdict (nothing to say); with two shared seeds that it does not win beyond
    noise the scenario cannot rank trackers."""
    summ = pd.DataFrame({"scenario": ["a"], "tracker": ["null"], "tracker_label": ["null"]})
    one = _runs({"null": {0: 2.0, 1: 2.0}, "kfnn": {0: 1.9}})
    assert report.baseline_notes(summ, one) == []
    two = _runs({"null": {0: 2.0, 1: 2.0}, "kfnn": {0: 1.9, 1: 2.1}})
    notes = report.baseline_notes(summ, two)
    assert len(notes) == 1 and "`kfnn`" in notes[0]


def test_only_the_trackers_declared_baseline_are_baselines():
    assert report._is_baseline("null")
    assert not report._is_baseline("grid-bayes")  # a reference, not the floor
    assert not report._is_baseline("kfnn")
    assert not report._is_baseline("no-such-tracker")


# --------------------------------------------------------------- small parts
def test_the_crossing_sentence_counts_the_runs_steps():
    row = pd.DataFrame([{"scenario": "crossing", "crossings_mean": 2.0,
                         "crossings_ci95": 0.5, "near_steps_mean": 12.0,
                         "near_steps_ci95": 1.0, "n_steps_mean": 50.0}])
    text = report.crossing_sentence(row)
    assert text == ("`crossing`: 2.0 ± 0.5 crossings per run, 12.0 ± 1.0 of 50 steps "
                    "near one.")


def test_inline_code_wraps_the_text_between_backticks():
    assert report._inline("a `b<c` d") == "a <code>b&lt;c</code> d"
    assert report._inline("plain & simple") == "plain &amp; simple"

"""Rules of the tracker x policy tables (``benchmarks/app/policy_axis.py``) on per-run
rows built by hand where a slip shows: an interval that touches 0, one policy only,
means equal but for their summation order, the base policy named first, an oracle
policy that uses the truth, a policy better than the base beyond noise (negative), a
tracker whose runs under two policies share different numbers of seeds, no Bayes
reference anywhere, the rows' order."""

from __future__ import annotations

import math

import pandas as pd

from mttbench.benchmarks.app import policy_axis as pa

#: per tracker: the per-seed OSPA under raster; renyi adds RENYI, oracle adds -0.5
BASE = {"null": 2.0, "truth-aided": 0.25, "gpf": 1.0, "kfnn": 1.5}
RENYI = {"null": 0.0, "truth-aided": 0.0, "gpf": -0.25, "kfnn": 0.125}
SEED = [0.0, 0.125, -0.125, 0.25]


def _runs(policies=("raster", "renyi", "oracle")) -> pd.DataFrame:
    rows = []
    for pol in policies:
        for lab, base in BASE.items():
            for seed, noise in enumerate(SEED):
                v = base + noise + (RENYI[lab] if pol == "renyi" else
                                    -0.5 if pol == "oracle" else 0.0)
                failed = lab == "kfnn" and pol == "oracle" and seed == 3
                rows.append({"scenario": "a", "looks_per_step": 24, "tracker": lab,
                             "tracker_label": lab, "policy_label": pol, "seed": seed,
                             "status": "error" if failed else "ok",
                             "ospa": math.nan if failed else v,
                             "tracker_uses_truth": lab == "truth-aided",
                             "policy_uses_truth": pol == "oracle"})
    return pd.DataFrame(rows)


def test_beyond_noise_needs_the_interval_strictly_above_zero():
    assert not pa._beyond(0.0, 0.0)
    assert not pa._beyond(0.1, 0.1)
    assert pa._beyond(0.1, 0.05)
    assert not pa._beyond(0.1, math.nan)


def test_one_policy_is_not_several():
    assert not pa.several(_runs(("raster",)))
    assert pa.several(_runs(("raster", "renyi")))


def test_means_equal_but_for_summation_order_tie_by_label():
    wide = pd.DataFrame({("a", "raster"): [0.1, 0.2, 0.3], ("b", "raster"): [0.3, 0.2, 0.1]})
    # summed in order, a's mean is the larger in its last bit: a tie to 12 digits
    assert wide[("a", "raster")].mean() > wide[("b", "raster")].mean()
    best = pa.best_pair(wide)
    assert (best["tracker_label"], best["runner_tracker"]) == ("a", "b")
    assert not best["beyond_noise"]


def test_the_differences_are_against_the_first_policy():
    axis = pa.policy_axis(_runs(), order=["raster", "renyi", "oracle"])
    assert set(axis.diffs["base_label"]) == {"raster"}
    gpf = axis.diffs[(axis.diffs["tracker_label"] == "gpf")
                     & (axis.diffs["policy_label"] == "renyi")]
    assert gpf["diff_mean"].iloc[0] == -0.25


def test_the_best_pair_is_a_contestant_under_a_policy_without_the_truth():
    axis = pa.policy_axis(_runs(), order=["raster", "renyi", "oracle"])
    best = axis.best.iloc[0]
    # gpf under oracle (0.5 + noise) is least, but the oracle uses the truth
    assert (best["tracker_label"], best["policy_label"]) == ("gpf", "renyi")


def test_the_display_table_marks_both_signs_and_counts_the_fewest_pairs():
    axis = pa.policy_axis(_runs(), order=["raster", "renyi", "oracle"])
    (head, table), = pa.display_tables(axis)
    rows = table.set_index(table["tracker"].str.replace(" (uses truth)", "", regex=False))
    renyi = [c for c in table.columns if c.startswith("renyi − ")][0]
    assert rows.loc["gpf", renyi] == "-0.250 ± 0.000" + pa.BEYOND_NOISE_MARK
    assert rows.loc["kfnn", renyi] == "+0.125 ± 0.000" + pa.BEYOND_NOISE_MARK
    assert rows.loc["null", renyi] == "+0.000 ± 0.000"
    assert int(rows.loc["kfnn", "pairs"]) == 3  # 4 under renyi, 3 under the oracle
    assert int(rows.loc["gpf", "pairs"]) == 4


def test_the_display_rows_run_floor_then_best_first_then_ceiling():
    axis = pa.policy_axis(_runs(("raster", "renyi")), order=["raster", "renyi"])
    (_, table), = pa.display_tables(axis)
    names = [t.replace(" (uses truth)", "") for t in table["tracker"]]
    assert names == ["null", "gpf", "kfnn", "truth-aided"]


def test_no_bayes_line_where_no_policy_has_a_reference():
    axis = pa.policy_axis(_runs(("raster", "renyi")))
    assert axis.bayes_policies == {("a", 24): set()}
    assert pa.bayes_lines(axis) == []

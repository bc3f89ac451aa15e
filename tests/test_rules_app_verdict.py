"""Rules of the report's verdict (``benchmarks/app/verdict.py``) on per-run rows built
by hand where a slip shows: contestants whose label order and difference order disagree,
a difference of exactly zero, two contestants behind the leader beyond noise, the costs
of trackers over one and two groups. The differences are constant per seed, so their
means and half-widths are exact."""

from __future__ import annotations

import pandas as pd

from mttbench.benchmarks.app import summary, verdict

#: per-seed OSPA: a leads; c is 0.25 behind, b 0.5 behind, d level (identical to a)
VALUES = {"a": [1.0, 1.25, 0.75, 1.0], "b": [1.5, 1.75, 1.25, 1.5],
          "c": [1.25, 1.5, 1.0, 1.25], "d": [1.0, 1.25, 0.75, 1.0]}


def _runs(values=VALUES) -> pd.DataFrame:
    rows = [{"scenario": "s", "policy_label": "raster", "looks_per_step": 24, "seed": seed,
             "tracker": lab, "tracker_label": lab, "status": "ok", "ospa": v}
            for lab, per in values.items() for seed, v in enumerate(per)]
    return pd.DataFrame(rows)


def test_the_others_are_ordered_by_their_difference():
    leader, mean, _, others = verdict.leader_comparison(_runs(), {"a", "b", "c"})
    assert (leader, mean) == ("a", 1.0)
    assert list(others["tracker_label"]) == ["c", "b"]
    assert list(others["diff_mean"]) == [0.25, 0.5]


def test_a_zero_difference_is_level_not_beyond_noise():
    assert not verdict._beyond_noise(0.0, 0.0)
    assert verdict._beyond_noise(0.25, 0.0)


def test_the_verdict_names_the_nearest_behind_and_the_level_ones():
    runs = _runs()
    gc = summary.gap_closed(runs)
    (line,) = verdict.group_lines(runs, gc)
    # a and d tie on the mean; the leader is the first label
    assert "`a` leads" in line
    assert "level within noise: `d` (+0.000 ± 0.000)" in line
    assert "ahead of the next, `c`, by 0.250 ± 0.000 (paired, 4 seeds)" in line


def test_the_cost_line_is_cheapest_first_with_the_range_over_groups():
    summ = pd.DataFrame({"tracker_label": ["slow", "fast", "slow", "fast"],
                         "tracker_wall_s_mean": [4e-3, 1e-3, 2e-3, 3e-3]})
    assert verdict.cost_line(summ) == (
        "Cost, tracker ms per step (mean over the scenarios; range over them), cheapest "
        "first: `fast` 2 (1-3), `slow` 3 (2-4).")
    one = summ.iloc[:2]
    assert verdict.cost_line(one) == (
        "Cost, tracker ms per step (mean over the scenarios; range over them), cheapest "
        "first: `fast` 1, `slow` 4.")

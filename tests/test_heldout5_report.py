"""The report's comparisons when several contestants trail: the verdict says the leader
is ahead of the NEAREST contestant behind it beyond noise; the policy axis breaks equal
means by tracker, then policy; the gap's floor is the bare floor tracker's label, else
the first of its labels in sorted order. References: the paired differences written out
from per-seed means chosen by hand (as tests/test_report_verdict.py's synthetic runs) and
the documented tie rules."""

from __future__ import annotations

import numpy as np
import pandas as pd
from test_report_verdict import WALL_MS, frame

from mttbench.benchmarks.app import policy_axis, summary, verdict

NOISE = np.array([0.01, -0.02, 0.015, -0.01, 0.0, 0.005])


def test_the_leader_is_said_to_be_ahead_of_the_nearest_contestant_behind_it():
    gpf = np.array([1.0, 1.2, 0.9, 1.1, 1.0, 0.95])
    per_seed = {("s", "null"): [2.0] * 6,
                ("s", "truth-aided"): [0.5, 0.6, 0.4, 0.5, 0.55, 0.45],
                ("s", "gpf"): list(gpf),
                ("s", "pmb"): list(gpf + 0.6 + NOISE),
                ("s", "kfnn"): list(gpf + 0.3 - NOISE)}
    runs = summary.per_run(frame(per_seed, WALL_MS))
    line = verdict.group_lines(runs, summary.gap_closed(runs))[0]
    behind = {lab: float(np.mean(np.array(per_seed[("s", lab)]) - gpf))
              for lab in ("pmb", "kfnn")}
    nearest = min(behind, key=behind.get)
    assert nearest == "kfnn"
    assert f"ahead of the next, `{nearest}`, by {behind[nearest]:.3f}" in line


def test_equal_means_are_broken_by_tracker_then_policy():
    """Two pairs of equal mean: the best is the one whose tracker label sorts first,
    whatever the policy labels; with the same tracker, the policy label decides."""
    v = [1.0, 2.0, 3.0]
    wide = pd.DataFrame({("b", "a-policy"): v, ("a", "z-policy"): v, ("c", "0"): [9.0] * 3})
    best = policy_axis.best_pair(wide)
    assert (best["tracker_label"], best["policy_label"]) == ("a", "z-policy")
    assert (best["runner_tracker"], best["runner_policy"]) == ("b", "a-policy")
    wide = pd.DataFrame({("a", "y"): v, ("a", "x"): v})
    assert policy_axis.best_pair(wide)["policy_label"] == "x"


def test_the_floor_is_the_bare_floor_label_else_the_first_of_its_labels():
    runs = pd.DataFrame({"tracker": ["null", "null", "gpf"],
                         "tracker_label": ["null(b=2)", "null(a=1)", "gpf"]})
    assert summary._pick_label(runs, "null") == "null(a=1)"
    with_bare = pd.concat([runs, pd.DataFrame({"tracker": ["null"], "tracker_label": ["null"]})])
    assert summary._pick_label(with_bare, "null") == "null"
    assert summary._pick_label(runs, "kfnn") is None

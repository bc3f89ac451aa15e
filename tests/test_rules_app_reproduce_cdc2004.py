"""Rules of the non-myopic reproduction's check (``reproduce_cdc2004.py``) on per-seed
rows built by hand where a slip shows: a paired interval that straddles 0 while its mean
does not, one paired seed, steps that made every look, a lost fraction. The interval is
recomputed with the tabulated Student t quantile."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from mttbench.benchmarks.app import reproduce_cdc2004 as cdc
from mttbench.benchmarks.engine.specs import TrackerSpec

T975_2 = 4.302652729911275


def _per_seed(diffs, tracker: str = "t") -> pd.DataFrame:
    rows = []
    for seed, d in enumerate(diffs):
        rows.append({"tracker_label": tracker, "policy": "renyi", "seed": seed,
                     "ospa": 1.0, "lost": False})
        rows.append({"tracker_label": tracker, "policy": "lookahead", "seed": seed,
                     "ospa": 1.0 + d, "lost": seed == 0})
    return pd.DataFrame(rows)


def test_the_paired_interval_is_the_t_interval_of_the_differences():
    d = np.array([0.3, -0.1, 0.1])
    half = T975_2 * d.std(ddof=1) / math.sqrt(3)
    out = cdc.paired_table(_per_seed(d), cdc.SETTINGS["reduced"])
    assert out.loc[0, "diff_mean"] == pytest.approx(0.1)
    assert out.loc[0, "diff_low"] == pytest.approx(0.1 - half)
    assert out.loc[0, "diff_high"] == pytest.approx(0.1 + half)


def test_the_verdict_resolves_a_difference_only_beyond_its_interval():
    setting = cdc.SETTINGS["reduced"]
    straddle = cdc.paired_table(_per_seed([-0.3, 0.1, -0.1]), setting)  # mean -0.1
    (line,) = cdc.verdict_lines(straddle, setting)
    assert "no difference resolved" in line
    better = cdc.paired_table(_per_seed([-0.3, -0.25, -0.35]), setting)
    (line,) = cdc.verdict_lines(better, setting)
    assert "lookahead beats renyi" in line


def test_short_steps_are_only_those_with_fewer_looks():
    res = pd.DataFrame({"step": [0, 1, 2], "status": "ok", "n_looks": [24, 23, 24],
                        "looks_per_step": 24})
    assert list(cdc.short_steps(res)["step"]) == [1]


def test_the_lost_fraction_is_a_fraction():
    table = cdc.policy_table(_per_seed([0.0, 0.0, 0.0, 0.0]))
    lost = table.set_index("policy")["lost_fraction"]
    assert lost["lookahead"] == 0.25 and lost["renyi"] == 0.0


def _results(diffs) -> pd.DataFrame:
    """Step rows of tracker null under both policies, 12 steps each (burn-in 10)."""
    rows = []
    for seed, d in enumerate(diffs):
        for pol, extra in (("renyi", 0.0), ("lookahead", d)):
            for step in range(12):
                rows.append({"scenario": "occlusion", "tracker_label": "null",
                             "policy": pol, "policy_label": pol, "looks_per_step": 24,
                             "seed": seed, "step": step, "status": "ok", "error": "",
                             "ospa": 1.0 + extra, "own_count_error": 0.0,
                             "count_error": 0.0, "est_count": 0.0, "true_count": 3.0,
                             "n_looks": 24})
    return pd.DataFrame(rows)


def test_the_check_needs_two_paired_seeds_and_fails_only_beyond_noise():
    spec = [TrackerSpec("null")]
    one = dataclasses.replace(cdc.SETTINGS["reduced"], n_steps=12, seeds=(0,))
    check = cdc.check(one, spec, _results([0.0]))
    assert "null: fewer than 2 paired seeds" in check.lines
    three = dataclasses.replace(one, seeds=(0, 1, 2))
    check = cdc.check(three, spec, _results([0.3, -0.1, 0.1]))  # worse on average only
    assert not any("worse than" in line for line in check.lines)
    check = cdc.check(three, spec, _results([0.3, 0.25, 0.35]))
    assert any("null: lookahead is worse than renyi beyond noise" in line
               for line in check.lines)

"""Rules of the managed-versus-periodic reproduction (``reproduce_kreucher.py``) on
hand-built runs where a slip shows: a run whose final OSPA sits exactly at the lost
threshold, a burn-in step that counts, a raster of exactly one look per cell, a managed
error equal to the smallest budget's, an interpolation between two budgets worked out by
hand on ``log(looks)``, a crossing whose after-window ends on the run's last step."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from mttbench.benchmarks.app import reproduce_kreucher as rk
from mttbench.benchmarks.engine.specs import TrackerSpec


def _run(ospa, seed: int = 0, policy: str = "raster", looks: int = 144,
         tracker: str = "gpf", status: str = "ok") -> pd.DataFrame:
    n = len(ospa)
    return pd.DataFrame({
        "scenario": "kreucher", "tracker_label": tracker, "policy": policy,
        "policy_label": policy, "looks_per_step": looks, "seed": seed, "step": range(n),
        "status": status, "ospa": ospa, "own_count_error": 0.0, "count_error": 5.0,
        "est_count": 3.0, "true_count": 3.0})


def test_per_seed_means_from_the_burn_in_and_the_last_window():
    # 6 steps, burn-in 2: OSPA of steps 2..5; last window 3: steps 3..5
    ospa = [9.0, 9.0, 0.5, 1.0, 1.0, 1.0]
    out = rk.per_seed(_run(ospa), burn_in=2, lost_window=3, lost_ospa=1.0)
    assert out.loc[0, "ospa"] == pytest.approx((0.5 + 1.0 + 1.0 + 1.0) / 4)
    assert out.loc[0, "ospa_final"] == pytest.approx(1.0)
    assert bool(out.loc[0, "lost"])  # exactly at the threshold: lost
    assert out.loc[0, "count_error"] == 0.0  # the tracker's own count's error


def test_a_seed_just_below_the_lost_threshold_is_kept():
    out = rk.per_seed(_run([1.0, 1.0, 0.5, 0.5]), burn_in=0, lost_window=2, lost_ospa=0.75)
    assert out.loc[0, "ospa_final"] == pytest.approx(0.5)
    assert not bool(out.loc[0, "lost"])


@pytest.mark.parametrize(("looks", "cells", "text"), [
    (24, 144, "no"), (144, 144, "no"), (288, 144, "every cell 2x"),
    (216, 144, "every cell 1x, 72 cells twice"), (312, 144, "every cell 2x, 24 cells 3x")])
def test_revisits_of_a_raster(looks, cells, text):
    assert rk.revisits(looks, cells) == text


def test_the_curve_table_median_is_the_median():
    runs = pd.DataFrame({"scenario": "kreucher", "tracker_label": "gpf", "policy": "raster",
                         "policy_label": "raster", "looks_per_step": 24, "seed": [0, 1, 2],
                         "ospa": [1.0, 2.0, 6.0], "count_error": 0.0, "est_count": 3.0,
                         "true_count": 3.0, "lost": [False, False, True]})
    curve = rk.curve_table(runs, rk.SETTINGS["reduced"])
    assert curve.loc[0, "ospa_median"] == 2.0
    assert curve.loc[0, "ospa_mean"] == 3.0
    assert curve.loc[0, "lost_fraction"] == pytest.approx(1 / 3)


def test_matched_looks_on_the_curve_and_between_two_budgets():
    looks, errors = [24, 48, 96], [2.0, 1.0, 0.5]
    assert rk.matched_looks(looks, errors, 2.0) == rk.Match(24.0, 0)  # on the first point
    assert rk.matched_looks(looks, errors, 2.5) == rk.Match(24.0, -1)
    assert rk.matched_looks(looks, errors, 0.25) == rk.Match(96.0, +1)
    # 1.75 between 2.0 (24) and 1.0 (48): a quarter of the way in log(looks)
    m = rk.matched_looks(looks, errors, 1.75)
    assert m.bound == 0
    assert m.looks == pytest.approx(math.exp(math.log(24) + 0.25 * math.log(2)), rel=1e-12)


def _crossing_results(n_steps: int) -> pd.DataFrame:
    parts = []
    for seed in range(2):
        ospa = np.where(np.arange(n_steps) < 4, 1.0, 2.0) + 0.25 * seed
        parts.append(_run(ospa, seed=seed, looks=144))
    return pd.concat(parts, ignore_index=True)


def test_a_crossing_whose_window_ends_on_the_last_step_counts():
    """Crossing at step 4, window 4, run of 8 steps: [0, 4) before, [4, 8) after, both
    inside the run; before 1.0 (+0.25 seed 1), after 2.0 (+0.25): ratio 2.25/1.25."""
    setting = dataclasses.replace(rk.SETTINGS["reduced"], n_steps=8)
    out = rk.crossing_table(_crossing_results(8), setting, crossings=(4,), window=4)
    assert len(out) == 1
    assert out.loc[0, "ospa_before"] == pytest.approx(1.125)
    assert out.loc[0, "ospa_after"] == pytest.approx(2.125)
    assert out.loc[0, "ratio"] == pytest.approx(2.125 / 1.125)
    # one step shorter: the after-window no longer fits
    short = dataclasses.replace(setting, n_steps=7)
    assert rk.crossing_table(_crossing_results(7), short, crossings=(4,), window=4).empty


def test_the_managed_policies_run_at_the_settings_budget():
    setting = dataclasses.replace(rk.SETTINGS["reduced"], managed_looks=12, snrs=(10.0,),
                                  raster_looks=(144,), seeds=(0,), n_steps=2)
    jobs = rk.setting_jobs(setting, [TrackerSpec("null")])
    managed = [j for j in jobs if j.policy.name != rk.PERIODIC]
    assert managed and {j.looks_per_step for j in managed} == {12}

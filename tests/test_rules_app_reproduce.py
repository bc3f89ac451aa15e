"""Rules of ``mttbench reproduce paper --check`` (``benchmarks/app/reproduce.py``) on
hand-built numbers tables where a slip shows: a curve exactly one band from its
reference on average, two half-widths whose sum and quadrature differ, a mean on one side
only, a count curve whose floor is ``1 / n_seeds``, the snapshot's truth against its
estimates, NaN against NaN. The expected verdicts follow from the documented formula
``|now - ref| / (sqrt(h_ref^2 + h_now^2) + floor)`` worked out by hand; nothing is run."""

from __future__ import annotations

import dataclasses
import math

import pandas as pd

from mttbench.benchmarks.app import reproduce
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec


def _curve(quantity: str, values, halves, n_seeds: int = 4, tracker: str = "gpf"
           ) -> pd.DataFrame:
    """An error-figure curve: the quantity, its ``_ci95`` and ``n_seeds`` per step."""
    rows = []
    for step, (v, h) in enumerate(zip(values, halves, strict=True)):
        for q, x in ((quantity, v), (f"{quantity}_ci95", h), ("n_seeds", n_seeds)):
            rows.append({"figure": "error", "scenario": "paper", "tracker": tracker,
                         "step": step, "item": 0, "quantity": q, "value": float(x)})
    return pd.DataFrame(rows)


def test_a_count_curve_one_band_off_on_average_passes():
    """est_count at n = 4 seeds: floor 1/4, no interval: a difference of exactly 0.25 at
    every step is a ratio of 1, the limit (inclusive); 0.5 fails."""
    ref = _curve("est_count", [1.0, 2.0], [0.0, 0.0])
    assert reproduce.check_numbers(_curve("est_count", [1.25, 2.25], [0.0, 0.0]), ref).passed
    assert not reproduce.check_numbers(_curve("est_count", [1.5, 2.5], [0.0, 0.0]), ref).passed


def test_the_band_combines_the_two_half_widths_in_quadrature():
    """h_ref = 0.4, h_now = 0.3: band 0.5, + floor 0.05 = 0.55; a difference of 0.6 is a
    ratio of 1.09 (fails); the plain sum 0.75 + 0.05 would give 0.75 (pass)."""
    ref = _curve("state_error", [1.0], [0.4])
    check = reproduce.check_numbers(_curve("state_error", [1.6], [0.3]), ref)
    assert not check.passed
    assert "band +-0.5 + floor 0.05, ratio 1.09" in "\n".join(check.lines)


def test_a_mean_on_one_side_only_fails():
    ref = _curve("state_error", [math.nan, 1.0], [math.nan, 0.1])
    check = reproduce.check_numbers(_curve("state_error", [1.0, 1.0], [0.1, 0.1]), ref)
    assert not check.passed


def test_every_step_outside_its_band_is_named():
    """Two steps at a ratio of 2 each (count floor 1/4, a difference of 0.5): the curve
    fails on its mean, and both steps are outside their band (ratio > 1) though inside
    the single-step limit."""
    ref = _curve("count_error", [1.0, 1.0], [0.0, 0.0])
    check = reproduce.check_numbers(_curve("count_error", [1.5, 1.5], [0.0, 0.0]), ref)
    assert check.n_moved == 2
    assert sum(line.startswith("  figure=error") for line in check.lines) == 2


def _snapshot(px: float, state_px: float) -> pd.DataFrame:
    return pd.DataFrame([
        {"figure": "snapshot", "scenario": "paper", "tracker": "gpf", "step": 3, "item": 0,
         "quantity": "truth.px", "value": px},
        {"figure": "snapshot", "scenario": "paper", "tracker": "gpf", "step": 3, "item": 0,
         "quantity": "state.px", "value": state_px}])


def test_check_compares_the_snapshots_truth_and_not_its_estimates():
    ref = _snapshot(4.5, 4.0)
    assert reproduce.check_numbers(_snapshot(4.5, 7.0), ref).passed
    assert not reproduce.check_numbers(_snapshot(4.75, 4.0), ref).passed
    assert not reproduce.check_numbers(_snapshot(4.5, 7.0), ref, exact=True).passed


def test_exact_check_takes_nan_for_nan():
    ref = _curve("rmse", [math.nan, 1.0], [math.nan, 0.1])
    assert reproduce.check_numbers(ref.copy(), ref, exact=True).passed


# ------------------------------------------------------------------ numbers
def test_the_count_error_curve_is_the_trackers_own_count():
    rows = []
    for seed in range(2):
        rows.append({"scenario": "paper", "tracker_label": "gpf", "seed": seed, "step": 0,
                     "status": "ok", "ospa": 1.0, "own_count_error": 0.5 + seed,
                     "count_error": 3.0, "rmse": 1.0, "est_count": 2.0, "true_count": 3.0})
    curves = reproduce.error_curves(pd.DataFrame(rows))
    assert curves.loc[0, "count_error"] == 1.0  # mean of 0.5 and 1.5


def test_long_numbers_hold_only_the_fields_each_snapshot_item_has():
    curves = pd.DataFrame(columns=["scenario", "tracker_label", "step", "state_error",
                                   "state_error_ci95", "count_error", "count_error_ci95",
                                   "rmse", "est_count", "est_count_ci95", "true_count",
                                   "n_seeds"])
    snap = pd.DataFrame([
        {"step": 3, "item": 0, "kind": "estimate", "count": 2.0},
        {"step": 3, "item": 0, "kind": "look", "cell": 5, "positive": 1},
        {"step": 3, "item": 0, "kind": "truth", "px": 1.5, "py": 2.5, "id": 7}])
    out = reproduce.long_numbers(curves, {"paper": snap}, "gpf")
    assert out["value"].notna().all()
    assert sorted(out["quantity"]) == sorted(["estimate.count", "look.cell", "look.positive",
                                              "truth.px", "truth.py", "truth.id"])


def test_read_numbers_keeps_the_tracker_named_null_and_reads_empty_as_nan(tmp_path):
    path = tmp_path / "n.csv"
    path.write_text("figure,scenario,tracker,step,item,quantity,value\n"
                    "error,paper,null,0,0,state_error,2.0\n"
                    "error,paper,null,0,0,rmse,\n")
    df = reproduce.read_numbers(path)
    assert list(df["tracker"]) == ["null", "null"]
    assert df["value"].iloc[0] == 2.0 and math.isnan(df["value"].iloc[1])


def test_the_cache_key_holds_the_trackers_parameters():
    setting = dataclasses.replace(reproduce.SETTINGS["reduced"], scenarios=("default",))
    pol = PolicySpec("raster")
    a = reproduce.cache_key(setting, [TrackerSpec("jmpd", {"n_particles": 200})], pol, env={})
    b = reproduce.cache_key(setting, [TrackerSpec("jmpd", {"n_particles": 1000})], pol, env={})
    assert a != b


def test_changed_versions_names_an_entry_recorded_only_now():
    now = reproduce.reference_versions()
    then = {k: v for k, v in now.items() if k != "numpy"}
    assert reproduce.changed_versions(then) == [f"numpy None -> {now['numpy']}"]
    then = {**now, "retired": "1.0"}
    assert reproduce.changed_versions(then) == ["retired 1.0 -> None"]

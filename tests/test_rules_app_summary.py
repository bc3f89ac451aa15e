"""Rules of the summary statistics (``benchmarks/app/summary.py``) on hand-built tables
where a slip shows: a run with both an unsupported and a failed step, step times whose
median, mean and 95th percentile differ, a failed step with the run's peak memory, a
pair whose difference is NaN, a gap exactly at its threshold, a Bayes share exactly one
half. The expected values are recomputed from the inputs by hand (closed forms, the
tabulated Student t quantile), not read from the code."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from mttbench.benchmarks.app import summary

#: t_{0.975, 3} and t_{0.975, 2} from the tables
T975_3 = 3.182446305284263
T975_2 = 4.302652729911275


def _steps(statuses, wall, select=None, rss=None, **cols) -> pd.DataFrame:
    """One run's step rows (scenario a, tracker x, raster, 24 looks, seed 0)."""
    n = len(statuses)
    df = pd.DataFrame({
        "scenario": "a", "tracker": "x", "tracker_label": "x", "policy_label": "raster",
        "looks_per_step": 24, "seed": 0, "step": range(n), "status": statuses,
        "error": ["" if s == "ok" else f"{s} at {k}" for k, s in enumerate(statuses)],
        "ospa": 1.0, "tracker_wall_s": wall, "tracker_cpu_s": wall,
        "select_wall_s": select if select is not None else [0.0] * n,
        "peak_rss_mb": rss if rss is not None else [100.0] * n})
    for k, v in cols.items():
        df[k] = v
    return df


# ---------------------------------------------------------------------- per_run
def test_a_run_with_an_unsupported_and_a_failed_step_is_unsupported():
    run = summary.per_run(_steps(["ok", "error", "unsupported"], [1e-3] * 3))
    assert run.loc[0, "status"] == "unsupported"
    assert run.loc[0, "error"] == "error at 1"  # the first message in step order


def test_per_run_times_median_p95_max_and_mean_selection():
    wall = [k * 1e-3 for k in range(1, 21)]  # 1..20 ms
    run = summary.per_run(_steps(["ok"] * 20, wall, select=[1e-3, 2e-3, 9e-3] + [3e-3] * 17))
    # linear interpolation: the 95th percentile of 1..20 sits at 0.95 * 19 = 18.05
    assert run.loc[0, "tracker_wall_p95_s"] == pytest.approx((19 + 0.05) * 1e-3, rel=1e-12)
    assert run.loc[0, "tracker_wall_s"] == pytest.approx(10.5e-3, rel=1e-12)
    assert run.loc[0, "tracker_wall_max_s"] == pytest.approx(20e-3, rel=1e-12)
    # the selection time is a mean, (1 + 2 + 9 + 17 * 3) / 20 = 3.15 ms (its median: 3)
    assert run.loc[0, "select_wall_s"] == pytest.approx((1 + 2 + 9 + 51) / 20 * 1e-3,
                                                        rel=1e-12)


def test_the_peak_memory_includes_the_failed_steps():
    run = summary.per_run(_steps(["ok", "error"], [1e-3, 1e-3], rss=[100.0, 300.0]))
    assert run.loc[0, "peak_rss_mb"] == 300.0


def test_a_run_that_failed_part_way_has_no_track_score():
    ok = summary.per_run(_steps(["ok", "ok"], [1e-3] * 2, id_switches=[4.0, 4.0]))
    assert ok.loc[0, "id_switches"] == 4.0
    bad = summary.per_run(_steps(["ok", "error"], [1e-3] * 2, id_switches=[4.0, 4.0]))
    assert math.isnan(bad.loc[0, "id_switches"])


def _per_run_by_pandas(results: pd.DataFrame) -> pd.DataFrame:
    """The per-run table the plain way: pandas statistics of each run's own rows (the
    definition :func:`summary.per_run` computes from arrays)."""
    steps, track = summary.step_metrics_of(results), summary.track_metrics_of(results)
    carry = [c for c in ("tracker", "policy", "tracker_uses_truth", "policy_uses_truth")
             if c in results.columns]
    out = []
    for key, g in results.groupby(summary.RUN_KEYS, sort=True):
        ok = g[g["status"] == "ok"]
        statuses = set(g["status"])
        row = dict(zip(summary.RUN_KEYS, key, strict=True))
        row.update({c: g[c].iloc[0] for c in carry})
        row["status"] = ("ok" if statuses == {"ok"}
                         else "unsupported" if "unsupported" in statuses else "error")
        bad = g.loc[g["status"] != "ok", "error"]
        row["error"] = str(bad.iloc[0]) if len(bad) else ""
        row["n_steps"] = len(ok)
        for m in steps:
            row[m] = ok[m].astype(float).dropna().mean() if ok[m].notna().any() else math.nan
        for m in track:
            row[m] = float(ok[m].iloc[0]) if statuses == {"ok"} else math.nan
        wall = ok["tracker_wall_s"]
        row["tracker_wall_s"] = float(np.median(wall)) if len(ok) else math.nan
        row["tracker_wall_p95_s"] = float(np.quantile(wall, 0.95)) if len(ok) else math.nan
        row["tracker_wall_max_s"] = float(wall.max()) if len(ok) else math.nan
        row["tracker_cpu_s"] = float(ok["tracker_cpu_s"].median()) if len(ok) else math.nan
        row["select_wall_s"] = float(ok["select_wall_s"].mean()) if len(ok) else math.nan
        row["peak_rss_mb"] = float(g["peak_rss_mb"].max())
        out.append(row)
    return pd.DataFrame(out)


def test_per_run_equals_the_statistics_of_each_runs_own_rows():
    """Runs interleaved in a shuffled table (a run's rows are not together), with failed
    and unsupported steps, NaN metrics and times, a track score, a row whose key is NaN
    (no run: groupby leaves it out) and 9-31 steps a run (numpy's pairwise sum blocks):
    every value equal to the pandas statistics of the run's own rows, bit for bit."""
    rng = np.random.default_rng(7)
    frames = []
    for seed in range(4):
        for label in ("x", "y(n=2)"):
            for policy in ("raster", "renyi"):
                n = int(rng.integers(9, 32))
                statuses = rng.choice(["ok"] * 8 + ["error", "unsupported"], n).tolist()
                if seed == 0:
                    statuses = ["ok"] * n  # whole runs, with their track score
                wall = rng.exponential(1e-3, n)
                run = _steps(statuses, wall, select=rng.exponential(1e-4, n),
                             rss=rng.uniform(90, 110, n), ospa=rng.uniform(0, 2, n),
                             rmse=np.where(rng.random(n) < 0.3, np.nan, rng.random(n)),
                             id_switches=float(rng.integers(0, 5)))
                run["tracker_cpu_s"] = np.where(rng.random(n) < 0.2, np.nan, wall)
                run["tracker_label"], run["policy_label"], run["seed"] = label, policy, seed
                frames.append(run)
    table = pd.concat(frames, ignore_index=True)
    table.loc[5, "looks_per_step"] = np.nan
    table = table.sample(frac=1.0, random_state=3).reset_index(drop=True)
    got = summary.per_run(table)
    want = _per_run_by_pandas(table)
    assert len(got) == 4 * 2 * 2 and "id_switches" in summary.track_metrics_of(table)
    assert (got["status"] != "ok").any() and (got["status"] == "ok").any()
    pd.testing.assert_frame_equal(got[list(want.columns)], want, check_exact=True,
                                  check_dtype=False)


# ----------------------------------------------------------------- mean_ci95
def test_mean_ci95_is_the_student_t_half_width_with_n_minus_one_degrees():
    v = np.array([1.0, 2.0, 3.0, 6.0])
    sd = math.sqrt(sum((x - 3.0) ** 2 for x in v) / 3)
    mean, half = summary.mean_ci95(v)
    assert mean == 3.0
    assert half == pytest.approx(T975_3 * sd / 2.0, rel=1e-9)


def test_ratio_ci95_is_the_delta_method_over_the_mean_of_b():
    a, b = np.array([1.0, 2.0, 4.0]), np.array([2.0, 3.0, 4.0])
    r = 7.0 / 9.0
    d = (a - r * b) / 3.0
    sd = math.sqrt(sum((x - d.mean()) ** 2 for x in d) / 2)
    share, half = summary.ratio_ci95(a, b)
    assert share == pytest.approx(r, rel=1e-12)
    assert half == pytest.approx(T975_2 * sd / math.sqrt(3), rel=1e-9)


# ----------------------------------------------------------------- summarize
def _runs(rows) -> pd.DataFrame:
    """Per-run rows ``(scenario, tracker label, seed, status, ospa)``."""
    out = []
    for sc, lab, seed, status, ospa in rows:
        out.append({"scenario": sc, "tracker": summary.tracker_name(lab), "tracker_label": lab,
                    "policy_label": "raster", "looks_per_step": 24, "seed": seed,
                    "status": status, "error": "" if status == "ok" else "boom",
                    "ospa": ospa, "rmse": ospa})
    return pd.DataFrame(out)


def test_the_failure_note_counts_all_runs_of_the_row():
    runs = _runs([("a", "x", 0, "ok", 1.0), ("a", "x", 1, "ok", 1.0),
                  ("a", "x", 2, "error", math.nan)])
    summ = summary.summarize(runs, metrics=["ospa"])
    assert summ.loc[0, "note"] == "failed in 1 of 3 runs: boom"


def test_paired_seeds_count_only_the_defined_differences():
    runs = _runs([("a", "ref", s, "ok", 1.0) for s in range(3)]
                 + [("a", "x", 0, "ok", 0.5), ("a", "x", 1, "ok", math.nan),
                    ("a", "x", 2, "ok", 0.75)])
    diff = summary.paired_difference(runs, "ref", "rmse")
    assert int(diff.loc[0, "n_seeds"]) == 2
    assert diff.loc[0, "diff_mean"] == pytest.approx(-0.375)


def test_run_failures_names_the_policy_when_only_the_policies_differ():
    steps = pd.concat([_steps(["ok", "ok"], [1e-3] * 2),
                       _steps(["ok", "error"], [1e-3] * 2).assign(policy_label="renyi")])
    k, n, first = summary.run_failures(steps)
    assert (k, n) == (1, 2)
    assert first == "a/x/renyi/24 looks/seed 0: error at 1 (step 1)"


# ---------------------------------------------------------------- crossings
def _series_run(seed: int, switches, near, crossings) -> pd.DataFrame:
    n = len(switches)
    return pd.DataFrame({
        "scenario": "a", "tracker": "x", "tracker_label": "x", "policy_label": "raster",
        "looks_per_step": 24, "seed": seed, "step": range(n), "status": "ok",
        "id_switches_step": switches, "crossings_near": near, "crossings": crossings})


def test_the_switch_rates_divide_by_their_own_steps():
    # 10 steps, 4 near a crossing: 1 switch near, 3 elsewhere
    run = _series_run(0, [0, 1, 0, 0, 1, 1, 0, 0, 1, 0],
                      [0, 1, 1, 1, 1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0, 0, 0, 0, 0])
    out = summary.crossing_switches(run)
    assert out.loc[0, "switches_near"] == 2.0  # steps 1 and 4
    assert out.loc[0, "switches_elsewhere"] == 2.0  # steps 5 and 8
    assert out.loc[0, "near_rate"] == pytest.approx(2 / 4)
    assert out.loc[0, "elsewhere_rate"] == pytest.approx(2 / 6)


def test_a_scenario_is_kept_when_some_run_has_a_crossing():
    runs = pd.concat([_series_run(0, [0, 1], [1, 1], [1, 0]),
                      _series_run(1, [0, 0], [0, 0], [0, 0])])
    out = summary.crossing_summary(runs)
    assert len(out) == 1 and int(out.loc[0, "n_seeds"]) == 2


# ------------------------------------------------------- floor and ceiling
def test_the_floor_is_the_bare_name_else_the_first_label_in_sorted_order():
    runs = _runs([("a", "null(b=2)", 0, "ok", 2.0), ("a", "null(a=1)", 0, "ok", 2.0)])
    assert summary._pick_label(runs, "null") == "null(a=1)"
    runs = _runs([("a", "null(b=2)", 0, "ok", 2.0), ("a", "null", 0, "ok", 2.0)])
    assert summary._pick_label(runs, "null") == "null"


def test_the_gap_thresholds_sides():
    """A gap of exactly MIN_GAP can rank (below it cannot); an interval that reaches 0
    exactly (gap == half) cannot."""
    assert summary._gap_reason(0.15, 0.01, 5, 0.15, "OSPA") == ""
    assert "is below 0.15" in summary._gap_reason(0.1499, 0.01, 5, 0.15, "OSPA")
    assert "reaches 0" in summary._gap_reason(0.5, 0.5, 5, 0.15, "OSPA")
    assert summary._gap_reason(0.5, 0.4999, 5, 0.15, "OSPA") == ""


def _trio(bayes: float) -> pd.DataFrame:
    rows = []
    for s, jitter in enumerate((0.0, 0.25, -0.25, 0.5)):
        rows += [("a", "null", s, "ok", 2.0 + jitter), ("a", "truth-aided", s, "ok", 1.0 + jitter),
                 ("a", "bayes", s, "ok", bayes + jitter), ("a", "gpf", s, "ok", 1.25 + jitter)]
    return _runs(rows)


def test_a_bayes_share_of_exactly_one_half_is_not_problem_limited():
    gc = summary.gap_closed(_trio(1.5))
    assert gc.gaps.loc[0, "bayes_share_mean"] == 0.5
    assert not gc.gaps.loc[0, "problem_limited"]
    assert summary.gap_closed(_trio(1.625)).gaps.loc[0, "problem_limited"]


def test_with_gap_closed_keeps_the_rows_without_a_share():
    runs = pd.concat([_trio(1.5), _runs([("b", "gpf", s, "ok", 1.0) for s in range(2)])])
    summ = summary.summarize(runs, metrics=["ospa"])
    out = summary.with_gap_closed(summ, summary.gap_closed(runs))
    assert len(out) == len(summ)
    b = out[out["scenario"] == "b"]
    assert len(b) == 1 and math.isnan(b["gap_closed_mean"].iloc[0])


def test_a_tracker_is_unlabelled_only_when_none_of_its_runs_has_a_score():
    runs = _runs([("a", "x", 0, "ok", 1.0), ("a", "x", 1, "ok", 1.0),
                  ("a", "y", 0, "ok", 1.0)])
    runs["id_switches"] = [2.0, math.nan, math.nan]
    assert summary.unlabelled_trackers(runs) == ["y"]

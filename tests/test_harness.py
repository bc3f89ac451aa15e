"""Harness (jobs, sweeps, parts, resume, parallel equality) and summary statistics."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mttbench import scenarios
from mttbench.benchmarks.app.summary import (
    mean_ci95,
    paired_difference,
    per_run,
    run_failures,
    summarize,
    to_markdown,
)
from mttbench.benchmarks.engine import loop as harness
from mttbench.benchmarks.engine.loop import COLUMNS, Job, build_jobs, run_job
from mttbench.benchmarks.engine.metrics import run_metric_columns, step_metrics
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec, parse_value, split_specs
from mttbench.benchmarks.engine.sweep import run_sweep
from mttbench.scenarios.simulator import simulate
from mttbench.trackers.base import Estimate, Tracker, register, unregister

#: one tolerance for float comparisons of recomputed statistics
TOL = 1e-12
TIMING = ["tracker_wall_s", "tracker_cpu_s", "select_wall_s", "select_cpu_s", "peak_rss_mb"]


def short(name: str, n_steps: int) -> scenarios.Scenario:
    return dataclasses.replace(scenarios.get(name), n_steps=n_steps)


# ---------------------------------------------------------------- test trackers
class Recorder(Tracker):
    """Reports one target at the first positive return's cell centre; records its looks
    and its first random draw, and counts resets (all class-level, for the tests)."""

    name = "test_recorder"
    summary = "test only"
    looks_seen: dict = {}
    draws: dict = {}
    resets = 0

    def __init__(self, tag: int = 0) -> None:
        self.tag = tag

    def reset(self, model, rng):
        type(self).resets += 1
        self._grid = model.grid
        self._key = (self.tag, len(type(self).draws))
        type(self).draws[self._key] = rng.random()
        self._est = Estimate.empty()
        self._k = 0

    def predict(self):
        pass

    def cell_count_distribution(self):
        P = np.zeros((self._grid.n_cells, 2))
        P[:, 0] = 1.0
        return P

    def update(self, looks):
        type(self).looks_seen.setdefault(self._key, []).append(looks.cells.copy())
        pos = looks.cells[looks.returns]
        if pos.size:
            xy = self._grid.cell_centers(pos[:1])[0]
            self._est = Estimate(1.0, np.array([[xy[0], 0.0, xy[1], 0.0]]))
        self._k += 1

    def estimate(self):
        return self._est


class CrashAt3(Recorder):
    name = "test_crash"

    def update(self, looks):
        if self._k == 3:
            raise RuntimeError("boom at step three")
        super().update(looks)


class Unsupported(Recorder):
    name = "test_unsupported"

    def unsupported_reason(self, model):
        return "cannot do this"


@pytest.fixture
def test_trackers():
    """Register the test trackers for one test, then remove them from the registry."""
    classes = [Recorder, CrashAt3, Unsupported]
    for cls in classes:
        register(cls)
    Recorder.looks_seen, Recorder.draws, Recorder.resets = {}, {}, 0
    yield
    for cls in classes:
        unregister(cls.name)


def strip_timing(df: pd.DataFrame) -> pd.DataFrame:
    return df.drop(columns=TIMING).reset_index(drop=True)


# ------------------------------------------------------------------------ specs
def test_parse_value_types():
    assert parse_value("1000") == 1000 and type(parse_value("1000")) is int
    assert parse_value("1e-3") == 1e-3 and type(parse_value("0.5")) is float
    assert parse_value("True") is True and parse_value("false") is False
    assert parse_value("global") == "global"


def test_tracker_spec_parse_and_label():
    spec = TrackerSpec.parse("jmpd:n_particles=1000,resample=true,alpha=0.5,mode=fast")
    assert spec.name == "jmpd"
    assert spec.params == {"n_particles": 1000, "resample": True, "alpha": 0.5, "mode": "fast"}
    assert spec.label == "jmpd(alpha=0.5,mode=fast,n_particles=1000,resample=True)"
    assert TrackerSpec.parse("kfnn").label == "kfnn"
    assert TrackerSpec.parse("kfnn") == TrackerSpec("kfnn", {})
    assert PolicySpec.parse("renyi:alpha=0.9").label == "renyi(alpha=0.9)"


@pytest.mark.parametrize("bad", ["", ":a=1", "kfnn:a", "kfnn:=1", "kfnn:a=1,a=2"])
def test_bad_spec_strings_refused(bad):
    with pytest.raises(ValueError):
        TrackerSpec.parse(bad)


def test_split_specs_keeps_parameters_together():
    assert split_specs(["raster,renyi:alpha=0.5,repeats=false", "all"]) == [
        "raster", "renyi:alpha=0.5,repeats=false", "all"]
    assert split_specs("kfnn") == ["kfnn"]


def test_build_jobs_dimensions():
    default, sup = short("default", 3), short("superposition", 3)
    trs = [TrackerSpec("null"), TrackerSpec("kfnn")]
    jobs = build_jobs([default, sup], trs, [PolicySpec("raster"), PolicySpec("renyi")],
                      [12, 24], [0, 1, 2])
    grid_jobs = [j for j in jobs if j.scenario.name == "default"]
    sup_jobs = [j for j in jobs if j.scenario.name == "superposition"]
    assert len(grid_jobs) == 2 * 2 * 2 * 3
    assert len(sup_jobs) == 2 * 3  # policy and looks do not apply
    assert all(j.policy is None and j.looks_per_step is None for j in sup_jobs)
    # looks default to the scenario's budget
    (job,) = build_jobs([default], trs[:1], None, None, [0])
    assert job.looks_per_step == default.model.sensor.looks_per_step
    assert job.policy == PolicySpec("raster")


def test_job_key_depends_on_everything_that_matters():
    sc = short("default", 5)
    base = Job(sc, TrackerSpec("null"), PolicySpec("raster"), 12, 0)
    assert base.key(2, 2) == Job(sc, TrackerSpec("null"), PolicySpec("raster"), 12, 0).key(2, 2)
    others = [
        Job(short("default", 6), TrackerSpec("null"), PolicySpec("raster"), 12, 0),
        Job(sc, TrackerSpec("kfnn"), PolicySpec("raster"), 12, 0),
        Job(sc, TrackerSpec("null"), PolicySpec("random"), 12, 0),
        Job(sc, TrackerSpec("null"), PolicySpec("raster"), 24, 0),
        Job(sc, TrackerSpec("null"), PolicySpec("raster"), 12, 1),
    ]
    keys = {base.key(2, 2), base.key(1, 2), base.key(2, 1), *(j.key(2, 2) for j in others)}
    assert len(keys) == 3 + len(others)


# ---------------------------------------------------------------------- run_job
def test_run_job_rows_and_metrics_match_direct_computation(test_trackers):
    sc = short("default", 12)
    job = Job(sc, TrackerSpec("test_recorder", {"tag": 7}), PolicySpec("raster"), 30, 4)
    df = run_job(job, c=3.0, p=1.0)
    assert list(df.columns) == COLUMNS + ["param_tag"] + run_metric_columns()  # track scores
    assert len(df) == sc.n_steps and list(df["step"]) == list(range(sc.n_steps))
    assert (df["status"] == "ok").all() and (df["error"] == "").all()
    assert (df["tracker_label"] == "test_recorder(tag=7)").all()
    assert json.loads(df["tracker_params"].iloc[0]) == {"tag": 7}
    assert (df["param_tag"] == 7).all()
    assert (df["n_looks"] == 30).all() and (df["ospa_c"] == 3.0).all()
    assert not df[["tracker_uses_truth", "policy_uses_truth"]].any().any()
    # recompute every step independently: truth from the simulator, looks from the
    # raster sweep, the estimate from the recorder's rule
    run = simulate(sc, 4)
    est = np.zeros((0, 2))
    for k in range(sc.n_steps):
        cells = (k * 30 + np.arange(30)) % sc.grid.n_cells
        looks = run.look(k, cells)
        pos = looks.cells[looks.returns]
        if pos.size:
            est = sc.grid.cell_centers(pos[:1])
        m = step_metrics(run.positions(k), est, float(len(est)), c=3.0, p=1.0)
        row = df.iloc[k]
        assert row["true_count"] == len(run.states[k])
        assert row["n_positive"] == looks.returns.sum()
        for name in harness.METRIC_COLUMNS:
            assert np.isclose(row[name], m[name], rtol=0, atol=TOL, equal_nan=True), (k, name)
    t = df[TIMING].to_numpy()
    assert np.isfinite(t).all() and (t >= 0).all()


def test_policy_randomness_is_shared_by_trackers_and_tracker_randomness_is_not(test_trackers):
    sc = short("default", 6)
    for tag in (1, 2):
        run_job(Job(sc, TrackerSpec("test_recorder", {"tag": tag}), PolicySpec("random"), 10, 3))
    (k1, cells1), (k2, cells2) = sorted(Recorder.looks_seen.items())
    assert k1[0] == 1 and k2[0] == 2
    # the same random cells for both trackers, and not a fixed sweep
    for a, b in zip(cells1, cells2, strict=True):
        np.testing.assert_array_equal(a, b)
    assert len({tuple(c) for c in cells1}) > 1
    # the trackers' own streams differ (seeded from their configurations: tag 1 vs 2)
    assert Recorder.draws[k1] != Recorder.draws[k2]


def test_oracle_policy_marks_rows_as_using_truth():
    df = run_job(Job(short("default", 4), TrackerSpec("null"), PolicySpec("oracle"), 5, 0))
    assert df["policy_uses_truth"].all() and (df["status"] == "ok").all()
    assert not df["tracker_uses_truth"].any()
    assert "| oracle (uses truth) |" in to_markdown(summarize(df))


def test_superposition_job_has_no_policy():
    df = run_job(Job(short("superposition", 4), TrackerSpec("null"), PolicySpec("raster"), 12, 0))
    assert (df["policy"] == "none").all() and (df["looks_per_step"] == 0).all()
    assert (df["n_looks"] == 0).all() and (df["status"] == "ok").all()


def test_unsupported_gives_one_marked_row(test_trackers):
    df = run_job(Job(short("default", 4), TrackerSpec("test_unsupported"), None, None, 0))
    assert len(df) == 1
    row = df.iloc[0]
    assert row["status"] == "unsupported" and row["error"] == "cannot do this"
    assert row["step"] == -1 and math.isnan(row["ospa"])


# ---------------------------------------------------------------------- sweeps
def test_sweep_keeps_other_results_when_a_tracker_crashes(test_trackers, tmp_path):
    sc = short("default", 6)
    jobs = build_jobs([sc], [TrackerSpec("null"), TrackerSpec("test_crash")], None, None, [0, 1])
    df = run_sweep(jobs, tmp_path)
    null = df[df["tracker"] == "null"]
    assert len(null) == 2 * 6 and (null["status"] == "ok").all()
    crash = df[df["tracker"] == "test_crash"]
    for _, g in crash.groupby("seed"):
        assert list(g["step"]) == [0, 1, 2, 3]
        assert list(g["status"]) == ["ok", "ok", "ok", "error"]
        err = g["error"].iloc[-1]
        assert "RuntimeError" in err and "boom at step three" in err
        assert math.isnan(g["ospa"].iloc[-1])
    on_disk = pd.read_parquet(tmp_path / "results.parquet")
    pd.testing.assert_frame_equal(on_disk, df)
    assert len(list((tmp_path / "parts").glob("*.parquet"))) == len(jobs)
    # summaries count the failures and keep them out of the means
    summ = summarize(df)
    row = summ[summ["tracker_label"] == "test_crash"].iloc[0]
    assert row["n_seeds"] == 0 and row["n_errors"] == 2 and "boom" in row["note"]


def test_resume_skips_finished_parts(test_trackers, tmp_path):
    sc = short("default", 5)
    spec = [TrackerSpec("test_recorder")]
    # (runs go in worker processes: what ran is told by the parts' modification times)
    first = run_sweep(build_jobs([sc], spec, None, None, [0, 1]), tmp_path)
    parts = {q: q.stat().st_mtime_ns for q in (tmp_path / "parts").glob("*.parquet")}
    assert len(parts) == 2
    again = run_sweep(build_jobs([sc], spec, None, None, [0, 1]), tmp_path,
                      resume=True)
    assert {q: q.stat().st_mtime_ns for q in (tmp_path / "parts").glob("*.parquet")} == parts
    pd.testing.assert_frame_equal(first, again)
    # the folder is this sweep's (sweep.json): a larger sweep, or this one again without
    # resume, is refused
    from mttbench.benchmarks.engine.errors import ConfigError

    with pytest.raises(ConfigError, match="another sweep"):
        run_sweep(build_jobs([sc], spec, None, None, [0, 1, 2]), tmp_path, resume=True)
    with pytest.raises(ConfigError, match="already holds this sweep"):
        run_sweep(build_jobs([sc], spec, None, None, [0, 1]), tmp_path)


def test_results_do_not_depend_on_the_number_of_workers(tmp_path):
    scs = [short("default", 8), short("superposition", 4)]
    trs = [TrackerSpec("null"), TrackerSpec("kfnn")]
    jobs = build_jobs(scs, trs, [PolicySpec("random"), PolicySpec("renyi")], [10], [0, 1])
    serial = run_sweep(jobs, tmp_path / "one", workers=1)
    parallel = run_sweep(list(reversed(jobs)), tmp_path / "two", workers=2)
    pd.testing.assert_frame_equal(strip_timing(serial), strip_timing(parallel))
    # grid: 2 trackers x 2 policies x 2 seeds x 8 steps; superposition: null 2 x 4 steps,
    # kfnn one "unsupported" row per seed
    assert len(serial) == 2 * 2 * 2 * 8 + 2 * 4 + 2


# ---------------------------------------------------------------------- summary
def hand_table() -> pd.DataFrame:
    """A step-level table: trackers A, B, ref; 4 seeds; 3 steps; one failed B run."""
    rng = np.random.default_rng(5)
    rows = []
    for tracker in ("A", "B", "ref"):
        for seed in range(4):
            for step in range(3):
                failed = tracker == "B" and seed == 3 and step == 2
                rows.append({
                    "scenario": "s", "tracker": tracker, "tracker_label": tracker,
                    "policy": "raster", "policy_label": "raster", "tracker_uses_truth": False,
                    "policy_uses_truth": False,
                    "looks_per_step": 24, "seed": seed, "step": step,
                    **{m: (math.nan if failed else rng.random()) for m in
                       ("ospa", "ospa_loc", "ospa_card", "gospa", "gospa_loc", "gospa_missed",
                        "gospa_false", "count_error")},
                    "rmse": math.nan if step == 0 else rng.random(),
                    "tracker_wall_s": rng.random(), "tracker_cpu_s": rng.random(),
                    "select_wall_s": rng.random(), "select_cpu_s": rng.random(),
                    "peak_rss_mb": 100.0 + seed, "status": "error" if failed else "ok",
                    "error": "ValueError: x" if failed else "",
                })
    return pd.DataFrame(rows)


def t_half_width(v: np.ndarray) -> float:
    """Independent reference: scipy's t interval around the mean."""
    lo, hi = stats.t.interval(0.95, len(v) - 1, loc=np.mean(v), scale=stats.sem(v))
    return (hi - lo) / 2


def test_per_run_averages_over_steps():
    df = hand_table()
    runs = per_run(df)
    assert len(runs) == 3 * 4
    g = df[(df["tracker_label"] == "A") & (df["seed"] == 2)]
    r = runs[(runs["tracker_label"] == "A") & (runs["seed"] == 2)].iloc[0]
    assert r["ospa"] == pytest.approx(g["ospa"].mean(), abs=TOL)
    assert r["rmse"] == pytest.approx(g["rmse"].iloc[1:].mean(), abs=TOL)  # NaN step skipped
    assert r["tracker_wall_s"] == pytest.approx(np.median(g["tracker_wall_s"]), abs=TOL)
    assert r["select_wall_s"] == pytest.approx(g["select_wall_s"].mean(), abs=TOL)
    assert r["status"] == "ok" and r["n_steps"] == 3
    bad = runs[(runs["tracker_label"] == "B") & (runs["seed"] == 3)].iloc[0]
    assert bad["status"] == "error" and bad["error"] == "ValueError: x"


def test_summarize_matches_scipy_t_interval():
    df = hand_table()
    summ = summarize(df)
    runs = per_run(df)
    for label, n in (("A", 4), ("B", 3)):
        row = summ[summ["tracker_label"] == label].iloc[0]
        v = runs[(runs["tracker_label"] == label) & (runs["status"] == "ok")]["ospa"].to_numpy()
        assert row["n_seeds"] == n == len(v)
        assert row["ospa_mean"] == pytest.approx(v.mean(), abs=TOL)
        assert row["ospa_ci95"] == pytest.approx(t_half_width(v), rel=1e-9)
    assert summ.loc[summ["tracker_label"] == "B", "n_errors"].iloc[0] == 1


def test_single_seed_has_nan_half_width():
    df = hand_table()
    summ = summarize(df[df["seed"] == 0])
    assert (summ["n_seeds"] == 1).all() and summ["ospa_ci95"].isna().all()
    mean, half = mean_ci95(np.array([0.25]))
    assert mean == 0.25 and math.isnan(half)


def test_paired_difference_matches_direct_computation():
    df = hand_table()
    out = paired_difference(df, "ref", "ospa")
    assert sorted(out["tracker_label"]) == ["A", "B"]
    runs = per_run(df).set_index(["tracker_label", "seed"])
    for label, seeds in (("A", [0, 1, 2, 3]), ("B", [0, 1, 2])):  # B's seed 3 failed
        d = np.array([runs.loc[(label, s), "ospa"] - runs.loc[("ref", s), "ospa"]
                      for s in seeds])
        row = out[out["tracker_label"] == label].iloc[0]
        assert row["n_seeds"] == len(seeds)
        assert row["diff_mean"] == pytest.approx(d.mean(), abs=TOL)
        assert row["diff_ci95"] == pytest.approx(t_half_width(d), rel=1e-9)
    with pytest.raises(ValueError):
        paired_difference(df, "nobody", "ospa")


def test_to_markdown_shows_mean_plus_minus_half_width():
    summ = summarize(hand_table())
    text = to_markdown(summ)
    lines = [ln for ln in text.splitlines() if ln.startswith("|")]
    assert len(lines) == 2 + len(summ)
    a = summ[summ["tracker_label"] == "A"].iloc[0]
    assert f"{a['ospa_mean']:.3f} ± {a['ospa_ci95']:.3f}" in text
    assert "failed in 1 of 4 runs" in text


class _Clock:
    """A fake ``perf_counter``/``process_time``: time moves only when a test's method
    says so, so the loop's accounting is checked exactly (no wall time asserted)."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        self.t += dt


def test_the_trackers_timed_share_excludes_the_selection_and_the_looks(monkeypatch):
    """Per step the tracker's time is predict + update + estimate (1 + 10 + 100); its
    ``P_c`` for the policy (1e3) and the policy's selection (1e4) are the selection's
    time; making the looks (1e5) is neither."""
    from types import SimpleNamespace

    from mttbench.benchmarks.engine.policies import Policy

    clock = _Clock()
    monkeypatch.setattr(harness, "time", SimpleNamespace(perf_counter=clock,
                                                         process_time=clock))

    class Ticking(Tracker):
        name = "ticking-test"

        def reset(self, model, rng):
            self._n = model.grid.n_cells

        def predict(self):
            clock.advance(1.0)

        def cell_count_distribution(self):
            clock.advance(1e3)
            P = np.zeros((self._n, 2))
            P[:, 0] = 1.0
            return P

        def update(self, looks):
            clock.advance(10.0)

        def estimate(self):
            clock.advance(100.0)
            return Estimate.empty()

    class Asking(Policy):
        name = "asking-test"
        uses_prediction = True

        def select(self, k, counts=None, truth_cells=None):
            assert counts is not None
            clock.advance(1e4)
            return np.arange(min(self._n_looks, self._n_cells), dtype=np.int64)

    sc = dataclasses.replace(scenarios.get("default"), n_steps=3)
    pb = harness.play(sc, Ticking(), 0, policy=Asking())
    look = pb.world.look

    def timed_look(k, cells):
        clock.advance(1e5)
        return look(k, cells)

    pb.world.look = timed_look
    recs = list(pb)
    assert len(recs) == 3
    for rec in recs:
        assert rec.tracker_wall_s == 111.0 and rec.tracker_cpu_s == 111.0
        assert rec.select_wall_s == 11000.0 and rec.select_cpu_s == 11000.0


def test_run_failures_counts_runs_not_rows():
    # three runs of four steps; the second fails at step 2 (its two ok rows, then the
    # error row), as run_job writes them: 1 of 3 runs failed, whatever the row counts
    rows = []
    for seed in range(3):
        for step in range(4):
            failed = seed == 1 and step == 2
            rows.append({"scenario": "s", "tracker_label": "t", "policy_label": "raster",
                         "looks_per_step": 4, "seed": seed, "step": step,
                         "status": "error" if failed else "ok",
                         "error": "ValueError: boom" if failed else ""})
            if failed:
                break
    k, n, first = run_failures(pd.DataFrame(rows))
    assert (k, n) == (1, 3)
    assert first == "s/t/seed 1: ValueError: boom (step 2)"

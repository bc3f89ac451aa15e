"""The converged Bayes reference: the ladder's convergence rule, its stored files, the
achievable gap in the summaries, and ``mttbench bayes`` end to end on a tiny scenario.

The ladder's decisions are checked with a synthetic sweep whose per-seed OSPA is chosen
exactly (so the paired interval is known in closed form); the achievable share against
the hand formula ``(F - X) / (F - B)`` with scipy's t quantile.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from test_gap_closed import frame

from mttbench.benchmarks.app import bayes, report, summary
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.app.usage import UsageError
from mttbench.benchmarks.engine.specs import PolicySpec, resolve_scenarios

TINY = resolve_scenarios(["env-centre"], steps=3)[0]


# ------------------------------------------------------------------ the ladder's rule
def rung(n: int, values: list[float], cpu: float = 1e-3, errors: int = 0) -> bayes.Rung:
    return bayes.Rung(n, dict(enumerate(values)), cpu * 1e3, cpu * 10, errors)


def test_paired_step_is_the_paired_t_interval():
    lo, hi = [1.0, 1.2, 0.9, 1.1], [0.98, 1.15, 0.91, 1.05]
    d = np.subtract(lo, hi)
    half = stats.t.ppf(0.975, 3) * d.std(ddof=1) / 2.0
    step = bayes.paired_step(rung(10, lo), rung(40, hi))
    assert step["diff_mean"] == pytest.approx(d.mean(), abs=1e-6)
    assert step["diff_ci95"] == pytest.approx(half, abs=1e-6)
    assert step["bound"] == pytest.approx(abs(d.mean()) + half, abs=1e-6)
    assert step["n_pairs"] == 4


def test_paired_step_pairs_only_the_shared_seeds():
    lo = bayes.Rung(10, {0: 1.0, 1: 2.0, 2: 3.0}, 1.0, 1.0, 0)
    hi = bayes.Rung(40, {1: 1.5, 2: 2.5}, 1.0, 1.0, 0)
    step = bayes.paired_step(lo, hi)
    assert step["n_pairs"] == 2 and step["diff_mean"] == pytest.approx(0.5)


def synthetic_sweep(ospa_of_n, cpu_of_n=lambda n: 1e-6 * n, fail_at=None, truth=None):
    """A sweep whose runs have OSPA ``ospa_of_n(n, seed)`` at every step and a CPU time
    per step ``cpu_of_n(n)``; the runs at ``fail_at`` particles fail. ``truth``: the true
    count at each of the 3 steps (rows then carry ``true_count`` and ``ospa_c`` = 2)."""
    calls = []

    def sweep(jobs, folder):
        rows = []
        for job in jobs:
            n = job.tracker.params["n_particles"]
            calls.append(n)
            for step in range(3):
                rows.append({"scenario": job.scenario.name, "tracker": job.tracker.name,
                             "tracker_label": job.tracker.label, "param_n_particles": n,
                             "policy_label": job.policy.label, "looks_per_step": 36,
                             "seed": job.seed, "step": step,
                             "ospa": ospa_of_n(n, job.seed),
                             "tracker_cpu_s": cpu_of_n(n),
                             "status": "error" if n == fail_at else "ok", "error": "",
                             **({} if truth is None else
                                {"true_count": truth[step], "ospa_c": 2.0})})
        return pd.DataFrame(rows)

    return sweep, calls


SEED_NOISE = [0.01, -0.02, 0.015, -0.005]


def test_the_ladder_stops_at_the_first_pair_within_tolerance(tmp_path):
    # OSPA(n) = 1 + 1/sqrt(n) (+ a seed effect shared by every n: it cancels in the pairs)
    sweep, calls = synthetic_sweep(lambda n, s: 1.0 + 1.0 / math.sqrt(n) + SEED_NOISE[s])
    ladder = bayes.Ladder(n_start=100, factor=4, n_max=102400, tolerance=0.02,
                          run_limit_s=1e9)
    refs = bayes.run_ladder([TINY], range(4), sweep, tmp_path, ladder=ladder,
                            say=lambda _: None)
    ref = refs[TINY.name]
    # differences 1/sqrt(n) - 1/sqrt(4n) = 0.5/sqrt(n): 0.05 (100), 0.025 (400),
    # 0.0125 (1600 -> 6400, the first within 0.02), 0.00625 (6400 -> 25600, the second:
    # two consecutive steps within, converged)
    assert ref.converged and ref.n_particles == 25600
    assert sorted(set(calls)) == [100, 400, 1600, 6400, 25600]
    assert [s["n_low"] for s in ref.provenance["steps"]] == [100, 400, 1600, 6400]
    assert set(ref.rows["tracker_label"]) == {bayes.REFERENCE}
    assert set(ref.rows["param_n_particles"]) == {25600}


def test_one_step_within_is_not_converged_when_the_next_is_not():
    # a small first step followed by a large one (as kreucher's 1000 -> 4000 -> 16000)
    ladder = bayes.Ladder(100, 4, 102400, 0.02, 1e9, 0.0)
    within = {"bound": 0.01, "tolerance": 0.02}
    beyond = {"bound": 0.04, "tolerance": 0.02}
    assert not ladder.is_converged([within])
    assert not ladder.is_converged([beyond, within])
    assert not ladder.is_converged([within, beyond])
    assert ladder.is_converged([beyond, within, within])
    assert bayes.Ladder(100, 4, 102400, 0.02, 1e9, 0.0, 1).is_converged([beyond, within])
    assert not ladder.is_converged([within, {"bound": None, "tolerance": 0.02}])


def test_the_gap_share_widens_the_tolerance_by_the_floors_exact_score(tmp_path):
    # truth 1, 1, 0 targets: the floor scores c = 2, 2, 0 -> 4/3 a run. OSPA(n) = 0.4 +
    # 1/sqrt(n): steps 0.05 (100 -> 400), 0.025 (400 -> 1600), 0.0125 (1600 -> 6400).
    # At 1600 the gap is 4/3 - 0.425 = 0.908, 5% of it 0.0454 >= 0.025: the two steps
    # from 400 are within, converged at 6400 (the absolute 0.02 alone: 25600).
    sweep, _ = synthetic_sweep(lambda n, s: 0.4 + 1.0 / math.sqrt(n) + SEED_NOISE[s],
                               truth=[1, 1, 0])
    ref = bayes.run_ladder([TINY], range(4), sweep, tmp_path,
                           ladder=bayes.Ladder(100, 4, 102400, 0.02, 1e9, 0.05),
                           say=lambda _: None)[TINY.name]
    assert ref.converged and ref.n_particles == 6400
    step = ref.provenance["steps"][-2]
    gap = 4.0 / 3.0 - np.mean([0.4 + 1.0 / 40.0 + e for e in SEED_NOISE])
    assert step["gap"] == pytest.approx(gap, abs=1e-6)
    assert step["tolerance"] == pytest.approx(0.05 * gap, abs=1e-6)
    assert "of the achievable gap" in ref.verdict()
    # the first step (0.05) is beyond 5% of its gap (0.858): not converged at 400
    assert ref.provenance["steps"][0]["bound"] > ref.provenance["steps"][0]["tolerance"]
    # with the share off, the absolute rule alone: 6400 as without the floor's numbers
    off = bayes.run_ladder([TINY], range(4), sweep, tmp_path / "off",
                           ladder=bayes.Ladder(100, 4, 102400, 0.02, 1e9, 0.0),
                           say=lambda _: None)[TINY.name]
    assert off.converged and off.n_particles == 25600
    assert "of the achievable gap" not in off.verdict()


def test_a_rung_past_the_run_limit_is_not_run_and_the_verdict_says_so(tmp_path):
    sweep, calls = synthetic_sweep(lambda n, s: 1.0 + 1.0 / math.sqrt(n),
                                   cpu_of_n=lambda n: 1e-3 * n)  # 3 steps: 3e-3 n s a run
    ladder = bayes.Ladder(n_start=100, factor=4, n_max=102400, tolerance=0.02,
                          run_limit_s=10.0)  # 400 -> 1600 takes 4.8 s a run; 6400: 19.2 s
    ref = bayes.run_ladder([TINY], range(4), sweep, tmp_path, ladder=ladder,
                           say=lambda _: None)[TINY.name]
    assert not ref.converged and ref.n_particles == 1600
    assert sorted(set(calls)) == [100, 400, 1600]
    assert "N = 6400" in ref.provenance["reason"]
    assert ref.verdict().startswith("not converged at N = 1600: an estimate, not a bound")


def test_failed_runs_end_the_ladder_unconverged(tmp_path):
    sweep, _ = synthetic_sweep(lambda n, s: 1.0, fail_at=400)
    ref = bayes.run_ladder([TINY], range(3), sweep, tmp_path,
                           ladder=bayes.Ladder(100, 4, 6400, 0.02, 1e9),
                           say=lambda _: None)[TINY.name]
    assert not ref.converged and "failed" in ref.provenance["reason"]


def test_n_max_reached_without_convergence(tmp_path):
    sweep, _ = synthetic_sweep(lambda n, s: 1.0 + 10.0 / math.sqrt(n))
    ref = bayes.run_ladder([TINY], range(3), sweep, tmp_path,
                           ladder=bayes.Ladder(100, 4, 1600, 0.02, 1e9),
                           say=lambda _: None)[TINY.name]
    assert not ref.converged and ref.n_particles == 1600
    assert "n_max" in ref.provenance["reason"]


@pytest.mark.parametrize("kwargs, what", [
    ({"n_start": 0}, "--n-start"), ({"factor": 1}, "--factor"),
    ({"n_start": 1000, "n_max": 2000}, "--n-max"), ({"tolerance": 0.0}, "--tolerance"),
    ({"tolerance": math.nan}, "--tolerance"), ({"run_limit_s": -1.0}, "--run-limit"),
    ({"gap_share": 1.0}, "--gap-share"), ({"gap_share": -0.1}, "--gap-share"),
    ({"confirm": 0}, "--confirm"), ({"confirm": 4, "n_max": 10 ** 9}, "--confirm"),
    ({"n_start": 1000, "n_max": 4000}, r"factor\^confirm")])
def test_bad_ladders_are_refused_in_one_line(kwargs, what):
    with pytest.raises(UsageError, match=what):
        bayes.Ladder(**kwargs)


# ------------------------------------------------------------------ stored references
def stored(tmp_path, seeds=(0, 1, 2)) -> bayes.Reference:
    sweep, _ = synthetic_sweep(lambda n, s: 1.0 + 0.1 * s)
    refs = bayes.run_ladder([TINY], seeds, sweep, tmp_path / "work",
                            ladder=bayes.Ladder(100, 4, 1600, 0.5, 1e9), say=lambda _: None)
    ref = refs[TINY.name]
    bayes.save(tmp_path / "store", TINY, ref.provenance["key"], ref)
    return ref


def test_a_stored_reference_reads_back_for_a_subset_of_its_seeds(tmp_path):
    ref = stored(tmp_path)
    key = bayes.reference_key(TINY, PolicySpec("raster"), None, 2.0, 2.0)
    assert ref.provenance["key"] == key
    found = bayes.find(TINY, PolicySpec("raster"), None, [0, 2], stores=[tmp_path / "store"])
    assert found is not None and sorted(set(found.rows["seed"])) == [0, 2]
    assert found.converged
    # other seeds, another policy, another cut-off: none
    assert bayes.find(TINY, PolicySpec("raster"), None, [0, 5],
                      stores=[tmp_path / "store"]) is None
    assert bayes.find(TINY, PolicySpec("random"), None, [0],
                      stores=[tmp_path / "store"]) is None
    assert bayes.find(TINY, PolicySpec("raster"), None, [0], c=3.0,
                      stores=[tmp_path / "store"]) is None


def test_a_damaged_stored_reference_is_ignored_with_a_line(tmp_path, capsys):
    ref = stored(tmp_path)
    rows_path, prov_path = bayes._paths(tmp_path / "store", TINY, ref.provenance["key"])
    rows_path.write_bytes(b"not parquet")
    assert bayes.find(TINY, PolicySpec("raster"), None, [0],
                      stores=[tmp_path / "store"]) is None
    assert "unreadable" in capsys.readouterr().err
    # a provenance file naming another key is refused too
    stored(tmp_path)
    prov = json.loads(prov_path.read_text())
    prov_path.write_text(json.dumps({**prov, "key": "0" * 16}))
    assert bayes.find(TINY, PolicySpec("raster"), None, [0],
                      stores=[tmp_path / "store"]) is None


def test_the_key_changes_with_the_scenario():
    other = resolve_scenarios(["env-centre"], steps=4)[0]
    raster = PolicySpec("raster")
    assert bayes.reference_key(TINY, raster, None, 2, 2) != \
        bayes.reference_key(other, raster, None, 2, 2)
    assert bayes.reference_key(TINY, raster, None, 2, 2) != \
        bayes.reference_key(TINY, raster, 12, 2, 2)


# ------------------------------------------------------------------ the achievable gap
def test_the_share_of_the_achievable_gap_against_the_hand_formula():
    F = [2.0, 2.0, 2.0, 2.0]
    C = [0.5, 0.6, 0.4, 0.5]
    B = [1.0, 1.2, 0.9, 1.1]
    X = [1.5, 1.4, 1.6, 1.3]
    df = frame({("s", "null"): F, ("s", "truth-aided"): C, ("s", "bayes"): B,
                ("s", "kfnn"): X})
    gc = summary.gap_closed(df)
    assert gc.bayes_label == "bayes"
    a, b = np.subtract(F, X), np.subtract(F, B)
    r = a.mean() / b.mean()
    d = (a - r * b) / b.mean()
    half = stats.t.ppf(0.975, 3) * d.std(ddof=1) / 2.0
    row = gc.shares[gc.shares["tracker_label"] == "kfnn"].iloc[0]
    assert row["achievable_mean"] == pytest.approx(r, abs=1e-9)
    assert row["achievable_ci95"] == pytest.approx(half, abs=1e-9)
    assert row["vs_bayes_mean"] == pytest.approx(np.mean(np.subtract(X, B)), abs=1e-9)
    g = gc.gaps.iloc[0]
    assert g["bayes_mean"] == pytest.approx(np.mean(B))
    assert g["achievable_mean"] == pytest.approx(np.mean(b))
    share = np.mean(b) / np.mean(np.subtract(F, C))
    assert g["bayes_share_mean"] == pytest.approx(share, abs=1e-9)
    assert bool(g["problem_limited"]) == bool(share < summary.PROBLEM_LIMITED_SHARE)
    bayes_row = gc.shares[gc.shares["tracker_label"] == "bayes"].iloc[0]
    assert bayes_row["role"] == "bayes"


def test_the_bayes_reference_is_no_contestant_and_a_tracker_beating_it_is_flagged():
    F = [2.0, 2.0, 2.0, 2.0]
    # only bayes beats the floor: the scenario cannot rank trackers
    df = frame({("s", "null"): F, ("s", "truth-aided"): [0.5] * 4,
                ("s", "bayes"): [1.6, 1.7, 1.5, 1.6], ("s", "kfnn"): [2.0, 2.01, 1.99, 2.0]})
    gc = summary.gap_closed(df)
    assert not bool(gc.gaps.iloc[0]["rankable"])
    assert "no contestant" in gc.gaps.iloc[0]["reason"]
    # bayes closes (2 - 1.6) / 1.5 < 0.5 of the gap: the problem limits accuracy
    assert bool(gc.gaps.iloc[0]["problem_limited"])
    notes = report.bayes_notes(gc)
    assert any("problem" in n for n in notes)
    # a tracker well below bayes on every seed is a finding to explain
    df = frame({("s", "null"): F, ("s", "truth-aided"): [0.5] * 4,
                ("s", "bayes"): [1.0, 1.1, 0.9, 1.0], ("s", "gpf"): [0.8, 0.85, 0.7, 0.8]})
    notes = report.bayes_notes(summary.gap_closed(df))
    assert any("`gpf` beats the Bayes reference beyond noise" in n for n in notes)


def test_without_bayes_rows_nothing_changes():
    df = frame({("s", "null"): [2.0] * 3, ("s", "truth-aided"): [0.5] * 3,
                ("s", "kfnn"): [1.0, 1.1, 0.9]})
    gc = summary.gap_closed(df)
    assert gc.bayes_label is None
    assert gc.shares["achievable_mean"].isna().all()
    assert "achievable_closed_mean" not in summary.with_gap_closed(
        summary.summarize(summary.per_run(df)), gc).columns
    assert report.bayes_notes(gc) == []


def test_attach_adds_the_stored_rows_and_says_which_are_missing(tmp_path):
    stored(tmp_path)
    other = resolve_scenarios(["env-pf-0.1"], steps=3)[0]
    base = frame({(TINY.name, "null"): [2.0] * 2})
    merged, notes = bayes.attach(base, [TINY, other], [0, 1], stores=[tmp_path / "store"])
    assert set(merged["tracker_label"]) == {"null", "bayes"}
    assert set(merged.loc[merged["tracker_label"] == "bayes", "seed"]) == {0, 1}
    assert "converged at N = 1600" in notes[0]
    assert "no stored `bayes` reference" in notes[1] and "mttbench bayes env-pf-0.1" in notes[1]


# ------------------------------------------------------------------ the command
def test_mttbench_bayes_end_to_end_stores_and_resumes(tmp_path, capsys):
    args = ["bayes", "env-centre", "--steps", "3", "--seeds", "2", "--n-start", "20",
            "--n-max", "80", "--confirm", "1", "--out", str(tmp_path / "work"), "--store",
            str(tmp_path / "store"), "--workers", "1", "--no-progress"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "| env-centre | 20 |" in out and "| env-centre | 80 |" in out
    files = sorted(p.suffix for p in (tmp_path / "store").iterdir())
    assert files == [".json", ".parquet"]
    prov = json.loads(next((tmp_path / "store").glob("*.json")).read_text())
    assert prov["seeds"] == [0, 1] and [r["n_particles"] for r in prov["rungs"]] == [20, 80]
    assert prov["scenario"] == "env-centre" and prov["n_steps"] == 3
    first = pd.read_parquet(next((tmp_path / "store").glob("*.parquet")))
    # the same folder again without --resume is refused; with it, the same reference
    assert main(args) == 2
    assert "--resume" in capsys.readouterr().err
    assert main([*args, "--resume"]) == 0
    again = pd.read_parquet(next((tmp_path / "store").glob("*.parquet")))
    cols = ["seed", "step", "ospa", "est_count"]
    pd.testing.assert_frame_equal(first[cols], again[cols])


@pytest.mark.parametrize("extra, what", [
    (["--n-start", "0"], "--n-start"), (["--n-max", "10"], "--n-max"),
    (["--policy", "raster", "renyi"], "one policy"), (["--looks", "4", "8"], "one look"),
    (["--seeds", "1"], "at least 2 seeds"), (["--tolerance", "-1"], "--tolerance"),
    (["--confirm", "0"], "--confirm"), (["--n-max", "8000"], "factor^confirm")])
def test_mttbench_bayes_refuses_bad_input_in_one_line(tmp_path, capsys, extra, what):
    code = main(["bayes", "env-centre", "--steps", "3", "--seeds", "2", "--out",
                 str(tmp_path / "w"), "--store", str(tmp_path / "s"), "--no-progress", *extra])
    err = capsys.readouterr().err
    assert code == 2 and what in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "s").exists()


def test_mttbench_bayes_needs_scenarios_or_a_suite(capsys):
    assert main(["bayes"]) == 2
    assert "SCENARIO" in capsys.readouterr().err


def test_a_look_budget_equal_to_the_scenarios_own_is_the_default_key():
    own = TINY.model.sensor.looks_per_step
    raster = PolicySpec("raster")
    assert bayes.reference_key(TINY, raster, own, 2, 2) == \
        bayes.reference_key(TINY, raster, None, 2, 2)


def test_mttbench_run_summarises_with_a_stored_reference(tmp_path, monkeypatch, capsys):
    """`run` adds the stored reference of its raster runs to its summary (the rows file
    keeps only the sweep's own runs)."""
    ref = stored(tmp_path)
    monkeypatch.setattr(bayes, "default_store", lambda: tmp_path / "store")
    assert ref.seeds == [0, 1, 2]
    code = main(["run", "--scenarios", "env-centre", "--steps", "3", "--seeds", "2",
                 "--trackers", "null", "--workers", "1", "--no-progress", "--out",
                 str(tmp_path / "run")])
    assert code == 0
    assert "bayes reference: `env-centre`: `bayes` converged" in capsys.readouterr().err
    summ = pd.read_csv(tmp_path / "run" / "summary.csv", keep_default_na=False,
                       na_values=[""])
    assert set(summ["tracker_label"]) == {"null", "bayes"}
    assert set(pd.read_parquet(tmp_path / "run" / "results.parquet")["tracker_label"]) == \
        {"null"}


def test_grid_bayes_is_a_reference_not_a_contestant():
    """A class flagged ``reference`` (grid-bayes) is neither ranked nor counted as the
    contestant that beats the floor."""
    df = frame({("s", "null"): [2.0] * 4, ("s", "truth-aided"): [0.5] * 4,
                ("s", "grid-bayes"): [1.0, 1.1, 0.9, 1.0], ("s", "kfnn"): [2.0, 2.01, 1.99, 2.0]})
    assert summary.reference_labels(summary.per_run(df)) == {"grid-bayes"}
    gc = summary.gap_closed(df)
    assert "no contestant" in gc.gaps.iloc[0]["reason"]


def test_the_frontier_draws_the_stored_bayes_line(tmp_path, monkeypatch, capsys):
    stored(tmp_path)
    monkeypatch.setattr(bayes, "default_store", lambda: tmp_path / "store")
    code = main(["frontier", "env-centre", "--trackers", "kfnn", "--steps", "3", "--seeds",
                 "2", "--workers", "1", "--no-progress", "--out", str(tmp_path / "f")])
    assert code == 0
    text = (tmp_path / "f" / "frontier.md").read_text()
    assert "bayes (converged, N = 1600)" in text

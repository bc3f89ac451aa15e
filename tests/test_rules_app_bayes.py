"""Rules of the Bayes reference's ladder (``benchmarks/app/bayes.py``, ``cli_bayes.py``)
where a slip shows: a bound exactly at its tolerance, a gap share wider than the absolute
tolerance, ``n_max`` exactly on a rung, the documented edges of each setting, a negative
paired mean, a step without a target, stored seeds that cover only some of the asked
ones, a ladder whose next rung would cross ``n_max`` or the run limit. The ladder is run
with a fake sweep (hand-made rows), never a tracker."""

from __future__ import annotations

import argparse
import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from mttbench import scenarios
from mttbench.benchmarks.app import bayes, cli_bayes
from mttbench.benchmarks.app.cli import build_parser
from mttbench.benchmarks.app.usage import UsageError
from mttbench.benchmarks.engine.specs import PolicySpec


def test_converged_when_each_bound_is_within_its_tolerance_inclusive():
    ladder = bayes.Ladder(confirm=2)
    at = [{"bound": 0.02, "tolerance": 0.02}, {"bound": 0.01, "tolerance": 0.02}]
    assert ladder.is_converged(at)
    assert not ladder.is_converged([{"bound": 0.0201, "tolerance": 0.02}, at[1]])
    assert not ladder.is_converged(at[:1])  # fewer steps than confirm


def test_the_tolerance_is_the_wider_of_the_two():
    ladder = bayes.Ladder(tolerance=0.02, gap_share=0.05)
    assert ladder.tolerance_for(1.0) == pytest.approx(0.05)  # 5% of the gap
    assert ladder.tolerance_for(0.1) == pytest.approx(0.02)  # the absolute floor
    assert ladder.tolerance_for(math.nan) == 0.02


def test_the_rungs_reach_n_max_inclusive():
    assert bayes.Ladder(n_start=1000, factor=4, n_max=16000, confirm=2).rungs() == [
        1000, 4000, 16000]


@pytest.mark.parametrize("kw", [{"n_max": 4000, "confirm": 1}, {"gap_share": 0.0},
                                {"confirm": 3, "n_max": 64000}, {"confirm": 1, "n_max": 4000}])
def test_the_documented_edges_of_the_ladders_settings_are_allowed(kw):
    bayes.Ladder(**kw)


@pytest.mark.parametrize("kw", [{"n_max": 3999, "confirm": 1}, {"gap_share": 1.0},
                                {"confirm": 4}, {"confirm": 0}])
def test_beyond_the_edges_is_refused(kw):
    with pytest.raises(UsageError):
        bayes.Ladder(**kw)


def _rung(n: int, ospa: dict[int, float]) -> bayes.Rung:
    return bayes.Rung(n, ospa, 1.0, 1.0, 0)


def test_the_paired_bound_is_the_mean_size_plus_the_half_width():
    lo = _rung(1000, {0: 1.0, 1: 1.0, 2: 1.0, 3: 1.0})
    hi = _rung(4000, {0: 1.1, 1: 1.2, 2: 1.1, 3: 1.2})  # lo - hi = -0.1, -0.2, ...
    step = bayes.paired_step(lo, hi)
    d = np.array([-0.1, -0.2, -0.1, -0.2])
    half = 3.182446305284263 * d.std(ddof=1) / 2
    assert step["diff_mean"] == pytest.approx(-0.15, abs=1e-6)
    assert step["bound"] == pytest.approx(0.15 + half, abs=1e-6)


def test_the_floor_of_a_rung_is_c_at_steps_with_targets_and_zero_without():
    rows = pd.DataFrame({"seed": [0, 0, 0, 0], "status": "ok", "ospa": 0.5,
                         "tracker_cpu_s": 1e-3, "true_count": [0, 2, 1, 0],
                         "ospa_c": 2.0})
    rung = bayes.rung_of(rows, 1000)
    assert rung.null_ospa == {0: pytest.approx(1.0)}  # (0 + 2 + 2 + 0) / 4
    assert rung.gap() == pytest.approx(0.5)


def test_the_key_takes_the_default_cut_off_in_the_scenarios_cells():
    """c None is 2 cells: the same key as c = 2 x cell_size, another than c = 2 world
    units on a grid whose cells are not 1."""
    sc = scenarios.get("default")
    sc = dataclasses.replace(sc, model=dataclasses.replace(
        sc.model, grid=dataclasses.replace(sc.model.grid, cell_size=2.5)))
    pol = PolicySpec("raster")
    assert bayes.reference_key(sc, pol, None, None, 2.0) == \
        bayes.reference_key(sc, pol, None, 5.0, 2.0)
    assert bayes.reference_key(sc, pol, None, None, 2.0) != \
        bayes.reference_key(sc, pol, None, 2.0, 2.0)


def test_a_stored_reference_is_found_only_when_it_holds_every_seed(tmp_path):
    sc = scenarios.get("default")
    pol = PolicySpec("raster")
    key = bayes.reference_key(sc, pol, None, None, 2.0)
    rows = pd.DataFrame({"seed": [0, 0, 1, 1], "step": [0, 1, 0, 1], "ospa": 1.0,
                         "tracker": "bayes", "tracker_label": "bayes"})
    bayes.save(tmp_path, sc, key, bayes.Reference(rows, {
        "key": key, "format": bayes.FORMAT, "seeds": [0, 1]}))
    ref = bayes.find(sc, pol, None, [1], stores=[tmp_path])
    assert ref is not None and set(ref.rows["seed"]) == {1}
    assert bayes.find(sc, pol, None, [1, 2], stores=[tmp_path]) is None


def test_the_missing_reference_hint_covers_the_largest_seed(tmp_path):
    sc = scenarios.get("default")
    _, notes = bayes.attach(pd.DataFrame(), [sc], [3, 7], stores=[tmp_path])
    assert notes == ["`default`: no stored `bayes` reference for these seeds (compute it: "
                     "`mttbench bayes default --seeds 8`)"]


# ------------------------------------------------------------------ the ladder
def _fake_sweep(cpu_s_per_step: float = 1e-3, n_steps: int = 2):
    """Rows of every job: ladder tracker, the job's particle count, OSPA 1/N-ish."""
    def sweep(jobs, folder):
        rows = []
        for job in jobs:
            n = int(job.tracker.params["n_particles"])
            for step in range(n_steps):
                rows.append({"scenario": job.scenario.name, "tracker": bayes.LADDER_TRACKER,
                             "param_n_particles": n, "seed": job.seed, "step": step,
                             "status": "ok", "ospa": 1.0 + 100.0 / n + 0.01 * job.seed,
                             "tracker_cpu_s": cpu_s_per_step, "true_count": 1,
                             "ospa_c": 2.0})
        return pd.DataFrame(rows)
    return sweep


def _ladder_run(ladder: bayes.Ladder, cpu_s: float = 1e-3) -> bayes.Reference:
    sc = dataclasses.replace(scenarios.get("default"), n_steps=2)
    refs = bayes.run_ladder([sc], [0, 1], _fake_sweep(cpu_s), "unused", ladder=ladder,
                            say=lambda line: None)
    return refs["default"]


def test_the_ladder_runs_the_rung_at_n_max():
    """Rungs 10, 40, 160 = n_max with differences 7.5 and 1.875 (never within 0.02):
    the ladder stops after the rung at n_max, not before it."""
    ref = _ladder_run(bayes.Ladder(n_start=10, factor=4, n_max=160, confirm=1))
    assert [r["n_particles"] for r in ref.provenance["rungs"]] == [10, 40, 160]
    assert ref.provenance["reason"] == "the ladder's n_max 160 reached"


def test_the_run_limit_looks_at_the_next_rungs_time():
    """A run of this rung takes 2 steps x 1 s = 2 s; the next (x4) 8 s: a limit of 5 s
    stops after the first rung, one of 10 s does not."""
    ladder = bayes.Ladder(n_start=10, factor=4, n_max=160, confirm=1, run_limit_s=5.0)
    ref = _ladder_run(ladder, cpu_s=1.0)
    assert [r["n_particles"] for r in ref.provenance["rungs"]] == [10]
    ladder = dataclasses.replace(ladder, run_limit_s=10.0)
    ref = _ladder_run(ladder, cpu_s=1.0)
    assert [r["n_particles"] for r in ref.provenance["rungs"]][:2] == [10, 40]


# --------------------------------------------------------------- command line
def _parser() -> argparse.ArgumentParser:
    return build_parser()


def test_the_commands_defaults_are_the_ladders():
    args = _parser().parse_args(["bayes", "default"])
    d = bayes.Ladder()
    assert (args.n_start, args.factor, args.n_max, args.tolerance, args.gap_share,
            args.confirm, args.run_limit) == (d.n_start, d.factor, d.n_max, d.tolerance,
                                              d.gap_share, d.confirm, d.run_limit_s)


def test_a_reference_at_zero_looks_is_refused(tmp_path):
    args = _parser().parse_args(["bayes", "default", "--looks", "0", "--out",
                                 str(tmp_path / "o")])
    with pytest.raises(UsageError, match="--looks value 0"):
        cli_bayes.cmd_bayes(args)

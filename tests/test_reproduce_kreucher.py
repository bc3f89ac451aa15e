"""``mttbench reproduce kreucher``: the matched-looks interpolation (closed-form cases),
the raster scan beyond the cell count, and the command end to end on a tiny setting
(stand-in tracker ``kfnn``) with its cache, ``--update-reference`` and ``--check``."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from mttbench import scenarios
from mttbench.benchmarks.app import reproduce
from mttbench.benchmarks.app import reproduce_kreucher as rk
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.app.resources import check_jobs
from mttbench.benchmarks.engine.loop import Job, run_job
from mttbench.benchmarks.engine.policies import make_policy
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec, resolve_trackers

KREUCHER = scenarios.get("kreucher")
#: a setting that runs in about a second: one seed, three steps, two raster budgets
TINY = rk.KreucherSetting("reduced", 3, (0,), trackers=("kfnn",), managed=("renyi",),
                          raster_looks=(24, 312), burn_in=0)


# ------------------------------------------------------------ matched looks
def test_matched_looks_at_a_point_of_the_curve():
    m = rk.matched_looks([24, 48, 72], [1.0, 0.5, 0.25], 0.5)
    assert (m.looks, m.bound) == (48.0, 0)
    assert m.text() == "48" and m.ratio_text(24) == "2.0x"
    assert rk.matched_looks([24, 48, 72], [1.0, 0.5, 0.25], 1.0) == rk.Match(24.0, 0)


def test_matched_looks_interpolates_in_log_looks():
    # halfway between 24 and 96 in log looks is their geometric mean, 48
    assert rk.matched_looks([24, 96], [1.0, 0.0], 0.5).looks == pytest.approx(48.0)
    # a quarter of the way from 24 to 312 (log scale): 24 * 13 ** 0.25
    m = rk.matched_looks([312, 24], [0.2, 1.0], 0.8)  # unsorted input
    assert m.bound == 0 and m.looks == pytest.approx(24.0 * 13.0 ** 0.25)
    assert m.ratio(24) == pytest.approx(13.0 ** 0.25)


def test_matched_looks_takes_the_first_crossing_of_a_bumpy_curve():
    m = rk.matched_looks([24, 48, 72, 144], [1.0, 0.4, 0.6, 0.2], 0.5)
    assert m.looks == pytest.approx(24.0 * 2.0 ** (5.0 / 6.0))  # (1 - 0.5) / (1 - 0.4)


def test_matched_looks_beyond_and_below_the_curve():
    looks, err = [24, 48, 72, 144, 216, 312], [1.9, 1.6, 1.0, 0.8, 0.7, 0.62]
    beyond = rk.matched_looks(looks, err, 0.47)  # Kreucher at SNR 2: better than 312
    assert (beyond.looks, beyond.bound) == (312.0, 1)
    assert beyond.text() == ">= 312 (beyond the curve)"
    assert beyond.ratio_text(24) == ">= 13.0x"
    below = rk.matched_looks(looks, err, 2.0)  # worse than raster at the same 24 looks
    assert (below.looks, below.bound) == (24.0, -1)
    assert below.text() == "< 24" and below.ratio_text(24) == "< 1.0x"
    missing = rk.matched_looks(looks, [1.9, math.nan, 1.0, 0.8, 0.7, 0.62], 1.2)
    assert math.isnan(missing.looks) and missing.text() == "n/a"


def test_matched_table_per_statistic():
    rows = [{"scenario": "s", "snr": 2.0, "tracker": "t", "policy": "raster",
             "kind": "periodic", "looks": lk, "ospa_median": med, "ospa_mean": mean}
            for lk, med, mean in ((24, 1.0, 1.2), (96, 0.0, 0.2))]
    rows.append({"scenario": "s", "snr": 2.0, "tracker": "t", "policy": "renyi",
                 "kind": "managed", "looks": 24, "ospa_median": 0.5, "ospa_mean": 0.1})
    m = rk.matched_table(pd.DataFrame(rows)).iloc[0]
    assert m["matched_median"] == pytest.approx(48.0) and m["bound_median"] == 0
    assert m["matched_mean"] == 96.0 and m["bound_mean"] == 1
    assert m["ratio_median_text"] == "2.0x" and m["matched_mean_text"].startswith(">= 96")


# ------------------------------------------------------------------- raster
def _raster(n_looks: int):
    pol = make_policy("raster")
    pol.reset(KREUCHER.model, n_looks, np.random.default_rng(0))
    return pol


def test_raster_wraps_past_the_cell_count_and_continues_across_steps():
    n = KREUCHER.grid.n_cells
    pol = _raster(312)
    steps = [pol.select(k) for k in range(5)]
    for cells in steps:
        assert cells.dtype == np.int64 and cells.shape == (312,)
        per_cell = np.bincount(cells, minlength=n)
        assert set(per_cell.tolist()) == {2, 3} and (per_cell == 3).sum() == 312 - 2 * n
    # one pointer through the flat cell order: step k starts where step k-1 stopped
    np.testing.assert_array_equal(np.concatenate(steps), np.arange(5 * 312) % n)
    assert "twice" in type(pol).summary


@pytest.mark.parametrize("m", [0, 1, 24, 144, 216])
def test_raster_budget_up_to_and_beyond_the_cells(m):
    n = KREUCHER.grid.n_cells
    pol = _raster(m)
    for k in (0, 1, 7):
        np.testing.assert_array_equal(pol.select(k), (k * m + np.arange(m)) % n)
    assert rk.revisits(m, n) == ("no" if m <= n else "every cell 1x, 72 cells twice")


def test_more_raster_looks_than_cells_run_through_the_harness():
    job = Job(dataclasses.replace(KREUCHER, n_steps=3), TrackerSpec("kfnn"),
              PolicySpec("raster"), 312, 0)
    assert not [w for w in check_jobs([job], 1) if "refus" in w.lower()]
    rows = run_job(job)
    assert (rows["status"] == "ok").all() and (rows["n_looks"] == 312).all()


# --------------------------------------------------------- the setting itself
def test_the_pinned_setting():
    assert rk.KREUCHER_CROSSINGS == (30, 70)
    assert rk.SETTINGS["full"].raster_looks == (24, 48, 72, 144, 216, 312)
    assert rk.SETTINGS["full"].seeds == tuple(range(20))
    assert rk.SETTINGS["full"].managed_looks == 24 and rk.SETTINGS["full"].snrs == (2.0, 10.0)
    resolve_trackers(rk.KREUCHER_TRACKERS)  # every pinned tracker is registered
    scs = rk.setting_scenarios(rk.SETTINGS["reduced"])
    assert [sc.name for sc in scs] == ["kreucher-snr2", "kreucher"]
    assert [sc.model.sensor.snr for sc in scs] == [2.0, 10.0]
    assert scs[0].model.dynamics == KREUCHER.model.dynamics  # only the sensor changes
    assert dataclasses.replace(scs[0].model, sensor=KREUCHER.model.sensor) == KREUCHER.model
    jobs = rk.setting_jobs(TINY, [TrackerSpec("kfnn")])
    assert sorted({(j.policy.name, j.looks_per_step) for j in jobs}) == [
        ("raster", 24), ("raster", 312), ("renyi", 24)]
    assert len(jobs) == 2 * 3  # two scenarios x three scans x one seed


def test_cache_key_follows_the_setting():
    specs = [TrackerSpec("kfnn")]
    env = {"fixed": True}
    key = rk.cache_key(TINY, specs, env)
    assert key.startswith("kreucher-") and key == rk.cache_key(TINY, specs, env)
    for other in (dataclasses.replace(TINY, snrs=(3.0, 10.0)),
                  dataclasses.replace(TINY, raster_looks=(24, 216)),
                  dataclasses.replace(TINY, n_steps=4)):
        assert rk.cache_key(other, specs, env) != key
    assert rk.cache_key(TINY, [TrackerSpec("null")], env) != key
    assert rk.cache_key(TINY, specs, {"fixed": False}) != key


def test_per_seed_means_after_the_burn_in_and_lost_seeds():
    base = {"scenario": "s", "tracker_label": "t", "policy": "raster", "policy_label": "raster",
            "looks_per_step": 24, "status": "ok", "count_error": 0.0, "own_count_error": 0.0,
            "est_count": 3.0,
            "true_count": 3.0}
    rows = [{**base, "seed": 0, "step": k, "ospa": 2.0 if k < 3 else 0.5} for k in range(8)]
    rows += [{**base, "seed": 1, "step": k, "ospa": 0.2 if k < 5 else 1.5} for k in range(8)]
    rows += [{**base, "seed": 2, "step": 0, "ospa": 0.1},
             {**base, "seed": 2, "step": 1, "ospa": math.nan, "status": "error"}]
    runs = rk.per_seed(pd.DataFrame(rows), burn_in=3, lost_window=3, lost_ospa=1.0)
    assert runs["seed"].tolist() == [0, 1]  # the failed run is left out
    assert runs["ospa"].tolist() == pytest.approx([0.5, (2 * 0.2 + 3 * 1.5) / 5])
    assert runs["lost"].tolist() == [False, True]


# ------------------------------------------------------------ end to end
@pytest.fixture
def tiny(monkeypatch):
    monkeypatch.setitem(rk.SETTINGS, "reduced", TINY)


def _run(cache, out, *extra):
    return main(["reproduce", "kreucher", "--reduced", "--out", str(out), "--cache-dir",
                 str(cache), "--workers", "1", "--no-progress", *extra])


def test_reproduction_end_to_end_with_cache_and_checks(tiny, tmp_path, capsys):
    cache, ref = tmp_path / "cache", tmp_path / "ref" / "kreucher_reduced.csv"
    assert _run(cache, tmp_path / "a", "--check", "--reference-csv", str(ref)) == 2
    assert "no reference" in capsys.readouterr().err
    assert _run(cache, tmp_path / "a", "--update-reference", "--reference-csv", str(ref)) == 0
    io = capsys.readouterr()
    assert "runs computed" in io.out and "reference updated" in io.out
    assert ref.with_suffix(".versions.json").is_file()
    out = tmp_path / "a"
    for name in ("fig_managed_vs_periodic.png", "curve.csv", "matched.csv", "crossings.csv",
                 "numbers_reduced.csv", "report.md", "report.html"):
        assert (out / name).is_file(), name
    md = (out / "report.md").read_text()
    assert "312 looks revisit cells within a step (every cell 2x, 24 cells 3x)" in md
    assert "| kreucher-snr2 | kfnn | renyi | 24 |" in md
    assert (out / "report.html").read_text().count("data:image/png;base64,") == 1
    curve = pd.read_csv(out / "curve.csv")
    assert set(curve["scenario"]) == {"kreucher", "kreucher-snr2"}
    assert sorted(curve["looks"].unique()) == [24, 312]
    assert len(pd.read_csv(out / "matched.csv")) == 2  # renyi per scenario
    # the second time the runs come from the cache and both checks pass
    assert _run(cache, tmp_path / "b", "--check", "--reference-csv", str(ref)) == 0
    io = capsys.readouterr()
    assert "runs from the cache" in io.out and "check passed" in io.out
    assert _run(cache, tmp_path / "b", "--check", "--exact", "--reference-csv", str(ref)) == 0
    assert "check passed" in capsys.readouterr().out
    # --no-cache recomputes the same numbers and leaves the cache alone
    before = sorted(p.name for p in cache.iterdir())
    assert _run(cache, tmp_path / "c", "--no-cache", "--check", "--exact",
                "--reference-csv", str(ref)) == 0
    assert "runs computed" in capsys.readouterr().out
    assert sorted(p.name for p in cache.iterdir()) == before


def test_check_names_a_curve_point_moved_outside_its_band(tiny, tmp_path, capsys):
    cache, ref = tmp_path / "cache", tmp_path / "kreucher_reduced.csv"
    assert _run(cache, tmp_path / "a", "--update-reference", "--reference-csv", str(ref)) == 0
    numbers = reproduce.read_numbers(ref)
    sel = ((numbers["figure"] == "error") & (numbers["scenario"] == "kreucher")
           & (numbers["tracker"] == "kfnn / raster") & (numbers["step"] == 312)
           & (numbers["quantity"] == "state_error"))
    assert sel.sum() == 1
    moved = numbers.copy()
    old = float(moved.loc[sel, "value"].iloc[0])
    moved.loc[sel, "value"] = old + 1.0 if old < 1.0 else old - 1.0  # 20 floors of 0.05
    moved.to_csv(ref, index=False, float_format="%.17g")
    capsys.readouterr()
    assert _run(cache, tmp_path / "a", "--check", "--reference-csv", str(ref)) == 1
    err = capsys.readouterr().err
    assert "check FAILED" in err
    assert ("figure=error scenario=kreucher tracker=kfnn / raster step=312 item=0 "
            "quantity=state_error") in err
    # a moved true position (the simulated world) fails --check exactly
    world = numbers.copy()
    at = (world["figure"] == "snapshot") & (world["quantity"] == "truth.px")
    assert at.any()
    world.loc[at.idxmax(), "value"] += 1e-6
    world.to_csv(ref, index=False, float_format="%.17g")
    assert _run(cache, tmp_path / "a", "--check", "--reference-csv", str(ref)) == 1
    assert "quantity=truth.px" in capsys.readouterr().err

"""Budget frontiers: the log grid, the Pareto front, the cheapest-budget rule, the command's
refusals, a tiny frontier end to end and its resume after an interruption."""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
import pandas as pd
import pytest

from mttbench import trackers
from mttbench.benchmarks.app import frontier
from mttbench.benchmarks.app.cli import EXIT_INTERRUPTED, main
from mttbench.benchmarks.app.summary import per_run as summary_per_run
from mttbench.benchmarks.engine import sweep as engine_sweep
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.trackers.kfnn import KFNNTracker
from mttbench.trackers.params import Budget, budget_problem

#: the columns of frontier.csv that timing does not touch
ACCURACY = ["scenario", "tracker", "budget_param", "budget", "tracker_label", "ospa_mean",
            "ospa_ci95", "count_error_mean", "count_error_ci95", "n_seeds", "n_failed"]


# ------------------------------------------------------------------------ the log grid
@pytest.mark.parametrize(("low", "high", "points"), [(100, 16000, 5), (1, 8, 5), (1, 3, 10),
                                                     (3, 300, 7), (5, 120, 2), (4, 512, 1)])
def test_integer_grid_is_rounded_log_spaced_unique_and_within_range(low, high, points):
    grid = Budget(low, high).grid(points)
    assert all(isinstance(v, int) for v in grid)
    assert grid == sorted(set(grid))
    assert low <= grid[0] and grid[-1] <= high
    # independently: round low * (high / low) ** (i / (points - 1)), repeats dropped
    want = ([high] if points == 1 else
            sorted({round(low * (high / low) ** (i / (points - 1))) for i in range(points)}))
    assert grid == want
    if points > 1:
        assert grid[0] == low and grid[-1] == high


def test_grid_examples_and_narrowed_range():
    assert Budget(1, 8).grid(5) == [1, 2, 3, 5, 8]
    assert Budget(100, 16000).grid(3) == [100, 1265, 16000]
    assert Budget(100, 16000).grid(2, 250, 4000) == [250, 4000]
    floats = Budget(0.01, 1.0).grid(3, integer=False)
    assert floats == pytest.approx([0.01, 0.1, 1.0])


@pytest.mark.parametrize(("low", "high"), [(50, 4000), (100, 20000), (4000, 250)])
def test_grid_refuses_a_range_outside_the_declaration(low, high):
    with pytest.raises(ValueError, match="not within the declared"):
        Budget(100, 16000).grid(3, low, high)


def test_every_registered_budget_is_accepted_by_its_parameter():
    declared = 0
    for name in trackers.available():
        cls = trackers.get_class(name)
        assert budget_problem(cls) is None, name
        declared += bool(cls.budget)
    assert declared >= 5
    assert trackers.get_class("jmpd-ip").budget == trackers.get_class("jmpd").budget


def test_a_bad_budget_declaration_is_caught():
    class Wrong(KFNNTracker):
        budget: ClassVar = {"gate_probability": Budget(0.5, 2.0)}  # accepts (0, 1) only

    class Unknown(KFNNTracker):
        budget: ClassVar = {"n_particles": Budget(1, 10)}

    assert "refused" in budget_problem(Wrong)
    assert "not a declared numeric parameter" in budget_problem(Unknown)
    with pytest.raises(TypeError):
        Budget(10, 1)


# ----------------------------------------------------------------------- the Pareto front
def _dominated_brute_force(cost, loss):
    on = []
    for i in range(len(cost)):
        if not (np.isfinite(cost[i]) and np.isfinite(loss[i])):
            on.append(False)
            continue
        dominated = any(np.isfinite(cost[j]) and np.isfinite(loss[j]) and cost[j] <= cost[i]
                        and loss[j] <= loss[i] and (cost[j] < cost[i] or loss[j] < loss[i])
                        for j in range(len(cost)))
        on.append(not dominated)
    return np.array(on)


@pytest.mark.parametrize("seed", range(30))
def test_pareto_front_equals_the_brute_force_definition(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 25))
    # few distinct values: ties in cost, in loss and whole duplicates happen
    cost = rng.integers(0, 6, n).astype(float)
    loss = rng.integers(0, 6, n).astype(float)
    cost[rng.random(n) < 0.1] = np.nan
    on = frontier.pareto_mask(cost, loss)
    assert (on == _dominated_brute_force(cost, loss)).all()
    # read left to right: the least loss for at most that cost
    for i in np.flatnonzero(on):
        cheaper = np.isfinite(loss) & (cost <= cost[i])
        assert loss[i] == loss[cheaper].min()


# ------------------------------------------------------------------ the cheapest budget
def _table(rows):
    cols = ["scenario", "tracker", "budget_param", "budget", "ospa_mean", "ospa_ci95",
            "cpu_ms_mean", "cpu_ms_ci95"]
    return pd.DataFrame(rows, columns=cols)


HAND = _table([
    # a: plateau 1.00 at 100 ms; 1.04 at 10 ms is within 0.05, 1.06 at 1 ms is not
    ("s", "a", "n", 10, 1.06, 0.1, 1.0, 0.1),
    ("s", "a", "n", 100, 1.04, 0.1, 10.0, 1.0),
    ("s", "a", "n", 1000, 1.00, 0.1, 100.0, 10.0),
    # b: not monotone in the budget: the cheapest within is the larger budget
    ("s", "b", "k", 1, 1.30, 0.1, 5.0, 0.1),
    ("s", "b", "k", 2, 1.21, 0.1, 3.0, 0.1),
    ("s", "b", "k", 4, 1.20, 0.1, 8.0, 0.1),
    # c: one failed setting (NaN) is ignored
    ("s", "c", "", math.nan, 1.50, 0.1, 2.0, 0.1),
    ("t", "a", "n", 10, math.nan, math.nan, math.nan, math.nan),
])


def test_cheapest_within_the_plateau_by_hand():
    got = frontier.cheapest_within(HAND).set_index(["scenario", "tracker"])
    assert got.loc[("s", "a"), "budget"] == 100
    assert got.loc[("s", "a"), "target"] == pytest.approx(1.05)
    assert got.loc[("s", "a"), "best_budget"] == 1000
    assert got.loc[("s", "b"), "budget"] == 2
    assert got.loc[("s", "b"), "cpu_ms_mean"] == 3.0
    assert got.loc[("s", "c"), "ospa_mean"] == 1.50
    assert (got["rule"] == "plateau").all()
    assert math.isnan(got.loc[("t", "a"), "budget"])


def test_cheapest_within_the_reference_by_hand():
    ref = {"s": frontier.Reference(0.98, 0.01, "bayes")}
    got = frontier.cheapest_within(HAND, ref).set_index(["scenario", "tracker"])
    # a: within 1.03 only the largest budget
    assert got.loc[("s", "a"), "budget"] == 1000 and got.loc[("s", "a"), "rule"] == "bayes"
    assert got.loc[("s", "a"), "target"] == pytest.approx(1.03)
    # b never reaches it: no budget, its best still shown
    assert math.isnan(got.loc[("s", "b"), "budget"])
    assert got.loc[("s", "b"), "best_budget"] == 4
    # a scenario without a reference falls back to the plateau
    assert got.loc[("t", "a"), "rule"] == "plateau"
    assert "within 0.05 of the reference (bayes)" in frontier.cheapest_caption(ref)


# -------------------------------------------------------------------- the command line
BAD = [
    (["--trackers", "nope"], "nope"),
    (["--trackers", "null"], "declares no budget"),
    (["--trackers", "jmpd-ap", "--range", "jmpd-ap=10:100"], "not within the declared"),
    (["--trackers", "jmpd-ap", "--range", "jmpd-ap=100"], "expected NAME=LOW:HIGH"),
    (["--trackers", "jmpd-ap:n_particles=250"], "fixes n_particles"),
    (["--trackers", "gpf", "--range", "jmpd-ap=100:200"], "not one of the --trackers"),
    (["--trackers", "kfnn", "--range", "kfnn=1:2"], "no budget parameter"),
    (["--trackers", "gpf", "--range", "gpf.epsilon=0.1:0.2"], "not a budget parameter"),
    (["--trackers", "gpf", "--points", "0"], "--points 0"),
    (["--trackers", "gpf", "--policy", "raster", "random"], "one policy"),
]


@pytest.mark.parametrize(("extra", "message"), BAD)
def test_bad_input_is_refused_in_one_line(extra, message, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["frontier", "default", *extra, "--seeds", "2", "--out", str(out),
                 "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and message in err, err
    assert not out.exists()


TINY = ["frontier", "default", "--trackers", "gpf", "kfnn", "--range", "gpf=1:2",
        "--points", "2", "--seeds", "2", "--steps", "5", "--workers", "1", "--no-progress"]


def test_tiny_frontier_writes_every_file(tmp_path, capsys):
    out = tmp_path / "f"
    assert main([*TINY, "--out", str(out)]) == 0
    for name in ("results.parquet", "frontier.csv", "cheapest.csv", "frontier.md",
                 "frontier-default.png"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    assert (out / "frontier-default.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = pd.read_csv(out / "frontier.csv")
    assert list(table["tracker_label"]) == ["gpf(max_components=1)", "gpf(max_components=2)",
                                            "kfnn"]
    assert (table["n_seeds"] == 2).all() and (table["n_failed"] == 0).all()
    # the OSPA means against the summary module's per-run means; CPU by hand
    res = pd.read_parquet(out / "results.parquet")
    runs = summary_per_run(res)
    for _, r in table.iterrows():
        mine = runs[runs["tracker_label"] == r["tracker_label"]]
        assert r["ospa_mean"] == pytest.approx(mine["ospa"].mean(), rel=1e-12)
        steps = res[(res["tracker_label"] == r["tracker_label"]) & (res["step"] > 0)]
        cpu = steps.groupby("seed")["tracker_cpu_s"].mean().mean() * 1e3
        assert r["cpu_ms_mean"] == pytest.approx(cpu, rel=1e-12)
    assert table["pareto"].any()
    md = (out / "frontier.md").read_text()
    assert "frontier-default.png" in md and "Cheapest budget" in md


def test_reference_is_drawn_and_used(tmp_path):
    table = _table([("s", "a", "n", 1, 1.2, 0.1, 1.0, 0.1), ("s", "a", "n", 2, 1.0, 0.1, 2.0, 0.1)])
    table = table.assign(pareto=frontier.pareto_mask(table["cpu_ms_mean"], table["ospa_mean"]))
    from mttbench.benchmarks.app.figures_frontier import frontier_figure, tracker_styles

    path = frontier_figure(table, "s", tmp_path / "f.png",
                           reference=frontier.Reference(0.9, 0.05, "bayes"))
    assert path.read_bytes()[:4] == b"\x89PNG"
    styles = tracker_styles([f"t{i}" for i in range(12)])
    assert len(set(styles.values())) == 12
    assert len({c for c, _ in styles.values()}) == 12


def test_resume_after_an_interruption_gives_the_same_frontier(tmp_path, capsys, monkeypatch):
    whole = tmp_path / "whole"
    assert main([*TINY, "--out", str(whole)]) == 0
    real = engine_sweep.run_sweep

    def interrupted(jobs, out_dir, progress=None, **options):
        def stop(done: int, total: int) -> None:
            if done >= 2:
                raise KeyboardInterrupt

        return real(jobs, out_dir, progress=stop, **options)

    part = tmp_path / "part"
    monkeypatch.setattr(engine_sweep, "run_sweep", interrupted)
    assert main([*TINY, "--out", str(part)]) == EXIT_INTERRUPTED
    assert "--resume" in capsys.readouterr().err
    kept = {p.name: p.read_bytes() for p in (part / "parts").glob("*.parquet")}
    assert 2 <= len(kept) < 6 and not (part / "frontier.csv").exists()
    monkeypatch.setattr(engine_sweep, "run_sweep", real)
    assert main([*TINY, "--out", str(part), "--resume"]) == 0
    for name, data in kept.items():  # finished runs were not run again
        assert (part / "parts" / name).read_bytes() == data
    a = pd.read_csv(whole / "frontier.csv")
    b = pd.read_csv(part / "frontier.csv")
    pd.testing.assert_frame_equal(a[ACCURACY], b[ACCURACY])
    # and the table is what the rows say
    res = pd.read_parquet(part / "results.parquet")
    curves = frontier.build_curves(
        [TrackerSpec("gpf"), TrackerSpec("kfnn")], 2,
        frontier.parse_ranges(["gpf=1:2"]))
    again = frontier.frontier_table(res, curves).to_csv(index=False)
    assert again == (part / "frontier.csv").read_text()


def test_the_grid_of_a_curve_and_its_labels():
    curves = frontier.build_curves([TrackerSpec("jmpd-ap", {"t_max": 8})], 3)
    (c,) = curves
    assert c.param == "n_particles" and c.values == (100, 1265, 16000)
    assert [s.label for s in c.specs()] == [f"jmpd-ap(n_particles={n},t_max=8)"
                                            for n in (100, 1265, 16000)]
    assert c.name == "jmpd-ap(t_max=8)"


def test_jobs_run_seed_by_seed_over_every_setting():
    from mttbench.benchmarks.engine.specs import resolve_scenarios

    curves = frontier.build_curves([TrackerSpec("gpf"), TrackerSpec("kfnn")], 2)
    jobs = frontier.frontier_jobs(resolve_scenarios(["default"]), curves, None, None, [3, 1])
    labels = ["gpf(max_components=1)", "gpf(max_components=8)", "kfnn"]
    assert [(j.tracker.label, j.seed) for j in jobs] == [(x, s) for s in (3, 1) for x in labels]


def test_help_names_the_options(capsys):
    assert main(["frontier", "--help"]) == 0
    out = capsys.readouterr().out
    for option in ("--trackers", "--seeds", "--points", "--range", "--resume", "--executor"):
        assert option in out

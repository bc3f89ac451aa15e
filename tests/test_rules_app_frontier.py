"""Rules of the budget frontier (``benchmarks/app/frontier.py``, ``cli_frontier.py``)
where a slip shows: a run's first step with a large one-off time, a one-step run, points
of equal loss at two costs, costs and losses in opposite orders, a setting exactly at the
target, a best setting that missed a seed, ``MAX_POINTS`` itself, an infinite range end.
The Pareto front is checked against a brute-force dominance test."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pandas as pd
import pytest

from mttbench import scenarios
from mttbench.benchmarks.app import frontier
from mttbench.benchmarks.app.cli import build_parser
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec


def _steps(label: str, seed: int, cpu, ospa=1.0, status="ok") -> pd.DataFrame:
    n = len(cpu)
    return pd.DataFrame({"scenario": "a", "tracker_label": label, "seed": seed,
                         "step": range(n), "status": status, "ospa": ospa,
                         "count_error": 0.0, "tracker_cpu_s": cpu})


def test_the_cpu_time_leaves_out_the_first_step_but_not_a_runs_only_step():
    res = pd.concat([_steps("x", 0, [0.75, 0.001, 0.003]), _steps("y", 0, [0.002])])
    runs = frontier.per_run(res).set_index("tracker_label")
    assert runs.loc["x", "cpu_ms"] == pytest.approx(2.0)
    assert runs.loc["y", "cpu_ms"] == pytest.approx(2.0)


def _brute_front(cost, loss) -> list[bool]:
    out = []
    for i, (c, l) in enumerate(zip(cost, loss, strict=True)):
        if not (math.isfinite(c) and math.isfinite(l)):
            out.append(False)
            continue
        dominated = any(math.isfinite(c2) and math.isfinite(l2) and c2 <= c and l2 <= l
                        and (c2 < c or l2 < l)
                        for j, (c2, l2) in enumerate(zip(cost, loss, strict=True)) if j != i)
        out.append(not dominated)
    return out


@pytest.mark.parametrize(("cost", "loss"), [
    ([1.0, 2.0, 3.0], [1.0, 1.0, 0.5]),          # a dearer point of equal loss
    ([3.0, 1.0, 2.0], [0.5, 2.0, 1.0]),          # costs and losses in opposite orders
    ([1.0, 1.0, 2.0, math.nan], [2.0, 1.0, 1.0, 0.1]),
    ([2.0, 1.0, 3.0, 1.5], [1.0, 3.0, 0.5, 1.0])])
def test_the_pareto_front_is_the_undominated_points(cost, loss):
    assert list(frontier.pareto_mask(np.array(cost), np.array(loss))) == \
        _brute_front(cost, loss)


def test_the_pareto_front_of_random_points_by_brute_force():
    rng = np.random.default_rng(np.random.SeedSequence(11))
    for _ in range(20):
        cost = rng.integers(0, 4, 7).astype(float)
        loss = rng.integers(0, 4, 7).astype(float)
        assert list(frontier.pareto_mask(cost, loss)) == _brute_front(cost, loss)


def _table(rows) -> pd.DataFrame:
    return pd.DataFrame([{"scenario": "a", "tracker": "t", "budget_param": "n",
                          "budget": b, "ospa_mean": o, "ospa_ci95": 0.1, "cpu_ms_mean": c,
                          "cpu_ms_ci95": 0.1} for b, o, c in rows])


def test_the_cheapest_setting_within_the_target_includes_the_edge():
    # plateau: best 1.0 + 0.25 = 1.25; the setting at exactly 1.25 is within it
    table = _table([(100, 1.25, 1.0), (400, 1.0, 4.0)])
    out = frontier.cheapest_within(table, tolerance=0.25)
    assert out.loc[0, "budget"] == 100 and out.loc[0, "target"] == 1.25


def test_the_reference_target_is_its_mean_plus_the_tolerance():
    table = _table([(100, 1.25, 1.0), (400, 1.0, 4.0)])
    ref = {"a": frontier.Reference(1.0, 0.05)}
    out = frontier.cheapest_within(table, ref, tolerance=0.25)
    assert out.loc[0, "rule"] == "bayes" and out.loc[0, "target"] == 1.25
    assert out.loc[0, "budget"] == 100


def test_ospa_minus_best_pairs_only_the_shared_seeds():
    """Setting n=1 ran seeds 0, 1, 2; the best (n=2) finished seeds 0 and 1 only: the
    paired difference is over seeds 0 and 1."""
    res = pd.concat([_steps("t(n=1)", 0, [1e-3], 2.0), _steps("t(n=1)", 1, [1e-3], 2.5),
                     _steps("t(n=1)", 2, [1e-3], 9.0),
                     _steps("t(n=2)", 0, [1e-3], 1.0), _steps("t(n=2)", 1, [1e-3], 1.0),
                     _steps("t(n=2)", 2, [1e-3], 1.0, status="error")])
    table = frontier._minus_best(
        pd.DataFrame({"scenario": "a", "tracker": "t", "budget_param": "n",
                      "tracker_label": ["t(n=1)", "t(n=2)"], "ospa_mean": [4.5, 1.0]}),
        frontier.per_run(res))
    assert table.loc[0, "ospa_minus_best_mean"] == pytest.approx(1.25)  # (1.0 + 1.5) / 2
    assert table.loc[1, "ospa_minus_best_mean"] == 0.0


def test_the_jobs_go_seed_by_seed():
    sc = [dataclasses.replace(scenarios.get("default"), n_steps=2)]
    curves = [frontier.Curve(TrackerSpec("null"), None, ()),
              frontier.Curve(TrackerSpec("kfnn"), None, ())]
    jobs = frontier.frontier_jobs(sc, curves, PolicySpec("raster"), None, [5, 3])
    assert [j.seed for j in jobs] == [5, 5, 3, 3]
    assert [j.tracker.name for j in jobs] == ["null", "kfnn", "null", "kfnn"]


def test_points_up_to_max_points_are_allowed():
    curves = frontier.build_curves([TrackerSpec("jmpd-ap")], frontier.MAX_POINTS)
    assert len(curves[0].values) >= 2
    with pytest.raises(ConfigError, match="--points"):
        frontier.build_curves([TrackerSpec("jmpd-ap")], frontier.MAX_POINTS + 1)


@pytest.mark.parametrize("text", ["jmpd-ap=100:inf", "jmpd-ap=100:nan", "jmpd-ap=inf:400"])
def test_a_range_end_that_is_not_finite_is_refused(text):
    with pytest.raises(ConfigError, match="--range"):
        frontier.parse_ranges([text])


def test_the_commands_default_points_are_the_modules():
    args = build_parser().parse_args(["frontier", "default", "--trackers", "jmpd-ap"])
    assert args.points == frontier.DEFAULT_POINTS


def test_ranges_pairs_by_brute_force_small():
    # every pair of distinct ranges keeps its own low and high
    for lo, hi in itertools.permutations([100.0, 400.0, 1600.0], 2):
        assert frontier.parse_ranges([f"jmpd-ap={lo:g}:{hi:g}"]) == {"jmpd-ap": (None, lo, hi)}

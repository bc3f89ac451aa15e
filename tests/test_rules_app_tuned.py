"""Rules of the tuned files and compare's use of them (``benchmarks/app/tuned.py``)
where a slip shows: seed lists that are sorted but not consecutive, two consecutive
seeds, a value with a fourth significant digit, a tuned file that holds the defaults,
a parameter given both on the command line and in the file, a default run that failed,
a budget without a steps table, a non-finite objective. Expected texts are written out
by hand from the inputs."""

from __future__ import annotations

import math
import tomllib

import pandas as pd
import pytest

from mttbench.benchmarks.app import tuned
from mttbench.benchmarks.engine.specs import TrackerSpec


@pytest.mark.parametrize(("seeds", "text"), [([1, 3, 5], "1, 3, 5"), ([3, 4], "3..4"),
                                             ([7], "7"), ([3, 4, 5], "3..5"),
                                             ([4, 3], "4, 3")])
def test_seed_text_writes_a_range_only_for_consecutive_seeds(seeds, text):
    assert tuned._seed_text(seeds) == text


def test_values_are_shown_with_four_significant_digits():
    assert tuned._params_text({"b": 0.123456, "a": 3}) == "a=3, b=0.1235"


def _tuned_dir(tmp_path, params: dict) -> str:
    rec = {"format": 1, "tracker": "kfnn", "source": "trial 1", "params": params,
           "objective": {"metric": "ospa", "value": 1.1, "default_value": 1.3},
           "budget": {"trials": 2, "tuning_seeds": [1_000_000],
                      "scenarios": ["default", "crossing"]}}
    tuned.write_tuned(tmp_path / "kfnn.toml", rec)
    return str(tmp_path)


def test_the_defaults_run_beside_a_tuned_file_only_when_it_changes_them(tmp_path):
    d = _tuned_dir(tmp_path, {"lost_track_probability": 0.2})
    plan = tuned.plan_tuning([TrackerSpec("kfnn")], d, tuning_effect=True)
    assert [s.label for s in plan.specs] == ["kfnn", "kfnn(tuned)"]
    assert plan.pairs == [("kfnn", "kfnn(tuned)")]
    d = _tuned_dir(tmp_path, {})  # the file holds the defaults
    plan = tuned.plan_tuning([TrackerSpec("kfnn")], d, tuning_effect=True)
    assert [s.label for s in plan.specs] == ["kfnn(tuned)"]
    assert plan.pairs == []


def test_a_parameter_given_on_the_command_line_wins_over_the_file(tmp_path):
    d = _tuned_dir(tmp_path, {"lost_track_probability": 0.2})
    plan = tuned.plan_tuning([TrackerSpec.parse("kfnn:lost_track_probability=0.3")], d)
    (src,) = [s for s in plan.sources.values()]
    assert src.params["lost_track_probability"] == 0.3


def _steps(label: str, per_seed: dict[int, tuple[str, float]]) -> pd.DataFrame:
    """Two steps per seed: the first ok with the value, the second with the status (a
    failed run keeps the mean of its ok step, 50 here, so only its status drops it)."""
    rows = []
    for seed, (status, ospa) in per_seed.items():
        for step, st in enumerate(("ok", status)):
            rows.append({"scenario": "default", "tracker": "kfnn", "tracker_label": label,
                         "policy_label": "raster", "looks_per_step": 24, "seed": seed,
                         "step": step, "status": st, "error": "" if st == "ok" else "x",
                         "ospa": ospa, "tracker_wall_s": 1e-3, "tracker_cpu_s": 1e-3,
                         "select_wall_s": 0.0, "peak_rss_mb": 1.0})
    return pd.DataFrame(rows)


def test_the_effect_table_means_are_over_the_ok_runs(tmp_path):
    d = _tuned_dir(tmp_path, {"lost_track_probability": 0.2})
    plan = tuned.plan_tuning([TrackerSpec("kfnn")], d, tuning_effect=True)
    res = pd.concat([_steps("kfnn", {0: ("ok", 1.0), 1: ("ok", 2.0), 2: ("error", 50.0)}),
                     _steps("kfnn(tuned)", {0: ("ok", 0.5), 1: ("ok", 1.5), 2: ("ok", 1.0)})])
    table = tuned.tuning_effect_table(res, plan)
    assert table.loc[0, "default OSPA"].startswith("1.500 ± ")
    assert table.loc[0, "tuned - default (paired)"] == "-0.500 ± 0.000"
    assert int(table.loc[0, "pairs"]) == 2


def test_the_budget_text_counts_the_scenarios_without_a_steps_table(tmp_path):
    d = _tuned_dir(tmp_path, {"lost_track_probability": 0.2})
    tf = tuned.read_tuned(f"{d}/kfnn.toml")
    assert tf.budget_text() == "2 trials x 1 tuning seeds x 2 scenarios (scenario lengths)"


def test_a_non_finite_value_is_written_as_its_text():
    rec = tomllib.loads(tuned.dumps({"a": math.inf, "b": [1.0, math.nan], "c": None}))
    assert rec == {"a": "inf", "b": [1.0, "nan"]}

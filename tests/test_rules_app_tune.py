"""Rules of ``mttbench tune`` (``benchmarks/app/tune.py``, ``cli_tune.py``) on values
where a slip shows: a trial that only ties the defaults, two trials of equal value, zero
startup trials, a seed list that mixes evaluation and tuning seeds, per-seed values whose
mean and median differ, an unsupported run, an int parameter on a log scale, a manifest
with a bad batch size. No study is run: optuna's in-memory studies and hand-built step
tables stand in, and the expected values are written out from the inputs."""

from __future__ import annotations

import argparse
import json

import numpy as np
import optuna
import pandas as pd
import pytest

from mttbench import scenarios
from mttbench.benchmarks.app import cli_tune, tune
from mttbench.benchmarks.app.tuned import TUNING_SEED_BASE
from mttbench.benchmarks.app.usage import UsageError
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.trackers.params import Param, Search

B = TUNING_SEED_BASE


def _settings(**kw) -> tune.TuneSettings:
    base = {"tracker": TrackerSpec("kfnn"), "scenarios": (scenarios.get("default"),),
            "seeds": (B, B + 1)}
    base.update(kw)
    return tune.TuneSettings(**base)


# -------------------------------------------------------------------- settings
def test_zero_startup_trials_are_allowed_and_negative_ones_refused():
    assert _settings(startup_trials=0).startup_trials == 0
    with pytest.raises(UsageError, match="startup trials -1"):
        _settings(startup_trials=-1)


def test_every_tuning_seed_must_be_a_tuning_seed():
    with pytest.raises(UsageError, match="tuning seeds must be"):
        _settings(seeds=(0, B))
    with pytest.raises(UsageError, match="tuning seeds must be"):
        _settings(seeds=(B - 1,))


def test_the_budget_counts_trials_times_seeds_times_scenarios():
    s = _settings(trials=3, scenarios=(scenarios.get("default"), scenarios.get("crossing")))
    b = s.budget()
    assert (b["runs"], b["default_runs"]) == (3 * 2 * 2, 2 * 2)
    assert s.budget_text().endswith("= 12 runs, + 4 runs of the defaults")


def test_trial_seed_is_the_seed_sequence_of_seed_then_number():
    for seed, number in ((0, 1), (1, 0), (7, 12)):
        want = int(np.random.SeedSequence([seed, number]).generate_state(1)[0])
        assert tune.trial_seed(seed, number) == want
    assert tune.trial_seed(1, 0) != tune.trial_seed(0, 1)


# --------------------------------------------------------------- search space
class _Recorder:
    def __init__(self):
        self.calls = []

    def suggest_int(self, name, low, high, step=1, log=False):
        self.calls.append(("int", name, low, high, step, log))
        return low

    def suggest_float(self, name, low, high, step=None, log=False):
        self.calls.append(("float", name, low, high, step, log))
        return low

    def suggest_categorical(self, name, choices):
        self.calls.append(("cat", name, tuple(choices)))
        return choices[0]


def test_suggest_passes_the_declared_scale_for_ints_and_floats():
    space = {"n": (Param(int, low=1, high=5000), Search(low=10, high=5000, log=True)),
             "k": (Param(int, low=0, high=10), Search(low=0, high=10, step=2)),
             "x": (Param(float, low=0.0, high=1.0), Search(low=0.001, high=0.1, log=True)),
             "m": (Param(str, choices=("a", "b")), Search(choices=("a", "b")))}
    trial = _Recorder()
    out = tune.suggest(trial, space)
    assert trial.calls == [("int", "n", 10, 5000, 1, True), ("int", "k", 0, 10, 2, False),
                           ("float", "x", 0.001, 0.1, None, True), ("cat", "m", ("a", "b"))]
    assert out == {"n": 10, "k": 0, "x": 0.001, "m": "a"}


def test_describe_search_writes_closed_ranges():
    space = {"x": (Param(float, low=0.0, high=1.0), Search(low=0.001, high=0.1, log=True)),
             "k": (Param(int, low=0, high=10), Search(low=0, high=10, step=2))}
    assert tune.describe_search(space) == {"x": "float in [0.001, 0.1], log",
                                           "k": "int in [0, 10], step 2"}


# ------------------------------------------------------------------- objective
def _steps(label: str, per_seed: dict[int, tuple[str, float]], scenario: str = "default"
           ) -> pd.DataFrame:
    rows = []
    for seed, (status, ospa) in per_seed.items():
        for step, off in enumerate((-0.25, 0.25)):
            rows.append({"scenario": scenario, "tracker": "kfnn", "tracker_label": label,
                         "policy_label": "raster", "looks_per_step": 24, "seed": seed,
                         "step": step, "status": status,
                         "error": "" if status == "ok" else "cannot",
                         "ospa": ospa + off, "tracker_wall_s": 1e-3, "tracker_cpu_s": 1e-3,
                         "select_wall_s": 0.0, "peak_rss_mb": 1.0})
    return pd.DataFrame(rows)


def test_the_objective_is_the_mean_over_seeds_of_the_run_means():
    s = _settings(seeds=(B, B + 1, B + 2))
    res = _steps("kfnn", {B: ("ok", 1.0), B + 1: ("ok", 2.0), B + 2: ("ok", 6.0)})
    value, per_sc, msg = tune.objective_value(res, "kfnn", s)
    assert (value, per_sc, msg) == (3.0, {"default": 3.0}, "")


def test_an_unsupported_run_fails_the_trial():
    s = _settings()
    res = _steps("kfnn", {B: ("ok", 1.0), B + 1: ("unsupported", 1.0)})
    value, _, msg = tune.objective_value(res, "kfnn", s)
    assert value is None
    assert msg == f"default / seed {B + 1}: unsupported: cannot"


# ---------------------------------------------------------------- tuned record
def _study(values, default):
    study = optuna.create_study(direction="minimize")
    dist = {"lost_track_probability": optuna.distributions.FloatDistribution(0.001, 0.5,
                                                                             log=True)}
    for i, v in enumerate(values):
        study.add_trial(optuna.trial.create_trial(
            params={"lost_track_probability": 0.01 * (i + 1)}, distributions=dist, value=v))
    study.set_user_attr("default_value", default)
    study.set_user_attr("default_per_scenario", {"default": default})
    return study


def test_a_trial_that_only_ties_the_defaults_leaves_the_defaults(tmp_path):
    s = _settings()
    rec = tune.tuned_record(_study([1.5, 1.25], 1.25), s, s.space(), tmp_path, None)
    assert rec["params"] == {}
    assert rec["source"].startswith("defaults")
    rec = tune.tuned_record(_study([1.5, 1.25], 1.3), s, s.space(), tmp_path, None)
    assert rec["params"] == {"lost_track_probability": 0.02}


def test_of_two_equal_trials_the_earlier_is_best(tmp_path):
    s = _settings()
    rec = tune.tuned_record(_study([1.0, 0.5, 0.5], 2.0), s, s.space(), tmp_path, None)
    assert rec["source"] == "trial 1"
    assert rec["params"] == {"lost_track_probability": 0.02}


# ------------------------------------------------------------------- folders
def test_stored_batch_size_of_a_bad_manifest_is_none(tmp_path):
    man = {"status": "running", "trackers": {"kfnn": {"settings": {"batch_size": "x"}}}}
    (tmp_path / "manifest.json").write_text(json.dumps(man))
    assert tune.stored_batch_size(tmp_path, "kfnn") is None
    man["trackers"]["kfnn"]["settings"]["batch_size"] = 3
    (tmp_path / "manifest.json").write_text(json.dumps(man))
    assert tune.stored_batch_size(tmp_path, "kfnn") == 3


@pytest.mark.parametrize("status", ["interrupted", "failed", "running"])
def test_only_a_finished_manifest_is_a_finished_tune(tmp_path, status):
    (tmp_path / "manifest.json").write_text(json.dumps({"status": status}))
    assert not tune.is_finished(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"status": "finished"}))
    assert tune.is_finished(tmp_path)


# --------------------------------------------------------------- command line
def _args(**kw) -> argparse.Namespace:
    base = {"steps": None, "workers": None, "c": None, "p": 2.0, "run_timeout": None,
            "trials": 1, "batch_size": None, "startup_trials": 0, "seed": 0,
            "tuning_seeds": 1, "seed_start": B, "scenarios": ["no-such-scenario"],
            "trackers": ["kfnn"], "policy": ["raster"], "looks": None}
    base.update(kw)
    return argparse.Namespace(**base)


def _refused_by_the_checks(args) -> bool:
    """True if cmd_tune refuses ``args`` in its own checks (before resolving the
    scenarios, which this test names wrongly on purpose)."""
    try:
        cli_tune.cmd_tune(args)
    except UsageError as exc:
        return "no-such-scenario" not in str(exc)
    except Exception:  # noqa: BLE001 - past the checks: the unknown scenario
        return False
    return False


def test_the_tune_commands_limits_are_inclusive():
    assert not _refused_by_the_checks(_args(startup_trials=0))
    assert _refused_by_the_checks(_args(startup_trials=-1))
    assert not _refused_by_the_checks(_args(seed=2**32 - 1))
    assert _refused_by_the_checks(_args(seed=2**32))
    assert not _refused_by_the_checks(_args(seed_start=B))
    assert _refused_by_the_checks(_args(seed_start=B - 1))

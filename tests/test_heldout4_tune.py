"""tune's tie rules and its batches, by hand.

* The tuned file's choice (``tuned_record``) on a study built here: the best trial is
  the first of the least value; the defaults stay unless a trial is strictly better.
* Batches of ``B`` trials are the trial numbers ``kB .. kB + B - 1``: a study resumed
  with more trials after a batch cut short by ``--trials`` first completes that batch
  (recorded from the sweeps' jobs, each trial's runs one job per scenario and seed).
"""

from __future__ import annotations

from typing import ClassVar

import optuna
import pytest

from mttbench.benchmarks.app import progress, tune
from mttbench.benchmarks.engine.specs import TrackerSpec, resolve_scenarios
from mttbench.trackers.null import NullTracker
from mttbench.trackers.params import Param, Search

SEEDS = (tune.TUNING_SEED_BASE, tune.TUNING_SEED_BASE + 1)


class Still(NullTracker):
    """Reports nothing (the ``null`` baseline); one searched parameter, so every trial
    scores the same."""

    name = "test_still"
    summary = "test tracker: reports nothing"
    baseline = False
    parameters: ClassVar[dict[str, Param]] = {
        "level": Param(float, 0, 1, search=Search(0.0, 1.0)),
    }

    def __init__(self, level: float = 0.5) -> None:
        self.level = level


def _settings(name: str = "kfnn", **kw) -> tune.TuneSettings:
    return tune.TuneSettings(TrackerSpec.parse(name),
                             tuple(resolve_scenarios(["default"], 3)), SEEDS, **kw)


def _study(default: float, values: list[float]):
    st = _settings()
    space = st.space()
    study = optuna.create_study(direction="minimize",
                                sampler=optuna.samplers.RandomSampler(seed=3))
    study.set_user_attr("default_value", default)
    params = []
    for v in values:
        trial = study.ask()
        params.append(tune.suggest(trial, space))
        study.tell(trial, v)
    return st, space, study, params


@pytest.mark.parametrize("default, values, winner", [
    (0.6, [0.5, 0.4, 0.7, 0.4], 1),     # two trials tie at the least value: the first
    (0.4, [0.5, 0.4, 0.4], None),       # the best ties the defaults: the defaults stay
    (0.41, [0.5, 0.4, 0.4], 1),         # strictly better than the defaults
])
def test_the_tuned_file_takes_the_first_best_trial_and_keeps_defaults_on_a_tie(
        tmp_path, default, values, winner):
    st, space, study, params = _study(default, values)
    rec = tune.tuned_record(study, st, space, tmp_path, None)
    least = min(values)
    first = values.index(least)
    assert rec["objective"]["best_trial"] == first
    want = None if default <= least else first  # the rule written out
    assert want == winner
    if winner is None:
        assert rec["params"] == {} and rec["source"].startswith("defaults")
        assert rec["objective"]["value"] == default
    else:
        assert rec["params"] == params[winner] and rec["source"] == f"trial {winner}"
        assert rec["objective"]["value"] == values[winner]


def test_a_study_resumed_with_more_trials_first_completes_its_cut_batch(tmp_path):
    """Batches of 2; 3 trials make batches {0, 1} and {2}; resumed with 6, trial 3 is
    run alone (completing batch {2, 3}), then {4, 5}."""
    st = _settings("test_heldout4_tune:Still", trials=3, batch_size=2, startup_trials=6)
    batches: list[int] = []

    def sweep(jobs, out_dir, **kw):
        labels = {job.tracker.label for job in jobs}
        batches.append(len(labels - {st.spec({}).label}))  # the trials' settings
        return progress.run_sweep(jobs, out_dir, **kw)

    out = tmp_path / "out"
    tune.tune_tracker(st, out, tuned_dir=tmp_path / "tuned", progress=False, sweep=sweep)
    assert batches == [2, 1]
    more = _settings("test_heldout4_tune:Still", trials=6, batch_size=2, startup_trials=6)
    res = tune.tune_tracker(more, out, tuned_dir=tmp_path / "tuned", progress=False,
                            sweep=sweep, resume=True)
    assert batches == [2, 1, 1, 2]
    assert list(res.trials["number"]) == list(range(6))

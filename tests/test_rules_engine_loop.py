"""Rules of the harness (benchmarks/engine/loop.py) on tiny runs of test trackers: zero
looks, the key's default cut-off, memory units, parameter values, the run length cap,
the policy's own stream, each side's use of the truth, the estimate's checks and the
error row of a run failing at its first step."""

from __future__ import annotations

import dataclasses
import resource
from typing import ClassVar

import crashing_tracker
import numpy as np
import pytest

from mttbench import Estimate
from mttbench.benchmarks.engine import loop
from mttbench.benchmarks.engine.loop import Job, play, run_job
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec
from mttbench.scenarios import get as get_scenario
from mttbench.trackers import make


class FailFirst(crashing_tracker._Nothing):
    """Raises at step 0 with a two-line message."""

    name = "fail-first"
    summary = "test tracker: raises at step 0"
    parameters: ClassVar[dict] = {}

    def update(self, looks):
        raise ValueError("first line\nsecond line")


class LateLabels(crashing_tracker._Nothing):
    """One state on the first target's start; labels only from step 2 on."""

    name = "late-labels"
    summary = "test tracker: labels from step 2"
    parameters: ClassVar[dict] = {}

    def estimate(self):
        states = np.array([[2.5, 0.0, 3.5, 0.0]])
        return Estimate(1, states, labels=np.array([1]) if self._k >= 2 else None)


@pytest.fixture
def sc():
    return dataclasses.replace(get_scenario("single-clean"), n_steps=3)


def test_zero_looks_per_step_are_kept(sc):
    job = Job(sc, TrackerSpec("null"), looks_per_step=0)
    assert job.looks_per_step == 0
    rows = run_job(job)
    assert rows["looks_per_step"].tolist() == [0, 0, 0] and rows["n_looks"].tolist() == [0] * 3
    records = list(play(sc, make("null"), 0, looks_per_step=0))
    assert [len(r.looks.cells) for r in records] == [0, 0, 0]


def test_the_keys_default_cutoff_is_two_cells_of_the_scenarios_grid(sc):
    wide = dataclasses.replace(sc, model=dataclasses.replace(
        sc.model, grid=dataclasses.replace(sc.model.grid, cell_size=5.0)))
    job = Job(wide, TrackerSpec("null"))
    assert job.key(None, 2.0) == job.key(10.0, 2.0) != job.key(2.0, 2.0)


def test_peak_memory_is_in_mebibytes():
    mb = loop._peak_rss_mb()
    kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # Linux: KiB, never falls
    assert mb * 1024 <= kib < (mb + 1) * 1024


@pytest.mark.parametrize("value", ["text", 3, 2.5, True, None])
def test_scalar_parameters_are_written_as_they_are(value):
    assert loop._param_value(value) == value and type(loop._param_value(value)) is type(value)
    assert loop._param_value([1, "a"]) == '[1, "a"]'


def test_a_run_is_capped_at_the_scenarios_length(sc):
    assert len(list(play(sc, make("null"), 0, n_steps=50))) == 3
    assert len(list(play(sc, make("null"), 0, n_steps=2))) == 2


def test_the_random_policys_cells_do_not_depend_on_the_tracker(sc):
    cells = []
    for tracker in ("null", "crashing_tracker:Slow"):
        pol = PolicySpec("random").make()
        tr = make(tracker) if ":" not in tracker else TrackerSpec(tracker).make()
        cells.append([r.looks.cells.tolist() for r in play(sc, tr, 4, policy=pol,
                                                             n_steps=2)])
    assert cells[0] == cells[1]


def test_each_side_is_marked_by_its_own_use_of_the_truth(sc):
    row = loop._base_row(Job(sc, TrackerSpec("truth-aided"), PolicySpec("random")), None, 2)
    assert (row["tracker_uses_truth"], row["policy_uses_truth"]) == (True, False)
    row = loop._base_row(Job(sc, TrackerSpec("null"), PolicySpec("oracle")), None, 2)
    assert (row["tracker_uses_truth"], row["policy_uses_truth"]) == (False, True)


def test_the_estimates_checks():
    loop._check_estimate(0, np.zeros((0, 4)))  # no target is a count
    with pytest.raises(ValueError, match="not a finite number >= 0"):
        loop._check_estimate(-0.5, np.zeros((0, 4)))
    states = np.zeros((2, 4))
    assert loop._labels_of(Estimate(2, states, labels=np.array([4, 7])), 2).tolist() == [4, 7]
    with pytest.raises(ValueError, match="not 2 integers"):
        loop._labels_of(Estimate(2, states, labels=np.array([4.0, 7.0])), 2)


def test_a_run_failing_at_its_first_step_has_its_error_row_there(sc):
    rows = run_job(Job(sc, TrackerSpec(f"{__name__}:FailFirst")))
    assert len(rows) == 1
    row = rows.iloc[0]
    assert (row["step"], row["status"]) == (0, "error")
    assert row["error"] == "ValueError: first line second line"
    assert row["true_count"] == 1.0  # single-clean's one target at step 0


def test_a_run_unlabelled_at_some_step_keeps_only_the_scores_that_need_no_labels(sc):
    rows = run_job(Job(sc, TrackerSpec(f"{__name__}:LateLabels")))
    assert rows["status"].tolist() == ["ok"] * 3
    assert rows["tgospa"].isna().all() and rows["id_switches"].isna().all()
    # one target: no crossing, a number on every row (needs no labels)
    assert rows["crossings"].tolist() == [0.0] * 3

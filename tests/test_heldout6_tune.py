"""Tuned settings' labels: a tracker given parameters over its tuned file is labelled
``name(tuned,k=v,...)`` with the given keys sorted, as every tracker label is
(``specs.label``), so one setting typed in two orders is one setting."""

from __future__ import annotations

import pytest

from mttbench.benchmarks.app import tuned
from mttbench.benchmarks.app.usage import UsageError
from mttbench.benchmarks.engine.specs import TrackerSpec, label


def _tuned_dir(tmp_path):
    rec = {"format": 1, "tracker": "kfnn", "source": "trial 1",
           "params": {"lost_track_probability": 0.2},
           "objective": {"metric": "ospa", "value": 1.1, "default_value": 1.3},
           "budget": {"trials": 2, "tuning_seeds": [1_000_000], "scenarios": ["default"]}}
    tuned.write_tuned(tmp_path / "kfnn.toml", rec)
    return tmp_path


def test_a_tuned_label_lists_the_given_parameters_sorted(tmp_path):
    d = _tuned_dir(tmp_path)
    given = "kfnn:gate_probability=0.95,association=greedy"
    plan = tuned.plan_tuning([TrackerSpec.parse(given)], d)
    spec = TrackerSpec.parse(given)
    # the reference: the plain label's parameter text (sorted keys), after "tuned"
    want = "kfnn(tuned," + label("kfnn", spec.params)[len("kfnn("):]
    assert [s.label for s in plan.main] == [want]
    assert want == "kfnn(tuned,association=greedy,gate_probability=0.95)"
    swapped = "kfnn:association=greedy,gate_probability=0.95"
    assert [s.label for s in tuned.plan_tuning([TrackerSpec.parse(swapped)], d).main] == [want]
    # the same setting typed twice in two orders is refused, as untuned it is
    with pytest.raises(UsageError, match="more than once"):
        tuned.plan_tuning([TrackerSpec.parse(given), TrackerSpec.parse(swapped)], d)

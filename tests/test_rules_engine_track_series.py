"""Per-step series of the track scores (benchmarks/engine/track_series.py): the run's
value of a series is the mean over its steps that are not NaN; a series returning the
wrong columns or length is refused; series that need no labels (the crossings) are
computed for an unlabelled run."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mttbench.benchmarks.engine import track_metrics
from mttbench.benchmarks.engine.metrics import RunData
from mttbench.benchmarks.engine.track_series import RunSeries, series_values


def _run(T: int, labels: bool = True) -> RunData:
    # two targets that meet at step 2 (distance 0.5) and part again
    xs = [np.array([[0.0, 0.0], [3.0 - 1.25 * min(k, 2) + 1.25 * max(k - 2, 0), 0.0]])
          for k in range(T)]
    ids = [np.array([0, 1])] * T
    return RunData(xs, ids, xs, [np.array([5, 6])] * T if labels else None)


def test_the_run_value_of_a_series_is_its_mean_over_the_steps_that_are_not_nan():
    values = np.array([1.0, np.nan, 4.0, np.nan, 7.0])
    m = RunSeries("probe", series=lambda run: {"probe": values})
    assert m.fn(_run(5)) == {"probe": 4.0}  # (1 + 4 + 7) / 3
    empty = RunSeries("probe2", series=lambda run: {"probe2": np.full(5, np.nan)})
    assert math.isnan(empty.fn(_run(5))["probe2"])


@pytest.mark.parametrize("out, message", [
    ({"probe": np.zeros(4)}, "has 4 values for 5 steps"),
    ({"probe": np.zeros(6)}, "has 6 values for 5 steps"),
    ({"probe": np.zeros(5), "other": np.zeros(5)}, "returned the columns"),
    ({}, "returned the columns"),
])
def test_a_series_of_other_columns_or_length_is_refused(out, message):
    m = RunSeries("probe", series=lambda run: out)
    with pytest.raises(ValueError, match=message):
        m.values(_run(5))


def test_an_unlabelled_run_gets_the_crossings_and_nan_for_the_label_series():
    run = _run(6, labels=False)
    got = series_values(run)
    cr = track_metrics.crossings(run.truth, run.truth_ids, distance=2.0, window=5)
    # by hand: the pair is within 2 at steps 1, 2, 3 (distances 1.75, 0.5, 1.75): one
    # encounter, beginning at step 1
    assert cr.starts.tolist() == [0, 1, 0, 0, 0, 0]
    assert got["crossings"].tolist() == [0, 1, 0, 0, 0, 0]
    assert got["crossings_near"].tolist() == [1.0] * 6
    assert np.isnan(got["ospa2_window"]).all() and np.isnan(got["id_switches_step"]).all()

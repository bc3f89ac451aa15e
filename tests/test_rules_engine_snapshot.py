"""The traced run (benchmarks/engine/snapshot.py): its tables read each look's column and
row, the estimates' position covariances and the tracker's own count, checked against
values written out by hand and against the harness's rows of the same run."""

from __future__ import annotations

from typing import ClassVar

import crashing_tracker
import numpy as np
import pandas as pd

from mttbench import Estimate
from mttbench.benchmarks.engine.loop import Job, run_job
from mttbench.benchmarks.engine.snapshot import StepTrace, Trace, trace_run
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.scenarios import get as get_scenario

#: a covariance whose 16 entries all differ (entry [i, j] = 10 i + j + 1)
COV = (10 * np.arange(4)[:, None] + np.arange(4)[None, :] + 1).astype(float)


class Fractional(crashing_tracker._Nothing):
    """One state at (1.5, 2.5) with :data:`COV`, and a count of ``0.25 + k`` at step ``k``
    (so the count is never the number of states)."""

    name = "fractional"
    summary = "test tracker: one state, a fractional count"
    parameters: ClassVar[dict] = {}

    def estimate(self):
        return Estimate(0.25 + self._k, np.array([[1.5, 0.1, 2.5, -0.2]]), COV[None].copy())


def test_frames_read_the_cells_column_and_row_and_the_position_covariances():
    sc = get_scenario("single-clean")  # 6 x 6 cells
    step = StepTrace(step=3, cells=np.array([0, 7, 35, 13]), returns=np.array([1, 0, 0, 1]),
                     truth=np.array([[1.0, 0.0, 2.0, 0.0]]), truth_ids=np.array([4]),
                     est_states=np.array([[1.5, 0.1, 2.5, -0.2], [4.0, 0.0, 5.0, 0.0]]),
                     est_covs=np.stack([COV, 2 * COV]), est_count=1.75)
    frames = Trace(sc, "t", "raster", 0, [step]).frames()
    looks = frames["looks"]
    # cell c = iy * nx + ix on the 6-wide grid: 7 -> (1, 1), 35 -> (5, 5), 13 -> (1, 2)
    assert looks["ix"].tolist() == [0, 1, 5, 1]
    assert looks["iy"].tolist() == [0, 1, 5, 2]
    assert looks["positive"].tolist() == [True, False, False, True]
    est = frames["estimates"]
    # positions are state entries 0 (px) and 2 (py): [0, 0] = 1, [0, 2] = 3, [2, 2] = 23
    assert est["cov_xx"].tolist() == [1.0, 2.0]
    assert est["cov_xy"].tolist() == [3.0, 6.0]
    assert est["cov_yy"].tolist() == [23.0, 46.0]
    assert est["count"].tolist() == [1.75, 1.75]
    assert frames["counts"]["count"].tolist() == [1.75]


def test_a_traced_run_is_the_harness_run_with_the_trackers_own_count():
    sc = get_scenario("single-clean")
    spec = TrackerSpec(f"{__name__}:Fractional")
    trace = trace_run(sc, spec, seed=3, n_steps=4)
    counts = trace.frames()["counts"]
    assert counts["count"].tolist() == [0.25, 1.25, 2.25, 3.25]  # never the 1 state
    rows = run_job(Job(sc, spec, seed=3))
    head = rows[rows["step"] < 4]
    pd.testing.assert_series_equal(counts["count"], head["est_count"].reset_index(drop=True),
                                   check_names=False)
    looks = trace.frames()["looks"]
    assert looks.groupby("step").size().tolist() == head["n_looks"].tolist()
    assert looks.groupby("step")["positive"].sum().tolist() == head["n_positive"].tolist()
    est = trace.frames()["estimates"]
    assert (est["cov_xy"] == COV[0, 2]).all() and (est["cov_yy"] == COV[2, 2]).all()

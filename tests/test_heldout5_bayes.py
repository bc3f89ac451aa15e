"""A bayes rung from a sweep's rows: a run counts when every one of its rows is ok (as in
the summaries), so a run that failed part-way gives no OSPA (nor a null floor) and
counts as an error. Reference: the per-seed means written out from the rows."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from mttbench.benchmarks.app import bayes


def test_a_run_that_failed_part_way_is_left_out_of_its_rungs_ospa():
    rows = []
    ospa = {0: [0.4, 0.6, 0.8], 1: [0.2, 0.3, np.nan], 2: [1.0, 1.2, 1.4]}
    for seed, values in ospa.items():
        for step, v in enumerate(values):
            failed = seed == 1 and step == 2
            rows.append({"seed": seed, "step": step, "status": "error" if failed else "ok",
                         "ospa": v, "tracker_cpu_s": 0.001 * (seed + 1),
                         "true_count": 1, "ospa_c": 2.0})
    rung = bayes.rung_of(pd.DataFrame(rows), 100)
    assert rung.ospa == {0: pytest.approx(0.6), 2: pytest.approx(1.2)}
    assert rung.errors == 1
    assert set(rung.null_ospa) == {0, 2}
    assert rung.gap() == pytest.approx(np.mean([2.0 - 0.6, 2.0 - 1.2]))

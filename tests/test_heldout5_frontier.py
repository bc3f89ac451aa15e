"""The frontier table's ``ospa_minus_best``: per setting, its per-seed OSPA minus that of
its tracker's best setting (least mean OSPA) on the same seed, paired over the seeds
both ran ok; 0 at the best setting, positive elsewhere. Reference: the differences and
scipy's t interval written out from hand-made runs."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mttbench.benchmarks.app.frontier import _minus_best


def test_each_setting_is_compared_with_its_trackers_best_on_the_same_seeds():
    ospa = {"t(n=10)": [0.9, 1.1, 1.0, 1.3], "t(n=20)": [0.5, 0.7, 0.65, 0.8],
            "t(n=40)": [0.6, 0.75, 0.7, 0.9]}
    runs = pd.DataFrame([{"scenario": "s", "tracker_label": lab, "seed": i, "ok": i != 3 or
                          lab != "t(n=40)", "ospa": v}
                         for lab, vs in ospa.items() for i, v in enumerate(vs)])
    table = pd.DataFrame({"scenario": "s", "tracker": "t", "budget_param": "n",
                          "tracker_label": list(ospa),
                          "ospa_mean": [np.mean(v) for v in ospa.values()]})
    out = _minus_best(table, runs).set_index("tracker_label")
    best = np.array(ospa["t(n=20)"])
    assert out.loc["t(n=20)", "ospa_minus_best_mean"] == 0.0
    for lab, n in (("t(n=10)", 4), ("t(n=40)", 3)):
        d = np.array(ospa[lab])[:n] - best[:n]
        lo, hi = stats.t.interval(0.95, n - 1, loc=d.mean(), scale=stats.sem(d))
        assert out.loc[lab, "ospa_minus_best_mean"] == pytest.approx(d.mean(), rel=1e-12)
        assert out.loc[lab, "ospa_minus_best_mean"] > 0
        assert out.loc[lab, "ospa_minus_best_ci95"] == pytest.approx((hi - lo) / 2, rel=1e-10)

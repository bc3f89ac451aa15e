"""The bayes ladder when more particles make the answer worse: the paired step's bound is
``|mean| + half-width`` whichever rung is lower, so a rung that moves the OSPA up by more
than the tolerance never counts as converged (the rule is symmetric in the two rungs).

Reference: the paired t interval of the per-seed differences, computed here with scipy.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats
from test_bayes import SEED_NOISE, TINY, rung, synthetic_sweep

from mttbench.benchmarks.app import bayes


def test_the_bound_of_a_step_is_the_same_in_either_direction():
    lo, hi = [1.0, 1.2, 0.9, 1.1], [1.08, 1.31, 0.97, 1.2]  # the higher rung is worse
    d = np.subtract(lo, hi)
    half = stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / math.sqrt(len(d))
    up = bayes.paired_step(rung(10, lo), rung(40, hi))
    down = bayes.paired_step(rung(10, hi), rung(40, lo))
    assert up["diff_mean"] == pytest.approx(d.mean(), abs=1e-6) and d.mean() < 0
    assert up["bound"] == pytest.approx(abs(d.mean()) + half, abs=1e-6)
    assert up["bound"] == pytest.approx(down["bound"], abs=1e-6)


def test_a_ladder_whose_ospa_rises_with_n_is_not_converged(tmp_path):
    # OSPA(n) = 1 - 1/sqrt(n): each step moves the OSPA up by 0.5/sqrt(n), beyond 0.02
    # until 1600 -> 6400 (0.0125); as the falling ladder of test_bayes, converged only at
    # 25600, the second step within
    sweep, calls = synthetic_sweep(lambda n, s: 1.0 - 1.0 / math.sqrt(n) + SEED_NOISE[s])
    ladder = bayes.Ladder(n_start=100, factor=4, n_max=102400, tolerance=0.02,
                          run_limit_s=1e9, gap_share=0.0)
    ref = bayes.run_ladder([TINY], range(4), sweep, tmp_path, ladder=ladder,
                           say=lambda _: None)[TINY.name]
    steps = ref.provenance["steps"]
    assert [s["diff_mean"] < 0 for s in steps] == [True] * len(steps)
    for s in steps:
        assert s["bound"] == pytest.approx(abs(s["diff_mean"]) + s["diff_ci95"], abs=1e-5)
    assert ref.converged and ref.n_particles == 25600
    assert sorted(set(calls)) == [100, 400, 1600, 6400, 25600]

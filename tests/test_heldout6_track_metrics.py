"""The dense layout of a run's per-step positions and ids (``track_metrics.as_dense``):
a step whose ids and positions differ in number is refused, naming the step, even when
the run's totals agree (so no later shape check could notice)."""

from __future__ import annotations

import numpy as np
import pytest

from mttbench.benchmarks.engine.track_metrics import as_dense


def test_a_step_with_more_positions_than_ids_is_refused_though_the_totals_agree():
    points = [np.array([[0.0, 0.0], [1.0, 1.0]]), np.array([[2.0, 2.0]])]
    ids = [np.array([7]), np.array([7, 8])]  # 3 positions and 3 ids in all
    with pytest.raises(ValueError, match=r"^step 0: 2 positions but 1 ids$"):
        as_dense(points, ids)
    ids = [np.array([7, 8]), np.array([9, 8])]  # each step agrees: laid out by id
    pos, present = as_dense([points[0], np.array([[2.0, 2.0], [3.0, 3.0]])], ids)
    want = np.full((2, 3, 2), np.nan)
    want[0, 0], want[0, 1], want[1, 2], want[1, 1] = [0, 0], [1, 1], [2, 2], [3, 3]
    np.testing.assert_array_equal(pos, want)
    np.testing.assert_array_equal(present, ~np.isnan(want[..., 0]))


@pytest.mark.parametrize("seed", [1421, 2632, 2884])
def test_tgospa_whose_lp_relaxation_is_fractional_equals_brute_force(seed, monkeypatch):
    """Runs whose linear relaxation has a fractional optimum (found by a search over
    seeds), so HiGHS must fall back to the integer programme: the total is the brute
    force minimum over every sequence of per-step assignments, and the parts add up."""
    from test_track_metrics import _brute_tgospa, _random_run

    from mttbench.benchmarks.engine import track_metrics

    rng = np.random.default_rng(seed)
    nx, ny, T = int(rng.integers(2, 4)), int(rng.integers(2, 4)), int(rng.integers(3, 7))
    tpos, tids = _random_run(rng, nx, T, spread=float(rng.uniform(0.5, 3)))
    epos, elab = _random_run(rng, ny, T, spread=float(rng.uniform(0.5, 3)), id0=10)
    c, p, gamma = 2.0, float(rng.choice([1.0, 2.0])), float(rng.choice([0.5, 1.0, 2.0]))
    monkeypatch.setattr(track_metrics, "_tgospa_dp", lambda *a, **k: None)  # HiGHS only
    g = track_metrics.trajectory_gospa(tpos, tids, epos, elab, c=c, p=p, gamma=gamma)
    assert g.solver == "milp"
    assert g.total == pytest.approx(_brute_tgospa(tpos, tids, epos, elab, c, p, gamma),
                                    abs=1e-9)
    assert g.localisation + g.missed + g.false + g.switch == pytest.approx(g.total**p)

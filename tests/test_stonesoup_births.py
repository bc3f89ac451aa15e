"""The Stone Soup peers' births from the model's untracked targets, not its whole density:
a detection where the looks have already found no target starts a light component (GM-PHD)
or an unlikely track (GNN), so clutter is not reported as targets."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import expit
from scipy.stats import multivariate_normal

from mttbench import trackers
from mttbench.scenarios.model import Looks
from mttbench.scenarios.spec import get as get_scenario
from mttbench.trackers.stonesoup import peers as sp

pytestmark = pytest.mark.skipif(sp.missing_extra() is not None, reason="needs stonesoup")


def _looks(cells, returns) -> Looks:
    return Looks(np.asarray(cells, np.int64), np.asarray(returns, bool))


def test_gmphd_birth_weight_is_the_untracked_intensity():
    """default (3 targets, no arrivals), every cell looked at per step. Step 0: one
    detection at ``c``; its birth component weighs ``b0 = n0 / n`` and is updated to ``w1 =
    p b0 q / (kappa + p b0 q)``. Step 1: a detection at a far cell ``c2``: the component at
    ``c`` is missed (times ``1 - p``) and the birth at ``c2`` weighs the undetected intensity
    there after step 0's look, ``b0 l0`` (``l0 = (1 - p_d) / (1 - p_f)``), plus the share
    of the model's 3 targets that neither the mixture nor that intensity holds, ``(3 - w1 -
    3 l0) / n``. The estimated count, the sum of the weights, matches to 1e-9."""
    model = get_scenario("default").model
    grid, sensor, bd = model.grid, model.sensor, model.birth_death
    n, n0 = grid.n_cells, bd.initial_count_mean
    tracker = trackers.make("ss-gmphd", birth_velocity_scale=1.0, prune_threshold=1e-12)
    tracker.reset(model, np.random.default_rng(0))
    every = np.arange(n)
    F, Q = model.dynamics.F, model.dynamics.Q
    r = grid.cell_size ** 2 / 12.0
    sv = bd.birth_velocity_std
    P_birth = F @ np.diag([r, sv * sv, r, sv * sv]) @ F.T + Q
    q = multivariate_normal(mean=np.zeros(2),
                            cov=P_birth[np.ix_([0, 2], [0, 2])] + r * np.eye(2)).pdf(np.zeros(2))
    p = (sensor.p_d - sensor.p_f) / (1 - sensor.p_f)
    kappa = sensor.p_f / grid.cell_size ** 2
    l0 = (1 - sensor.p_d) / (1 - sensor.p_f)

    def updated(b):
        return p * b * q / (kappa + p * b * q)

    c, c2 = 2 * grid.nx + 2, 9 * grid.nx + 9
    tracker.predict()
    tracker.update(_looks(every, every == c))
    w1 = updated(n0 / n)
    assert tracker.estimate().count == pytest.approx(w1, rel=1e-12)
    tracker.predict()
    tracker.update(_looks(every, every == c2))
    b2 = n0 / n * l0 + (n0 - w1 - n0 * l0) / n
    assert tracker.estimate().count == pytest.approx(w1 * (1 - p) + updated(b2), rel=1e-9)
    # every cell looked at: the birth gets what the mixture does not hold, spread evenly
    assert b2 == pytest.approx((n0 - w1) / n, rel=1e-12)


def test_gnn_track_prior_is_the_untracked_intensity_at_its_birth():
    """default, every cell looked at per step. A track born at step 0 at ``c`` has
    existence ``sigmoid(L0 + log(p_d / p_f))`` with ``L0 = log(exp(lambda) - 1)``, ``lambda
    = n0 / n``; one born at step 1 at a far cell, after a negative look there, starts from
    ``lambda l0`` plus the share of the model's 3 targets that neither the first track
    (existence ``r``) nor the undetected intensity (``3 l0``) holds, ``(3 - r - 3 l0) / n``:
    its existence is that of the smaller prior (scipy's expit, to 1e-12)."""
    model = get_scenario("default").model
    grid, sensor, bd = model.grid, model.sensor, model.birth_death
    n, n0 = grid.n_cells, bd.initial_count_mean
    tracker = trackers.make("ss-gnn")
    tracker.reset(model, np.random.default_rng(0))
    every = np.arange(n)
    l0 = (1 - sensor.p_d) / (1 - sensor.p_f)
    log_pos = np.log(sensor.p_d / sensor.p_f)
    c, c2 = 2 * grid.nx + 2, 9 * grid.nx + 9
    tracker.predict()
    tracker.update(_looks(every, every == c))
    (first,) = tracker._tracks + list(tracker._initiator.holding_tracks)
    tracker.predict()
    tracker.update(_looks(every, (every == c) | (every == c2)))
    tracks = tracker._tracks + list(tracker._initiator.holding_tracks)
    (second,) = [tr for tr in tracks if tr.id != first.id]
    r = tracker._existence([first])[0]
    want = expit(np.log(np.expm1(n0 / n * l0 + (n0 - r - n0 * l0) / n)) + log_pos)
    got = tracker._existence([second])[0]
    assert got == pytest.approx(want, rel=1e-12)
    assert got < expit(np.log(np.expm1(n0 / n)) + log_pos) - 0.01  # a smaller prior
    assert tracker._prior_logodds[first.id] == pytest.approx(np.log(np.expm1(n0 / n)))

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
    tracker = trackers.make("ss-gnn", association="distance")
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


# ======================================================================= ss-jpda
def _births_model():
    """``births``: survival 0.98, 0.05 arrivals a step, ``die`` at the walls."""
    model = get_scenario("births").model
    bd = model.birth_death
    assert bd.boundary == "die" and bd.survival_probability < 1 and bd.birth_rate > 0
    return model


def test_jpda_undetected_intensity_per_look_and_its_birth_existence():
    """Step 0: cell ``a`` looked at 3 times, ``c`` once, all negative: from ``lambda_1 = p_s
    n0 / n + b / n`` the intensity is ``lambda_1 m^3`` at ``a`` and ``lambda_1 m`` at ``c``
    (``m = (1 - p_d) / (1 - p_f)``, once per look), ``lambda_1`` elsewhere. Step 1: ``a``
    looked at twice, one positive: a track is born with existence ``(1 - e^{-x}) / (1 - (1
    - p_f,2) e^{-x})``, ``x = lambda_2 (1 - (1 - p_d)^2)``, ``p_f,2 = 1 - (1 - p_f)^2``,
    ``lambda_2 = p_s lambda_1 m^3 + b / n``; ``a`` then holds ``lambda_2 m^2``."""
    model = _births_model()
    grid, sensor, bd = model.grid, model.sensor, model.birth_death
    n, ps, b = grid.n_cells, bd.survival_probability, bd.birth_rate
    p_d, p_f = sensor.p_d, sensor.p_f
    m = (1 - p_d) / (1 - p_f)
    tracker = trackers.make("ss-jpda")
    tracker.reset(model, np.random.default_rng(0))
    a, c, far = 5 * grid.nx + 5, 5 * grid.nx + 6, 11 * grid.nx + 1
    tracker.predict()
    tracker.update(_looks([a, a, a, c], [False] * 4))
    lam1 = ps * bd.initial_count_mean / n + b / n
    np.testing.assert_allclose(tracker._undetected.at(np.array([a, c, far])),
                               [lam1 * m ** 3, lam1 * m, lam1], rtol=1e-12)
    assert len(tracker.existence) == 0
    tracker.predict()
    tracker.update(_looks([a, a], [True, False]))
    lam2 = ps * lam1 * m ** 3 + b / n
    x = lam2 * (1 - (1 - p_d) ** 2)
    r0 = -np.expm1(-x) / (1 - (1 - p_f) ** 2 * np.exp(-x))
    assert r0 > tracker.prune_existence
    np.testing.assert_allclose(tracker.existence, [r0], rtol=1e-12)
    np.testing.assert_allclose(tracker._undetected.at(np.array([a, c, far])),
                               [lam2 * m ** 2, ps * lam1 * m + b / n, ps * lam1 + b / n],
                               rtol=1e-12)


def test_jpda_recycles_only_the_tentative_tracks_it_prunes_or_caps():
    """Six tracks at rest, none looked at (one negative look far away), cap of one track:
    a tentative track pruned (``p_s r`` below ``prune_existence``) and one dropped by the
    cap give ``p_s r`` back to the undetected intensity of their cell; a tentative track
    outside the workspace (``die``), one the covariance deleter removes and a confirmed
    one deleted below ``beta`` give nothing; the kept track is the most probable. The
    whole field must equal ``p_s (p_s n0 / n + b / n) + b / n`` (two steps; times ``m`` at
    the looked cell) plus exactly those two amounts."""
    model = _births_model()
    grid, bd = model.grid, model.birth_death
    n, ps, b = grid.n_cells, bd.survival_probability, bd.birth_rate
    m_ratio = (1 - model.sensor.p_d) / (1 - model.sensor.p_f)
    tracker = trackers.make("ss-jpda", max_tracks=1)
    tracker.reset(model, np.random.default_rng(0))
    tracker.predict()

    def at(ix, iy):
        return [(ix + 0.5) * grid.cell_size, 0.0, (iy + 0.5) * grid.cell_size, 0.0]

    sharp = np.diag([0.05, 0.01, 0.05, 0.01])
    wide = np.diag([100.0, 0.01, 100.0, 0.01])  # position sd 10 cells > max_position_sd 5
    tracks = {  # name: (mean, covariance, existence, confirmed)
        "pruned": (at(2, 2), sharp, 0.5 * tracker.prune_existence, False),
        "outside": ([-3.0, 0.0, 5.5, 0.0], sharp, 0.5 * tracker.prune_existence, False),
        "too-wide": (at(8, 2), wide, 0.5, False),
        "deleted": (at(2, 8), sharp, 0.5 * tracker.lost_track_probability, True),
        "kept": (at(8, 8), sharp, 0.3, False),
        "capped": (at(5, 5), sharp, 0.2, False),
    }
    mean, cov, r, confirmed = (np.array(x) for x in zip(*tracks.values(), strict=True))
    tracker.set_tracks(mean, cov, r, confirmed)
    tracker.predict()
    looked = 11 * grid.nx + 11
    tracker.update(_looks([looked], [False]))
    field = np.full(n, ps * (ps * bd.initial_count_mean / n + b / n) + b / n)  # 2 predicts
    field[looked] *= m_ratio
    for name in ("pruned", "capped"):
        (x, _, y, _), _, r_name, _ = tracks[name]
        field[int(y) * grid.nx + int(x)] += ps * r_name
    np.testing.assert_allclose(tracker._undetected.at(np.arange(n)), field, rtol=1e-12)
    np.testing.assert_allclose(tracker.existence, [ps * tracks["kept"][2]], rtol=1e-12)

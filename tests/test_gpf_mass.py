"""GPF mass accounting: reflecting walls fold each Gaussian's mass back into the
workspace, absorbing walls truncate it (the mass outside is death), and targets the model
expects but no particle holds return to the undetected field.

References are independent: Monte Carlo samples folded or truncated by hand (400,000
draws; tolerances of 5 standard errors of each moment), and exact moment algebra.
"""

from __future__ import annotations

import numpy as np
import pytest

from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.trackers.cells import CellField
from mttbench.trackers.gpf import (
    DEFAULT_DEATH_FLOOR,
    EmptyPriorGPF,
    GaussianParticleFilter,
    truncate_to_workspace,
)
from mttbench.trackers.gpf.grid import fold_into_workspace

N_MC = 400_000
W, H = 12.0, 12.0


def _gaussian(mean, sds, corr_pv=0.6):
    """A state Gaussian ``[px, vx, py, vy]`` with position-velocity correlation per axis
    and a little x-y correlation."""
    sx, svx, sy, svy = sds
    P = np.diag(np.square(sds)).astype(float)
    P[0, 1] = P[1, 0] = corr_pv * sx * svx
    P[2, 3] = P[3, 2] = corr_pv * sy * svy
    P[0, 2] = P[2, 0] = 0.2 * sx * sy
    return np.asarray(mean, dtype=float), P


def _mc_check(samples, mean, cov, z=5.0):
    """Mean and covariance of ``samples`` equal ``mean``, ``cov`` within ``z`` standard
    errors (the errors estimated from the samples' own fourth moments)."""
    n = len(samples)
    mu = samples.mean(axis=0)
    se_mu = samples.std(axis=0) / np.sqrt(n)
    assert np.all(np.abs(mu - mean) <= z * se_mu + 1e-12), (mu, mean, se_mu)
    d = samples - mu
    prods = d[:, :, None] * d[:, None, :]
    c = prods.mean(axis=0)
    se_c = prods.std(axis=0) / np.sqrt(n)
    assert np.all(np.abs(c - cov) <= z * se_c + 1e-12), (c, cov, se_c)


@pytest.mark.parametrize("mean", [(11.2, 0.3, 6.0, 0.1), (0.4, -0.2, 11.5, 0.25),
                                  (6.0, 0.0, -0.3, -0.2)])
def test_fold_matches_folded_samples(mean):
    """Reflecting walls: samples of the Gaussian, each coordinate beyond a wall mirrored
    (and its velocity negated), have the moments :func:`fold_into_workspace` returns."""
    m, P = _gaussian(mean, (0.5, 0.1, 0.6, 0.12))
    rng = np.random.default_rng(np.random.SeedSequence(1))
    x = rng.multivariate_normal(m, P, size=N_MC)
    for p, v, length in ((0, 1, W), (2, 3, H)):
        low, high = x[:, p] < 0, x[:, p] >= length
        x[low, p] = -x[low, p]
        x[high, p] = 2 * length - x[high, p]
        x[low | high, v] = -x[low | high, v]
    fm, fP = fold_into_workspace(m[None], P[None], Grid(12, 12, 1.0))
    _mc_check(x, fm[0], fP[0])


def test_fold_leaves_a_gaussian_inside_unchanged():
    m, P = _gaussian((6.0, 0.1, 6.0, 0.1), (0.5, 0.1, 0.5, 0.1))
    fm, fP = fold_into_workspace(m[None], P[None], Grid(12, 12, 1.0))
    assert np.array_equal(fm[0], m) and np.array_equal(fP[0], P)


@pytest.mark.parametrize("mean", [(11.4, 0.3, 6.0, 0.1), (0.2, -0.2, 0.5, -0.1)])
def test_truncate_matches_the_samples_inside(mean):
    """Absorbing walls: the mass inside and the moments of the samples that stay inside."""
    m, P = _gaussian(mean, (0.6, 0.1, 0.5, 0.12))
    rng = np.random.default_rng(np.random.SeedSequence(2))
    x = rng.multivariate_normal(m, P, size=N_MC)
    inside = (x[:, 0] >= 0) & (x[:, 0] < W) & (x[:, 2] >= 0) & (x[:, 2] < H)
    mass, tm, tP = truncate_to_workspace(m[None], P[None], W, H)
    p = inside.mean()
    assert abs(mass[0] - p) <= 5 * np.sqrt(p * (1 - p) / N_MC)
    _mc_check(x[inside], tm[0], tP[0])


def _fixed_count_model(n0=3, birth_rate=0.0):
    return TrackingModel(
        grid=Grid(12, 12, 1.0), dynamics=Dynamics(tau=1.0, wna_intensity=5e-4),
        birth_death=BirthDeath(initial_states=tuple((1.0 + i, 0.0, 1.0, 0.0) for i in range(n0)),
                               birth_rate=birth_rate),
        sensor=RayleighGridSensor())


@pytest.mark.parametrize("birth_rate", [0.0, 0.01])
def test_missing_targets_return_to_the_undetected_field(birth_rate):
    """Three targets expected and one particle of weight 1. Without arrivals the field's
    sum after a predict is the two targets no particle holds (its shape kept); with
    arrivals the field follows its own recursion ``u <- 1 - (1 - p u)(1 - b / n)``,
    floored at ``birth_floor``, and stays far below that."""
    model = _fixed_count_model(birth_rate=birth_rate)
    t = GaussianParticleFilter()
    t.reset(model, np.random.default_rng(0))
    m, P = _gaussian((6.0, 0.0, 6.0, 0.0), (0.3, 0.05, 0.3, 0.05))
    t.set_particles([1.0], m[None], P[None])
    t._u = CellField(model.grid.n_cells, 1e-4)
    t._u.set([0], [2e-4])
    t.predict()
    u = t._u.dense()
    if birth_rate == 0.0:
        assert np.isclose(u.sum(), 3.0 - float(t._w.sum()), rtol=1e-12)
        assert np.isclose(u[0] / u[1], 2.0, rtol=1e-9)
    else:
        p, b = 1.0 - DEFAULT_DEATH_FLOOR, birth_rate / model.grid.n_cells
        before = np.full(model.grid.n_cells, 1e-4)
        before[0] = 2e-4
        want = np.maximum(1.0 - (1.0 - p * before) * (1.0 - b), t.birth_floor)
        np.testing.assert_allclose(u, want, rtol=1e-12)
        assert u.sum() < 0.1


def test_default_predict_under_die_weights_by_the_mass_inside_and_truncates():
    """The GPF's predict under "die": each weight times the
    predicted Gaussian's mass inside (here with uncorrelated axes, the product of the
    marginal CDFs), and the Gaussian becomes its truncation to the workspace."""
    from scipy import stats

    model = TrackingModel(Grid(5, 4, 1.0), Dynamics(wna_intensity=2e-3),
                          BirthDeath(boundary="die"), RayleighGridSensor())
    t = EmptyPriorGPF(death_probability=0.0)
    t.reset(model, np.random.default_rng(0))
    m = np.array([[4.8, 0.5, 2.0, 0.1], [2.5, 0.05, 2.0, 0.0]])
    P = np.stack([np.diag([0.09, 0.01, 0.04, 0.01])] * 2)
    t.set_particles([0.9, 0.5], m, P)
    t.predict()
    w1, m1, P1 = t.particles
    F, Q = model.dynamics.F, model.dynamics.Q
    for i in range(2):
        mean, cov = F @ m[i], F @ P[i] @ F.T + Q
        fx = stats.norm(mean[0], np.sqrt(cov[0, 0]))
        fy = stats.norm(mean[2], np.sqrt(cov[2, 2]))
        inside = (fx.cdf(5.0) - fx.cdf(0.0)) * (fy.cdf(4.0) - fy.cdf(0.0))
        assert w1[i] == pytest.approx([0.9, 0.5][i] * inside, rel=1e-9)
        ref_mass, ref_m, ref_P = truncate_to_workspace(mean[None], cov[None], 5.0, 4.0)
        np.testing.assert_allclose(m1[i], ref_m[0], atol=1e-12)
        np.testing.assert_allclose(P1[i], ref_P[0], atol=1e-12)
    assert m1[0, 0] < F[0] @ m[0]  # the first one's mean pulled inside

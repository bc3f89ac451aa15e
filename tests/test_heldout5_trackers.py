"""Tracker rules checked against independent references: KF-NN's gated pairs on
elongated innovation covariances (the full K x D Mahalanobis table), jmpd-ap's default slot
count (the expected count's recursion iterated to its peak), and the GPF's prior rows on a
workspace that is not square (the uniform law's variance by a midpoint grid)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mttbench import scenarios
from mttbench.trackers.gpf import GaussianParticleFilter
from mttbench.trackers.jmpd.ap import JMPDAPTracker
from mttbench.trackers.kfnn import gated_pairs


@pytest.mark.parametrize("seed", range(3))
def test_gated_pairs_are_every_pair_inside_the_gate_of_an_elongated_covariance(seed):
    """Innovation covariances stretched 400 to 1 along random axes: the pairs found equal
    those of the full Mahalanobis table with ``d2 < gate``."""
    rng = np.random.default_rng(seed)
    K, D, gate = 6, 300, 9.21
    pred = rng.uniform(0.0, 20.0, (K, 2))
    z = rng.uniform(0.0, 20.0, (D, 2))
    S = np.empty((K, 2, 2))
    for k in range(K):
        a = rng.uniform(0.0, np.pi)
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        S[k] = R @ np.diag([4.0, 0.01]) @ R.T
    y = z[None, :, :] - pred[:, None, :]
    d2 = np.einsum("kdi,kij,kdj->kd", y, np.linalg.inv(S), y)
    want_r, want_c = np.nonzero(d2 < gate)
    rows, cols, got = gated_pairs(pred, S, z, gate)
    assert len(want_r) > K  # pairs along the long axes exist
    np.testing.assert_array_equal(rows, want_r)
    np.testing.assert_array_equal(cols, want_c)
    np.testing.assert_allclose(got, d2[want_r, want_c], rtol=1e-12)


def _expected_peak(n0: float, survival: float, birth: float, steps: int = 20_000) -> float:
    n, peak = n0, n0
    for _ in range(steps):
        n = survival * n + birth
        peak = max(peak, n)
    return peak


@pytest.mark.parametrize(("n0", "survival", "birth"), [
    (2.0, 0.9, 0.55),    # births dominate: the count rises towards 5.5
    (7.0, 0.9, 0.25),    # the initial count is the peak: it decays towards 2.5
    (3.0, 0.95, 0.1),
])
def test_jmpd_ap_default_slots_are_twice_the_expected_peak_count_plus_four(n0, survival, birth):
    """``t_max`` None: twice the peak of the expected count ``n_k`` (``n_0`` the initial
    count mean, ``n_{k+1} = p_s n_k + b``, iterated) rounded up, plus 4."""
    sc = scenarios.get("default")
    states = tuple((1.5 + i % 8, 0.0, 1.5 + i // 8, 0.0) for i in range(int(n0)))
    bd = dataclasses.replace(sc.model.birth_death, initial_states=states, n_random_initial=0,
                             survival_probability=survival, birth_rate=birth)
    model = dataclasses.replace(sc.model, birth_death=bd)
    t = JMPDAPTracker(n_particles=4)
    t.reset(model, np.random.default_rng(0))
    assert t.pos.shape[1] == 2 * math.ceil(_expected_peak(n0, survival, birth) - 1e-9) + 4


def test_the_gpf_prior_rows_spread_over_a_workspace_that_is_not_square():
    """Without a grid sensor the prior is broad Gaussians: position variance that of a
    uniform over the workspace's width and height (a midpoint grid of 10^5 points), velocity
    variance the square of the birth velocity sd."""
    sc = scenarios.get("superposition")
    grid = dataclasses.replace(sc.model.grid, nx=12, ny=5, cell_size=2.0)
    bd = dataclasses.replace(sc.model.birth_death, birth_velocity_std=0.3)
    model = dataclasses.replace(sc.model, grid=grid, birth_death=bd)
    t = GaussianParticleFilter()
    t.reset(model, np.random.default_rng(1))
    _, _, covs = t.particles
    assert len(covs) == 2

    def uniform_var(length: float) -> float:
        x = (np.arange(100_000) + 0.5) / 100_000 * length
        return float(np.mean((x - x.mean()) ** 2))

    want = np.diag([uniform_var(24.0), 0.3 * 0.3, uniform_var(10.0), 0.3 * 0.3])
    for cov in covs:
        np.testing.assert_allclose(cov, want, rtol=1e-6, atol=1e-12)

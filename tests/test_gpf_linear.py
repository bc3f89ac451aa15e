"""GPF on the superposition sensor and the combination enumeration, against exact references.

References: filterpy's KalmanFilter (one particle, w = 1); the exact posterior by brute
force (every existence pattern, the stacked joint Gaussian conditioned on z directly);
the paper's main-text per-particle form; brute-force listing of all joint choices.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from scipy.stats import multivariate_normal

from mttbench import scenarios
from mttbench.scenarios.model import Grid, Looks
from mttbench.trackers.gpf import EmptyPriorGPF
from mttbench.trackers.gpf.linear import enumerate_combinations, superposition_update

TOL = dict(rtol=1e-10, atol=1e-10)

H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
R = np.array([[0.25, 0.05], [0.05, 0.4]])


def _random_spd(rng: np.random.Generator, d: int = 4) -> np.ndarray:
    A = rng.normal(size=(d, d))
    return A @ A.T + 0.5 * np.eye(d)


def _random_particles(rng, n):
    w = rng.uniform(0.1, 0.9, n)
    m = rng.uniform(0.0, 12.0, (n, 4))
    P = np.stack([_random_spd(rng) for _ in range(n)])
    return w, m, P


# ------------------------------------------------------------ reduction to the KF
def test_one_certain_particle_equals_filterpy_kalman_filter():
    sc = scenarios.get("superposition")
    # a workspace large enough that the boundary rule (reflection) never acts
    model = dataclasses.replace(sc.model, grid=Grid(1000, 1000))
    rng = np.random.default_rng(7)
    gpf = EmptyPriorGPF()
    gpf.reset(model, np.random.default_rng(0))
    x0 = np.array([500.0, 0.1, 505.0, -0.05])
    P0 = np.diag([1.0, 0.1, 2.0, 0.05])
    gpf.set_particles([1.0], x0[None], P0[None])
    kf = KalmanFilter(dim_x=4, dim_z=2)
    kf.x, kf.P = x0.copy(), P0.copy()
    kf.F, kf.Q = model.dynamics.F, model.dynamics.Q
    kf.H, kf.R = model.sensor.H, model.sensor.R
    truth = x0.copy()
    for _ in range(200):
        truth = model.dynamics.F @ truth + rng.multivariate_normal(np.zeros(4), model.dynamics.Q)
        z = model.sensor.H @ truth + rng.multivariate_normal(np.zeros(2), model.sensor.R)
        gpf.predict()
        kf.predict()
        gpf.update(Looks(np.zeros(0, np.int64), np.zeros(0, bool), z))
        kf.update(z)
        w, m, P = gpf.particles
        assert w.shape == (1,) and w[0] == 1.0
        np.testing.assert_allclose(m[0], kf.x, **TOL)
        np.testing.assert_allclose(P[0], kf.P, **TOL)
        est = gpf.estimate()
        assert est.count == 1.0
        np.testing.assert_allclose(est.states[0], kf.x, **TOL)


# ------------------------------------------------------- brute-force exact posterior
def _exact_posterior(w, m, P, z):
    """Every existence pattern: prior, likelihood and the stacked joint Gaussian posterior."""
    n = len(w)
    out = []
    for pattern in itertools.product([0, 1], repeat=n):
        e = np.array(pattern, dtype=bool)
        prior = np.prod(np.where(e, w, 1.0 - w))
        idx = np.nonzero(e)[0]
        k = len(idx)
        if k == 0:
            out.append((e, np.log(prior) + multivariate_normal(np.zeros(2), R).logpdf(z), {}))
            continue
        mu = np.concatenate([m[i] for i in idx])
        Sig = np.zeros((4 * k, 4 * k))
        for a, i in enumerate(idx):
            Sig[4 * a:4 * a + 4, 4 * a:4 * a + 4] = P[i]
        A = np.hstack([H / k] * k)
        S = A @ Sig @ A.T + R
        # condition the joint Gaussian of (x_stacked, z) on z
        C = Sig @ A.T
        mu_post = mu + C @ np.linalg.solve(S, z - A @ mu)
        Sig_post = Sig - C @ np.linalg.solve(S, C.T)
        logw = np.log(prior) + multivariate_normal(A @ mu, S).logpdf(z)
        marg = {i: (mu_post[4 * a:4 * a + 4], Sig_post[4 * a:4 * a + 4, 4 * a:4 * a + 4])
                for a, i in enumerate(idx)}
        out.append((e, logw, marg))
    logs = np.array([o[1] for o in out])
    post = np.exp(logs - logs.max())
    post /= post.sum()
    return [(o[0], p, o[2]) for o, p in zip(out, post, strict=True)]


@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_superposition_update_equals_exact_posterior(n, seed):
    rng = np.random.default_rng(seed)
    w, m, P = _random_particles(rng, n)
    z = rng.uniform(2.0, 10.0, 2)
    res = superposition_update(w, m, P, z, H, R, epsilon=0.0)
    exact = _exact_posterior(w, m, P, z)
    assert res.present.shape == (2**n, n)
    assert res.dropped == pytest.approx(0.0, abs=1e-12)
    # combination weights and each present particle's moments, pattern by pattern
    for e, p, marg in exact:
        row = np.nonzero(np.all(res.present == e, axis=1))[0]
        assert len(row) == 1
        c = row[0]
        np.testing.assert_allclose(res.comb_weights[c], p, **TOL)
        for i, (mu_i, Sig_i) in marg.items():
            np.testing.assert_allclose(res.comb_means[c, i], mu_i, **TOL)
            np.testing.assert_allclose(res.comb_covs[c, i], Sig_i, **TOL)
    # folded particle set: existence marginal and moment match over patterns with e_i = 1
    for i in range(n):
        terms = [(p, marg[i]) for e, p, marg in exact if e[i]]
        wi = sum(p for p, _ in terms)
        mean = sum(p * mu for p, (mu, _) in terms) / wi
        cov = sum(p * (S + np.outer(mu - mean, mu - mean)) for p, (mu, S) in terms) / wi
        np.testing.assert_allclose(res.weights[i], wi, **TOL)
        np.testing.assert_allclose(res.means[i], mean, **TOL)
        np.testing.assert_allclose(res.covs[i], cov, **TOL)


def test_main_text_per_particle_form_gives_the_joint_marginal():
    """The paper's H = I/n, shifted z, R + others' covariances equals the joint marginal."""
    rng = np.random.default_rng(11)
    w, m, P = _random_particles(rng, 3)
    z = rng.uniform(2.0, 10.0, 2)
    res = superposition_update(w, m, P, z, H, R, epsilon=0.0)
    for c, e in enumerate(res.present):
        idx = np.nonzero(e)[0]
        n = len(idx)
        for j in idx:
            others = [i for i in idx if i != j]
            Hj = H / n
            zj = z - sum(H @ m[i] for i in others) / n
            Rj = R + sum(H @ P[i] @ H.T for i in others) / n**2
            S = Hj @ P[j] @ Hj.T + Rj
            K = P[j] @ Hj.T @ np.linalg.inv(S)
            np.testing.assert_allclose(res.comb_means[c, j], m[j] + K @ (zj - Hj @ m[j]), **TOL)
            np.testing.assert_allclose(res.comb_covs[c, j], (np.eye(4) - K @ Hj) @ P[j], **TOL)


def test_epsilon_cut_reports_dropped_mass_and_renormalises():
    rng = np.random.default_rng(5)
    w = np.array([0.95, 0.9, 0.05, 0.5])
    _, m, P = _random_particles(rng, 4)
    z = rng.uniform(2.0, 10.0, 2)
    eps = 0.02
    res = superposition_update(w, m, P, z, H, R, epsilon=eps)
    priors = {pat: np.prod(np.where(np.array(pat, bool), w, 1 - w))
              for pat in itertools.product([0, 1], repeat=4)}
    kept = {p for p, v in priors.items() if v > eps}
    assert {tuple(int(x) for x in row) for row in res.present} == kept
    assert res.dropped == pytest.approx(sum(v for p, v in priors.items() if p not in kept),
                                        abs=1e-12)
    assert res.comb_weights.sum() == pytest.approx(1.0, abs=1e-12)


# ------------------------------------------------------------------ enumeration
def _brute(option_probs):
    for combo in itertools.product(*[range(len(p)) for p in option_probs]):
        yield combo, float(np.prod([p[c] for p, c in zip(option_probs, combo, strict=True)]))


@pytest.mark.parametrize("seed", range(4))
def test_enumeration_complete_at_epsilon_zero(seed):
    rng = np.random.default_rng(seed)
    probs = [rng.dirichlet(np.ones(k)) for k in rng.integers(2, 5, size=5)]
    probs[1][0] = 0.0  # an impossible option is never listed
    probs[1] /= probs[1].sum()
    c = enumerate_combinations(probs, 0.0, 10**6)
    expected = {combo for combo, p in _brute(probs) if p > 0}
    got = [tuple(int(x) for x in row) for row in c.choice]
    assert len(got) == len(set(got)) and set(got) == expected
    assert np.exp(c.log_prior).sum() == pytest.approx(1.0, abs=1e-12)
    assert c.dropped == pytest.approx(0.0, abs=1e-12)
    assert np.all(np.diff(c.log_prior) <= 1e-12)  # best first


@pytest.mark.parametrize("eps", [1e-3, 1e-2, 0.05])
def test_enumeration_epsilon_and_cap_drop_exactly_what_was_cut(eps):
    rng = np.random.default_rng(42)
    probs = [rng.dirichlet(np.ones(k) * 0.5) for k in (2, 3, 4, 2, 3, 2)]
    allc = dict(_brute(probs))
    c = enumerate_combinations(probs, eps, 10**6)
    got = {tuple(int(x) for x in row) for row in c.choice}
    assert got == {k for k, p in allc.items() if p > eps}
    assert c.dropped == pytest.approx(sum(p for p, in_ in
                                          ((p, k in got) for k, p in allc.items()) if not in_),
                                      abs=1e-12)
    np.testing.assert_allclose(np.exp(c.log_prior),
                               [allc[tuple(int(x) for x in row)] for row in c.choice], rtol=1e-12)
    # a cap keeps the most probable ones
    cap = 7
    capped = enumerate_combinations(probs, 0.0, cap)
    top = sorted(allc.values(), reverse=True)[:cap]
    np.testing.assert_allclose(np.exp(capped.log_prior), top, rtol=1e-12)
    assert capped.dropped == pytest.approx(1.0 - sum(top), abs=1e-12)


def test_enumeration_keeps_the_most_probable_when_nothing_passes_epsilon():
    probs = [np.array([0.5, 0.5])] * 4 + [np.array([0.3, 0.3, 0.4])]  # best prior 0.025
    c = enumerate_combinations(probs, 0.1, 5)
    assert len(c.choice) == 5
    np.testing.assert_allclose(np.exp(c.log_prior), [0.025] * 5, rtol=1e-12)
    assert c.dropped == pytest.approx(1.0 - 5 * 0.025, abs=1e-12)

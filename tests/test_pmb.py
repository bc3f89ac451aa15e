"""The PMB filter (trackers/pmb): its update against brute-force enumeration of the
association hypotheses, its reductions, the PPP, recycling and the conformance kit.

References are independent of the code under test: the cell masses and moments come from
a tensor Gauss-Legendre rule on each cell (:func:`cell_moments`, 32 x 32 nodes, exact to
about 1e-13 for the Gaussians used here) rather than the shared ``rect_state_moments``;
the ratios from the sensor's ``p_d`` and ``p_f`` in closed form; the hypotheses written
out one by one (:func:`enumerate_update`).
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.trackers import make
from mttbench.trackers.gpf import collapse
from mttbench.trackers.gpf.grid import known_existence_update
from mttbench.trackers.pmb import PMBTracker, cell_ratios, pmb_update
from mttbench.trackers.pmb.tracker import COMPONENT_FLOOR, reduce_rows

#: the update on a tree-structured world equals the enumeration (quadrature-limited)
EXACT_TOL = 1e-9
#: moments (means, covariances) against the quadrature reference
MOMENT_TOL = 1e-8
#: a loopy world (two tracks, two shared detected cells): LBP's existence and new-target
#: probabilities against the enumeration; measured on the world below: existence 0.013,
#: new Bernoullis 0.026, means 0.055 cell (the Bethe approximation's error, as in
#: tests/test_pmb_lbp.py)
LOOPY_TOL = 0.05

GRID = Grid(8, 8)
SENSOR = RayleighGridSensor(p_d=0.5, snr=10.0, looks_per_step=64)


def _cov(sp, sv, rho_xy=0.2, rho_pv=0.5):
    """A full state covariance: positions sd ``sp`` (correlated), velocities ``sv``
    correlated with their position."""
    sd = np.array([sp, sv, sp * 1.2, sv])
    C = np.eye(4)
    C[0, 2] = C[2, 0] = rho_xy
    C[0, 1] = C[1, 0] = C[2, 3] = C[3, 2] = rho_pv
    C[1, 3] = C[3, 1] = rho_xy * rho_pv ** 2
    return C * sd[:, None] * sd[None, :]


def cell_moments(m, P, cell, n=32):
    """Mass, ``int (x - m) N`` and ``int (x - m)(x - m)^T N`` of ``N(m, P)`` over a grid
    cell (positions by a tensor Gauss-Legendre rule on the cell, velocities by their
    Gaussian conditional on position)."""
    x0, x1, y0, y1 = (float(v) for v in GRID.cell_bounds(np.int64(cell)))
    t, wt = np.polynomial.legendre.leggauss(n)
    xs = 0.5 * (x1 - x0) * t + 0.5 * (x1 + x0)
    ys = 0.5 * (y1 - y0) * t + 0.5 * (y1 + y0)
    W = np.outer(wt, wt) * 0.25 * (x1 - x0) * (y1 - y0)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    pos = [0, 2]
    vel = [1, 3]
    Spp = P[np.ix_(pos, pos)]
    U = np.stack([X - m[0], Y - m[2]], axis=-1)  # (n, n, 2)
    q = np.einsum("abi,ij,abj->ab", U, np.linalg.inv(Spp), U)
    dens = np.exp(-0.5 * q) / (2 * np.pi * np.sqrt(np.linalg.det(Spp)))
    w = W * dens
    mass = w.sum()
    Eu = np.einsum("ab,abi->i", w, U)
    Euu = np.einsum("ab,abi,abj->ij", w, U, U)
    B = P[np.ix_(vel, pos)] @ np.linalg.inv(Spp)
    R = P[np.ix_(vel, vel)] - B @ P[np.ix_(pos, vel)]
    M1 = np.zeros(4)
    M1[pos], M1[vel] = Eu, B @ Eu
    M2 = np.zeros((4, 4))
    M2[np.ix_(pos, pos)] = Euu
    M2[np.ix_(pos, vel)] = Euu @ B.T
    M2[np.ix_(vel, pos)] = B @ Euu
    M2[np.ix_(vel, vel)] = B @ Euu @ B.T + mass * R
    return mass, M1, M2


def enumerate_update(r, m, P, looks, lam, sensor=SENSOR):
    """The PMB update by writing out every association hypothesis.

    Per looked cell ``c``: ``L_c = prod l(z)``, ``M_c = l(0)^n_c``, ``S_c = L_c - M_c``
    at a detected cell (trackers/pmb/update.py's model); track ``i`` is absent
    (``1 - r_i``), present and the source of nothing (``r_i Q_i``, ``Q_i = 1 - sum_c
    m_ic + sum_c m_ic M_c``) or the source of detected cell ``j`` (``r_i m_ij S_j``);
    an unclaimed detected cell weighs ``1 + lambda_j S_j``. Returns ``r' (T,)``,
    ``means (T, 4)``, ``covs (T, 4, 4)`` (each track's mixture over the hypotheses,
    moment matched) and ``r_new (J,)``."""
    lp = sensor.p_d / sensor.p_f
    lm = (1 - sensor.p_d) / (1 - sensor.p_f)
    cells = np.unique(looks.cells)
    n = np.array([np.sum(looks.cells == c) for c in cells])
    k = np.array([np.sum(looks.returns[looks.cells == c]) for c in cells])
    L = lp ** k * lm ** (n - k)
    M = lm ** n
    det = np.nonzero(k > 0)[0]
    S = L - M
    T = len(r)
    mom = [[cell_moments(m[i], P[i], c) for c in cells] for i in range(T)]
    mass = np.array([[mom[i][u][0] for u in range(len(cells))] for i in range(T)])
    Q = 1 - mass.sum(1) + mass @ M
    options = [["absent", "missed"] + list(det) for _ in range(T)]
    hyps, weights = [], []
    for choice in itertools.product(*options):
        taken = [c for c in choice if not isinstance(c, str)]
        if len(taken) != len(set(taken)):
            continue
        wgt = 1.0
        for i, c in enumerate(choice):
            wgt *= (1 - r[i]) if c == "absent" else r[i] * Q[i] if c == "missed" else (
                r[i] * mass[i, c] * S[c])
        for j in det:
            if j not in taken:
                wgt *= 1 + lam[list(det).index(j)] * S[j]
        hyps.append(choice)
        weights.append(wgt)
    p = np.array(weights) / np.sum(weights)
    r_post, means, covs = np.zeros(T), np.zeros((T, 4)), np.zeros((T, 4, 4))
    parts = [{} for _ in range(T)]  # per track: hypothesis -> [weight, mean, cov]
    for i in range(T):
        Z, S1, S2 = 0.0, np.zeros(4), np.zeros((4, 4))
        for h, ph in zip(hyps, p, strict=True):
            c = h[i]
            if c == "absent":
                continue
            if c == "missed":  # N g0 / Q: g0 = M_c in looked cells, 1 elsewhere
                z = 1.0 + sum((M[u] - 1) * mom[i][u][0] for u in range(len(cells)))
                s1 = sum((M[u] - 1) * mom[i][u][1] for u in range(len(cells)))
                s2 = P[i] + sum((M[u] - 1) * mom[i][u][2] for u in range(len(cells)))
            else:  # truncated to cell c
                z, s1, s2 = mom[i][c]
            Z += ph
            S1 += ph * s1 / z
            S2 += ph * s2 / z
            key = -1 if c == "missed" else list(det).index(c)
            dd = s1 / z
            if key not in parts[i]:
                parts[i][key] = [0.0, m[i] + dd, s2 / z - np.outer(dd, dd)]
            parts[i][key][0] += ph
        d = S1 / Z
        r_post[i], means[i], covs[i] = Z, m[i] + d, S2 / Z - np.outer(d, d)
    r_new = np.zeros(len(det))
    for jj, j in enumerate(det):
        unused = sum(ph for h, ph in zip(hyps, p, strict=True) if j not in h)
        nu = lam[jj] * S[j]
        r_new[jj] = unused * nu / (1 + nu)
    return r_post, means, covs, r_new, parts


def _cell(ix, iy):
    return iy * GRID.nx + ix


def _run_update(r, m, P, looks, lam):
    ratios = cell_ratios(SENSOR, looks.cells, looks.returns)
    return pmb_update(np.array(r, float), m, P, ratios, np.asarray(lam, float), GRID)


def _collapsed(res):
    """Each track's posterior rows moment matched: ``means (T, 4)``, ``covs (T, 4, 4)``."""
    return collapse(res.alpha, res.means, res.covs, res.own, len(res.r))


# ------------------------------------------------------------------ tree world
def _tree_world():
    """Track A broad at (3.5, 4.5), track B narrow at (5.3, 4.6); detected cells (4, 4)
    (both reach it) and (1, 4) (only A); a cell without detection (3, 4), and cell (4, 4)
    looked twice (one detection, one miss). The graph A-(1,4), A-(4,4), B-(4,4) is a
    tree."""
    m = np.array([[3.5, 0.1, 4.5, -0.05], [5.3, -0.1, 4.6, 0.02]])
    P = np.stack([_cov(0.6, 0.1), _cov(0.25, 0.08)])
    cells = np.array([_cell(4, 4), _cell(1, 4), _cell(3, 4), _cell(4, 4)])
    returns = np.array([True, True, False, False])
    return np.array([0.7, 0.9]), m, P, Looks(cells, returns)


def test_update_equals_enumeration_on_a_tree_world():
    r, m, P, looks = _tree_world()
    lam = np.array([0.02, 0.05])  # PPP at the detected cells (1, 4) and (4, 4), sorted
    got = _run_update(r, m, P, looks, lam)
    want = enumerate_update(r, m, P, looks, lam)
    assert got.marginals.converged
    assert list(got.meas_cells) == [_cell(1, 4), _cell(4, 4)]
    np.testing.assert_allclose(got.r, want[0], rtol=0, atol=EXACT_TOL)
    np.testing.assert_allclose(got.r_new, want[3], rtol=0, atol=EXACT_TOL)
    means, covs = _collapsed(got)
    np.testing.assert_allclose(means, want[1], rtol=0, atol=MOMENT_TOL)
    np.testing.assert_allclose(covs, want[2], rtol=0, atol=MOMENT_TOL)
    # and hypothesis by hypothesis: each posterior row is one (track, hypothesis) of the
    # enumeration, its weight P(hypothesis) / r', its moments that hypothesis' posterior
    for row in range(len(got.own)):
        i, h = got.own[row], got.hyp[row]
        weight, mean, cov = want[4][i][h]
        assert got.alpha[row] * got.r[i] == pytest.approx(weight, abs=EXACT_TOL)
        np.testing.assert_allclose(got.means[row], mean, rtol=0, atol=MOMENT_TOL)
        np.testing.assert_allclose(got.covs[row], cov, rtol=0, atol=MOMENT_TOL)
    # every hypothesis of weight above EXACT_TOL is a row (B cannot have made (1, 4))
    heavy = {(i, h) for i in range(2) for h, part in want[4][i].items() if part[0] > EXACT_TOL}
    assert heavy <= set(zip(got.own.tolist(), got.hyp.tolist(), strict=True))
    # the world is not trivial: both tracks compete for (4, 4), and A may have made (1, 4)
    assert 0.05 < got.r_new[1] < 0.95 or 0.05 < got.r[0] < 0.95


def test_update_close_to_enumeration_on_a_loopy_world():
    """Both tracks broad, both reach both detected cells (a cycle): LBP's marginals are
    approximate; existence within LOOPY_TOL."""
    m = np.array([[3.6, 0.1, 4.4, -0.05], [4.4, -0.1, 4.6, 0.02]])
    P = np.stack([_cov(0.7, 0.1), _cov(0.6, 0.08, rho_xy=-0.3)])
    looks = Looks(np.array([_cell(3, 4), _cell(4, 4), _cell(4, 5)]),
                  np.array([True, True, False]))
    r, lam = np.array([0.8, 0.6]), np.array([0.03, 0.03])
    got = _run_update(r, m, P, looks, lam)
    want = enumerate_update(r, m, P, looks, lam)
    assert got.marginals.converged and got.marginals.iterations > 2
    assert np.max(np.abs(got.r - want[0])) < LOOPY_TOL
    assert np.max(np.abs(got.r_new - want[3])) < LOOPY_TOL
    assert np.max(np.abs(_collapsed(got)[0] - want[1])[:, [0, 2]]) < 0.1  # cell units


def test_single_bernoulli_existence_is_the_exact_bernoulli_update():
    """One track, no PPP: ``r' = r L / (r L + 1 - r)``, ``L = m_out + sum_c m_c L_c`` (the
    exact Bernoulli update of the GPF docstring), here with three detected cells."""
    m = np.array([[3.5, 0.1, 4.5, -0.05]])
    P = _cov(0.8, 0.1)[None]
    cells = np.array([_cell(3, 4), _cell(4, 4), _cell(2, 5), _cell(3, 5)])
    looks = Looks(cells, np.array([True, False, True, True]))
    got = _run_update([0.4], m, P, looks, np.zeros(3))
    lp = SENSOR.p_d / SENSOR.p_f
    lm = (1 - SENSOR.p_d) / (1 - SENSOR.p_f)
    mass = np.array([cell_moments(m[0], P[0], c)[0] for c in cells])
    Lam = np.where(looks.returns, lp, lm)
    Ltot = 1 - mass.sum() + mass @ Lam
    want = 0.4 * Ltot / (0.4 * Ltot + 0.6)
    assert got.r[0] == pytest.approx(want, abs=EXACT_TOL)


# ------------------------------------------------------------------ reduction
def test_reduction_to_known_existence_update():
    """One Bernoulli, existence 1, every cell looked at, no PPP, p_f tiny (snr 30): the
    PMB update is the Gaussian-on-cells update that the GPF and truth-aided share."""
    sensor = RayleighGridSensor(p_d=0.6, snr=30.0, looks_per_step=64)
    m = np.array([[3.7, 0.1, 4.2, -0.05]])
    P = _cov(0.7, 0.1)[None]
    cells = np.arange(GRID.n_cells)
    returns = cells == _cell(4, 4)
    ratios = cell_ratios(sensor, cells, returns)
    got = pmb_update(np.ones(1), m, P, ratios, np.zeros(1), GRID)
    want_m, want_P = known_existence_update(m, P, cells, returns, GRID, sensor,
                                            workspace="none")
    assert got.r[0] == pytest.approx(1.0, abs=1e-12)
    means, covs = _collapsed(got)  # the one-Gaussian TOMB: the mixture moment matched
    np.testing.assert_allclose(means, want_m, rtol=0, atol=1e-9)
    np.testing.assert_allclose(covs, want_P, rtol=0, atol=1e-9)
    # and it moved: the detection pulled the mean towards cell (4, 4)
    assert means[0, 0] > m[0, 0] + 0.2


# ------------------------------------------------------------------ tracker level
def _model(birth_rate=0.0, n0=2.0, p_s=1.0):
    bd = BirthDeath(initial_states=((3.5, 0.0, 3.5, 0.0),) * int(n0), survival_probability=p_s,
                    birth_rate=birth_rate, boundary="reflect")
    return TrackingModel(GRID, Dynamics(wna_intensity=5e-4), bd, SENSOR)


def test_ppp_predict_and_update_follow_their_formulas():
    model = _model(birth_rate=0.3, n0=2.0, p_s=0.9)
    tr = PMBTracker()
    tr.reset(model, np.random.default_rng(0))
    tr.predict()
    lam = 0.9 * 2.0 / 64 + 0.3 / 64
    np.testing.assert_allclose(tr.intensity.dense(), lam, rtol=1e-15)
    cells = np.array([_cell(1, 1), _cell(2, 1), _cell(2, 1)])
    tr.update(Looks(cells, np.array([False, False, False])))
    lm = (1 - SENSOR.p_d) / (1 - SENSOR.p_f)
    want = np.full(64, lam)
    want[_cell(1, 1)] *= lm
    want[_cell(2, 1)] *= lm ** 2
    np.testing.assert_allclose(tr.intensity.dense(), want, rtol=1e-12)
    assert len(tr.tracks[0]) == 0  # no detection, no track


def test_detection_starts_a_track_weighed_against_the_ppp():
    """A detection where the PPP holds ``lambda``: one new Bernoulli with
    ``r = lambda S / (1 + lambda S)`` at the cell centre, its velocity the model's."""
    model = _model(n0=1.0)
    tr = PMBTracker()
    tr.reset(model, np.random.default_rng(0))
    tr.predict()
    lam = 1.0 / 64
    tr.update(Looks(np.array([_cell(5, 2)]), np.array([True])))
    r, m, P, labels = tr.tracks
    S = SENSOR.p_d / SENSOR.p_f - (1 - SENSOR.p_d) / (1 - SENSOR.p_f)
    assert r == pytest.approx([lam * S / (1 + lam * S)], rel=1e-12)
    np.testing.assert_allclose(m[0], [5.5, 0.0, 2.5, 0.0])
    assert P[0, 0, 0] == pytest.approx(1 / 12) and P[0, 1, 1] == pytest.approx(0.01)


def test_recycling_moves_existence_into_the_ppp():
    model = _model(n0=2.0)  # two tracks within the count bound
    tr = PMBTracker(recycle_threshold=0.05)
    tr.reset(model, np.random.default_rng(0))
    m = np.array([[4.5, 0.0, 4.5, 0.0], [2.0, 0.0, 6.0, 0.0]])
    P = np.stack([_cov(0.5, 0.1), _cov(0.5, 0.1)])
    tr.set_tracks([0.03, 0.9], m, P)
    before = tr.intensity.total() + tr.tracks[0].sum()
    tr.update(Looks(np.array([_cell(0, 0)]), np.array([False])))  # far from both
    r, _, _, labels = tr.tracks
    assert len(r) == 1 and r[0] == pytest.approx(0.9)
    assert labels[0] == 1  # the survivor keeps its label
    lam0 = 2.0 / 64  # the prior intensity; the look at (0, 0) leaves lam0 M there
    missed = lam0 * (1 - (1 - SENSOR.p_d) / (1 - SENSOR.p_f))
    assert tr.intensity.total() + r.sum() == pytest.approx(before - missed, abs=1e-8)
    assert tr.intensity.at(np.array([_cell(4, 4)]))[0] > lam0 + 0.005  # where it was


@pytest.mark.parametrize("max_components", [1, 2, 4])
def test_reduce_rows_keeps_each_tracks_moments(max_components):
    """Merging and capping a track's rows moment-matches them: each track's mixture mean
    and covariance are kept (to round-off) once the floor's rows are taken out, at most
    ``max_components`` rows stay, and the weights sum to 1 per track."""
    rng = np.random.default_rng(5)
    own = np.array([0, 0, 0, 0, 0, 1, 1, 2])
    a = np.array([0.3, 0.25, 0.2, 0.24, 0.01, 0.5, 0.5, 1.0])
    hyp = np.array([-1, 3, 3, 5, -1, -1, 2, -1])  # rows 1, 2: same cell of track 0
    m = rng.normal(size=(8, 4))
    P = np.stack([_cov(0.3 + 0.1 * i, 0.05) for i in range(8)])
    o2, a2, m2, P2 = reduce_rows(own, a, m, P, hyp, 3, max_components)
    assert np.all(np.bincount(o2, minlength=3) <= max_components)
    np.testing.assert_allclose(np.bincount(o2, weights=a2), 1.0, rtol=1e-12)
    kept = a >= COMPONENT_FLOOR
    want_m, want_P = collapse(a[kept], m[kept], P[kept], own[kept], 3)
    got_m, got_P = collapse(a2, m2, P2, o2, 3)
    np.testing.assert_allclose(got_m, want_m, atol=1e-12)
    np.testing.assert_allclose(got_P, want_P, atol=1e-12)
    if max_components == 4:  # the two rows of cell 3 merged, the floor's row dropped
        assert np.sum(o2 == 0) == 3


def test_extraction_rules():
    tr = PMBTracker()  # round_sum: the round(sum r) most likely tracks
    tr.reset(_model(n0=2.0), np.random.default_rng(0))
    m = np.array([[1.5, 0, 1.5, 0], [4.5, 0, 4.5, 0], [6.5, 0, 1.5, 0]])
    P = np.repeat(np.diag([0.04, 0.01, 0.04, 0.01])[None], 3, axis=0)
    tr.set_tracks([0.45, 0.8, 0.3], m, P)
    est = tr.estimate()
    assert est.count == pytest.approx(1.55)
    np.testing.assert_array_equal(est.states, m[[0, 1]])
    tr2 = PMBTracker(extraction="threshold", extraction_threshold=0.5)
    tr2.reset(_model(n0=2.0), np.random.default_rng(0))
    tr2.set_tracks([0.45, 0.8, 0.3], m, P)
    np.testing.assert_array_equal(tr2.estimate().states, m[[1]])
    assert list(tr2.estimate().labels) == [1]


def test_merge_capped_sum():
    """With ``merge_threshold``, two tracks on the same spot become one Bernoulli of
    existence ``min(1, r1 + r2)`` with the label of the more likely; a far one stays."""
    tr = PMBTracker(merge_threshold=4.0)
    tr.reset(_model(n0=2.0), np.random.default_rng(0))
    m = np.array([[4.5, 0, 4.5, 0], [4.6, 0, 4.4, 0], [1.5, 0, 6.5, 0]])
    P = np.repeat(np.diag([0.25, 0.01, 0.25, 0.01])[None], 3, axis=0)
    tr.set_tracks([0.4, 0.5, 0.9], m, P)
    tr.update(Looks(np.array([_cell(7, 0)]), np.array([False])))  # far from all three
    r, mm, _, labels = tr.tracks
    assert sorted(r.round(12)) == [0.9, 0.9]
    assert sorted(labels.tolist()) == [1, 2]
    joined = np.argmin(np.abs(mm[:, 0] - 4.55))
    assert mm[joined, 0] == pytest.approx((0.4 * 4.5 + 0.5 * 4.6) / 0.9)


def test_labels_persist_on_a_held_target():
    """One target, every cell looked at: after the first detections one label is reported
    at (nearly) every step."""
    from mttbench import scenarios
    from mttbench.benchmarks.engine.loop import play
    from mttbench.benchmarks.engine.policies import AllCells

    sc = scenarios.get("default")
    bd = dataclasses.replace(sc.model.birth_death, initial_states=((5.5, 0.05, 6.5, -0.03),))
    sc = dataclasses.replace(sc, name="pmb-labels", n_steps=40,
                             model=dataclasses.replace(sc.model, birth_death=bd))
    labels = [tuple(rec.estimate.labels) for rec in play(sc, PMBTracker(), 0,
                                                         policy=AllCells())][10:]
    ones = [lab for lab in labels if len(lab) == 1]
    assert len(ones) >= 25
    assert len({lab[0] for lab in ones}) == 1


def test_registered_and_conformant(kit):
    assert isinstance(make("pmb"), PMBTracker)
    assert kit.check_tracker(PMBTracker) == {}  # check_tracker, once per session


def test_superposition_sensor_is_refused_with_a_reason():
    from mttbench.scenarios.model import SuperpositionSensor

    model = dataclasses.replace(_model(), sensor=SuperpositionSensor())
    assert "cell" in PMBTracker().unsupported_reason(model)


def test_recycling_a_mixture_track_returns_r_times_each_components_weight():
    """A track whose density is a two-Gaussian mixture (weights 0.3 and 0.7, far apart) is
    recycled: each component's cells gain ``r a_k`` (its 6-sd box holds all but ~1e-9 of
    its mass), not ``r`` each nor ``a_k``; the track is gone and the mass is conserved."""
    model = _model(n0=1.0)
    tr = PMBTracker(recycle_threshold=0.05)
    tr.reset(model, np.random.default_rng(0))
    tr.set_intensity(0.0)
    r, a = 0.04, np.array([0.3, 0.7])
    tr.set_tracks([r], np.array([[1.5, 0.0, 1.5, 0.0]]), _cov(0.1, 0.1, 0.0, 0.0)[None])
    tr._own, tr._a = np.array([0, 0]), a.copy()
    tr._m = np.array([[1.5, 0.0, 1.5, 0.0], [6.5, 0.0, 6.5, 0.0]])
    tr._P = np.stack([_cov(0.1, 0.1, 0.0, 0.0)] * 2)
    tr._recycle()
    assert len(tr.tracks[0]) == 0
    for (cx, cy), weight in zip([(1, 1), (6, 6)], a, strict=True):
        block = np.array([_cell(ix, iy) for ix in range(cx - 1, cx + 2)
                          for iy in range(cy - 1, cy + 2)])
        assert tr.intensity.at(block).sum() == pytest.approx(r * weight, rel=1e-8)
    assert tr.intensity.total() == pytest.approx(r, rel=1e-8)


def test_a_mixture_track_is_reported_by_its_heaviest_component():
    """Two tracks, each a two-Gaussian mixture (rows not in weight order): the estimate
    gives each track the mean and covariance of its heaviest row (argmax per track)."""
    tr = PMBTracker()
    tr.reset(_model(n0=2.0), np.random.default_rng(0))
    m0 = np.array([[1.5, 0.0, 1.5, 0.0], [6.5, 0.0, 1.5, 0.0]])
    tr.set_tracks([0.9, 0.8], m0, np.stack([_cov(0.1, 0.1)] * 2))
    own = np.array([0, 0, 1, 1])
    a = np.array([0.3, 0.7, 0.6, 0.4])
    m = np.array([[1.5, 0, 1.5, 0], [2.5, 0, 5.5, 0], [6.5, 0, 1.5, 0], [6.5, 0, 6.5, 0]], float)
    P = np.stack([_cov(0.1 * (i + 1), 0.1) for i in range(4)])
    tr._own, tr._a, tr._m, tr._P = own, a, m, P
    heaviest = [int(np.flatnonzero(own == t)[np.argmax(a[own == t])]) for t in (0, 1)]
    assert heaviest == [1, 2]
    est = tr.estimate()
    np.testing.assert_array_equal(est.states, m[heaviest])
    np.testing.assert_array_equal(est.covariances, P[heaviest])

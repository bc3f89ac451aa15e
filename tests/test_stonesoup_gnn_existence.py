"""``ss-gnn``'s association and track management by existence (trackers/stonesoup/
gnn_existence.py, ``association="existence"``).

* Each factor of a hypothesis' weight is the exact likelihood ratio of its Bernoulli, by
  enumeration over the target's cell on a small grid (independent of the cell-evidence code).
* The existence update is Bayes' rule for the track's Bernoulli, by the same enumeration.
* A new track's existence is the closed form ``u q1 / (u q1 + (1 - u) q0)``.
* The association is the assignment of largest product of weights, against a brute-force
  enumeration of every assignment (and not the largest sum, on a hand-computed case).
* The tracker passes the kit's tracking checks with every cell looked at.
"""

from __future__ import annotations

import datetime
import itertools
import math

import numpy as np
import pytest
from scipy.stats import norm

from mttbench import testing
from mttbench.scenarios.model import Grid
from mttbench.trackers.cell_evidence import cell_evidence, looked_log_ratios
from mttbench.trackers.stonesoup import gnn_existence as ge
from mttbench.trackers.stonesoup import peers as sp

P_D, P_F = 0.7, 0.1
GRID = Grid(nx=7, ny=6, cell_size=1.0)


@pytest.fixture
def stonesoup_installed():
    pytest.importorskip("stonesoup", minversion="1.9",
                        reason="needs the stonesoup extra: pip install 'mttbench[stonesoup]'")


def _masses(mean_xy, sd):
    """Mass of N(mean, sd^2 I) per cell, ``(ny nx,)``, from scipy's normal cdf."""
    mx = np.diff(norm.cdf(np.arange(GRID.nx + 1), mean_xy[0], sd))
    my = np.diff(norm.cdf(np.arange(GRID.ny + 1), mean_xy[1], sd))
    return np.outer(my, mx).ravel()


def _present(m, cells, returns):
    """P(looks | one target in the Gaussian of cell masses ``m``): its mass off the grid
    is in no looked cell."""
    return (sum(m[j] * _look_prob(cells, returns, (j,)) for j in range(GRID.n_cells))
            + (1.0 - m.sum()) * _look_prob(cells, returns, ()))


def _look_prob(cells, returns, target_cells):
    """P(looks | targets in ``target_cells``): each look positive with p_d at a target's
    cell, p_f elsewhere, independently."""
    p = 1.0
    for c, y in zip(cells, returns, strict=True):
        q = P_D if c in target_cells else P_F
        p *= q if y else 1.0 - q
    return p


def _world():
    """Looks over a small grid: negative cells around a track at (2.7, 2.4) (sd 0.6 cells),
    some looked twice, and one positive cell (3, 2) looked twice, once positive."""
    cells = np.array([8, 9, 10, 15, 16, 16, 22, 23, 24, 24, 30, 2])
    returns = np.zeros(len(cells), bool)
    z = 2 * GRID.nx + 3  # the detection's cell
    cells = np.concatenate([cells, [z, z]])
    returns = np.concatenate([returns, [True, False]])
    return cells, returns, z, np.array([2.7, 2.4]), 0.6


def _adapter_terms(cells, returns, mean_xy, sd, z):
    """``L_k0`` (cell_evidence) and ``L_kz`` (+ ge.cell_mass), the adapter's way."""
    looked, _, det, log_r = looked_log_ratios(cells, returns, math.log(P_D / P_F),
                                              math.log((1 - P_D) / (1 - P_F)))
    cov = np.diag([sd * sd, sd * sd])
    lik0 = math.exp(cell_evidence(GRID, mean_xy[None], cov[None], looked, log_r, det,
                                  np.zeros(0, np.int64), np.zeros(0, np.int64))[0][0])
    ratio = math.exp(log_r[np.searchsorted(looked, z)])
    return lik0, lik0 + ge.cell_mass(GRID, mean_xy, cov, z) * (ratio - 1.0), ratio


def test_weights_are_the_bernoullis_exact_likelihood_ratios():
    """``1 - r + r L_k0`` is P(looks | the track's Bernoulli) / P(looks | no target) with
    the detection's cell left out (another explains it); ``1 - r + r L_kz`` the same with
    it; ``1 + u (r_z - 1)`` that of an untracked Bernoulli ``u`` in cell ``z``; the weights
    are their quotients."""
    cells, returns, z, mean_xy, sd = _world()
    lik0, likz, ratio = _adapter_terms(cells, returns, mean_xy, sd, z)
    m = _masses(mean_xy, sd)
    r, u = 0.63, 0.08
    off_z = cells != z
    for keep, lik in ((off_z, lik0), (np.ones(len(cells), bool), likz)):
        c, y = cells[keep], returns[keep]
        none = _look_prob(c, y, ())
        present = _present(m, c, y)
        exact = ((1 - r) * none + r * present) / none
        assert 1 - r + r * lik == pytest.approx(exact, rel=1e-9)
    at_z = cells == z
    exact_u = ((1 - u) * _look_prob(cells[at_z], returns[at_z], ())
               + u * _look_prob(cells[at_z], returns[at_z], (z,))) / _look_prob(
        cells[at_z], returns[at_z], ())
    assert 1 + u * (ratio - 1) == pytest.approx(exact_u, rel=1e-12)
    cov = np.diag([sd * sd, sd * sd])
    assert ge.miss_weight(r, lik0) == pytest.approx(1 - r + r * lik0, rel=1e-15)
    assert ge.detection_weight(r, lik0, ge.cell_mass(GRID, mean_xy, cov, z), ratio, u) == \
        pytest.approx((1 - r + r * likz) / exact_u, rel=1e-9)


def test_existence_update_is_bayes_rule_by_enumeration():
    """``r L / (1 - r + r L)`` equals P(present | looks) enumerated over the target's cell,
    for the miss (``L_k0``) and for taking the detection (``L_kz``), at several priors."""
    cells, returns, z, mean_xy, sd = _world()
    lik0, likz, _ = _adapter_terms(cells, returns, mean_xy, sd, z)
    m = _masses(mean_xy, sd)
    for r in (0.02, 0.4, 0.97):
        for keep, lik in ((cells != z, lik0), (np.ones(len(cells), bool), likz)):
            c, y = cells[keep], returns[keep]
            present = r * _present(m, c, y)
            absent = (1 - r) * _look_prob(c, y, ())
            assert float(ge.existence_update(r, lik)) == pytest.approx(
                present / (present + absent), rel=1e-9)


def test_birth_existence_is_the_closed_form():
    """One positive look: ``u p_d / (u p_d + (1 - u) p_f)``, ``u = 1 - exp(-lambda)``; no
    untracked intensity: 0."""
    for lam in (1e-4, 0.05, 0.7, 3.0):
        u = 1 - math.exp(-lam)
        want = u * P_D / (u * P_D + (1 - u) * P_F)
        assert float(ge.birth_existence(lam, math.log(P_D / P_F))) == pytest.approx(want,
                                                                                   rel=1e-12)
    assert float(ge.birth_existence(0.0, math.log(P_D / P_F))) == 0.0


def test_cell_mass_is_the_product_of_normal_cdfs():
    mean_xy, sd = np.array([2.3, 4.9]), 0.45
    want = _masses(mean_xy, sd)
    got = [ge.cell_mass(GRID, mean_xy, np.diag([sd * sd, sd * sd]), c)
           for c in range(GRID.n_cells)]
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-300)


# ------------------------------------------------------------------ the association
def _tracks_and_detections(ss, n_tracks, n_dets):
    """Stone Soup tracks started at cells 0.. and detections at cells 20.. of GRID."""
    meas = ss.LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=np.eye(2) / 12)
    t0, t1 = sp.EPOCH, sp.EPOCH + datetime.timedelta(seconds=1)

    def det(cell, t):
        x, y = GRID.cell_centers(np.array([cell]))[0]
        return ss.Detection(np.array([[x], [y]]), timestamp=t, measurement_model=meas,
                            metadata={"cell": int(cell)})

    starter = ss.SimpleMeasurementInitiator(
        ss.GaussianState(np.zeros((4, 1)), np.diag([0.0, 0.01, 0.0, 0.01])), meas)
    tracks = [next(iter(starter.initiate([det(c, t0)], t0))) for c in range(n_tracks)]
    dets = [det(20 + j, t1) for j in range(n_dets)]
    predictor = ss.KalmanPredictor(ss.LinearGaussianTimeInvariantTransitionModel(
        transition_matrix=np.eye(4), covariance_matrix=np.eye(4) * 1e-3))
    return tracks, dets, predictor, ss.KalmanUpdater(meas), t1


def _gnn(ss, weights, n_tracks, n_dets):
    """``OrderedGNN`` over the existence hypothesiser (no gate) with the weights ``(n_tracks,
    n_dets + 1)`` (column 0 the miss); returns the chosen detection index per track (-1:
    miss)."""
    tracks, dets, predictor, updater, t = _tracks_and_detections(ss, n_tracks, n_dets)
    index = {tr.id: i for i, tr in enumerate(tracks)}
    hyp = ss.ExistenceHypothesiser(predictor, updater, measure=ss.Mahalanobis(),
                                   gate=math.inf)
    hyp.weigh = lambda tr, d: weights[index[tr.id],
                                      0 if d is None else d.metadata["cell"] - 19]
    assoc = ss.OrderedGNN(hyp).associate(tracks, dets, t)
    return [assoc[tr].measurement.metadata["cell"] - 20 if assoc[tr] else -1
            for tr in tracks]


def _brute_force(weights):
    """The assignment (detection per track, -1 miss) of largest product, by enumeration."""
    n_tracks, n_cols = weights.shape
    best, arg = -math.inf, None
    for choice in itertools.product(range(-1, n_cols - 1), repeat=n_tracks):
        taken = [c for c in choice if c >= 0]
        if len(taken) != len(set(taken)):
            continue
        score = sum(math.log(weights[i, c + 1]) for i, c in enumerate(choice))
        if score > best:
            best, arg = score, list(choice)
    return arg


def test_the_gnn_takes_the_assignment_of_largest_product(stonesoup_installed):
    """Random weights (log-uniform over two decades) for 3 tracks and 3 detections, 25
    draws: Stone Soup's GNN over the distance hypotheses ``-log w`` chooses the
    brute-force maximiser of the product."""
    ss = sp.stonesoup()
    rng = np.random.default_rng(np.random.SeedSequence(2024))
    for _ in range(25):
        weights = np.exp(rng.uniform(-2.3, 2.3, size=(3, 4)))
        assert _gnn(ss, weights, 3, 3) == _brute_force(weights)


def test_the_gnn_maximises_the_product_not_the_sum(stonesoup_installed):
    """Hand case: track A weighs the detection 2.1 and its miss 1, track B 1.0 and 0.1. A
    takes it: product 0.21, sum 2.2; B takes it: product 1.0, sum 2.0. The product (the
    assignment's likelihood) gives it to B."""
    weights = np.array([[1.0, 2.1], [0.1, 1.0]])
    assert _gnn(sp.stonesoup(), weights, 2, 1) == [-1, 0]


# ------------------------------------------------------------------ the tracker
class _ExistenceEveryCell(sp.StoneSoupGNN):
    """ss-gnn by existence, set for the kit's every-cell tracking scenarios."""

    name = "ss-gnn-existence-every-cell"
    conformance_exceptions = {}
    parameters = None

    def __init__(self, gate: float = 5.0) -> None:
        super().__init__(gate, association="existence")


def test_existence_gnn_passes_the_tracking_checks(stonesoup_installed):
    testing.check_tracker(_ExistenceEveryCell, checks=["check_tracks_one_target",
                                                       "check_tracks_two_targets"])


def _state_masses(mean, cov, grid):
    """Position mass per cell ``(n_cells,)`` of a state, from scipy's normal cdf."""
    sd = np.sqrt(np.diag(cov)[[0, 2]])
    px = np.diff(norm.cdf(np.arange(grid.nx + 1) * grid.cell_size, mean[0], sd[0]))
    py = np.diff(norm.cdf(np.arange(grid.ny + 1) * grid.cell_size, mean[2], sd[1]))
    return np.outer(py, px).ravel()


def test_a_tracks_existence_through_its_life(stonesoup_installed):
    """On ``births``: a detection starts a track at the closed-form ``r0``; a step without
    looks only multiplies it by ``p_s``; a step whose looks miss it everywhere applies
    Bayes with ``L = 1 + sum_c m_c ((1 - p_d) / (1 - p_f) - 1)`` (scipy's masses of the
    predicted state); once ``r`` falls below the threshold the track is deleted and
    ``r m_c`` of its last state returns to the undetected intensity."""
    from mttbench.scenarios.model import Looks
    from mttbench.scenarios.spec import get as get_scenario
    from mttbench.trackers import kalman, make

    model = get_scenario("births").model
    grid, sensor, bd = model.grid, model.sensor, model.birth_death
    miss = (1 - sensor.p_d) / (1 - sensor.p_f)
    tracker = make("ss-gnn", association="existence", existence_threshold=0.05)
    tracker.reset(model, np.random.default_rng(0))
    cell = int(grid.cell_of(5.5, 4.5))
    everything = np.arange(grid.n_cells)
    tracker.predict()
    lam = tracker._undetected.at([cell])[0] + tracker._spare(0.0)
    tracker.update(Looks(np.array([cell]), np.array([True])))
    (track,) = tracker._tracks
    u = 1 - math.exp(-lam)
    r = u * sensor.p_d / (u * sensor.p_d + (1 - u) * sensor.p_f)
    assert tracker._r[track.id] == pytest.approx(r, rel=1e-12)
    tracker.predict()
    tracker.update(Looks(np.zeros(0, np.int64), np.zeros(0, bool)))
    r *= bd.survival_probability
    assert tracker._r[track.id] == pytest.approx(r, rel=1e-12)
    for _ in range(30):
        mean, cov = kalman.predict(np.ravel(track.state.mean)[None],
                                   np.asarray(track.state.covar, float)[None],
                                   model.dynamics.F, model.dynamics.Q)
        before = tracker._undetected.dense()
        tracker.predict()
        tracker.update(Looks(everything, np.zeros(grid.n_cells, bool)))
        p_s = bd.survival_probability
        lik = 1 + _state_masses(mean[0], cov[0], grid).sum() * (miss - 1)
        r = p_s * r * lik / (1 - p_s * r + p_s * r * lik)
        if not tracker._tracks:
            want = (p_s * before + bd.birth_rate / grid.n_cells) * miss
            last = _state_masses(np.ravel(track.state.mean), np.asarray(track.state.covar),
                                 grid)
            np.testing.assert_allclose(tracker._undetected.dense(), want + r * last,
                                       rtol=0, atol=1e-8)
            assert r < 0.05 and r * last.max() > 1e-3
            return
        assert tracker._r[track.id] == pytest.approx(r, rel=1e-9)
    pytest.fail("the track was never deleted")

"""``grid-bayes``, the exact single-target grid filter, against independent references:
Bayes' rule enumerated over every hypothesis, the closed form of existence under negative
looks, the Kalman prediction, mass conservation, and its refusals of multi-target models.
The conformance kit runs it through tests/test_conformance.py; the kit's checks it skips
(their scenarios have several targets) are run here on the single-target presets."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mttbench import scenarios, testing
from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.trackers import get_class, make
from mttbench.trackers.grid_bayes import AxisGrid, GridBayesTracker, axis_transition


def tiny_model(**bd) -> TrackingModel:
    """3x2 cells, one declared target, strong clutter so both returns carry weight."""
    birth = dict(initial_states=((1.2, 0.1, 0.7, -0.1),), survival_probability=0.9,
                 boundary="reflect")
    birth.update(bd)
    return TrackingModel(Grid(3, 2), Dynamics(wna_intensity=1e-2), BirthDeath(**birth),
                         RayleighGridSensor(p_d=0.7, snr=4.0, looks_per_step=5))


def fresh(model: TrackingModel, **params) -> GridBayesTracker:
    t = GridBayesTracker(**params)
    t.reset(model, np.random.default_rng(0))
    return t


# ------------------------------------------------------------------------- update
def test_update_equals_bayes_rule_enumerated_over_every_hypothesis():
    """A random density on every node and a random "no target" mass, looks with repeats
    and both returns: the update equals ``p(h | z) ∝ p(h) prod_looks p(z | n_h(cell))``
    over the hypotheses h = no target, or the target at one node (n_h(cell) its count in
    the looked cell, 0 or 1), with p(z | n) from the sensor directly (no ratios)."""
    model = tiny_model()
    t = fresh(model, spacing=2.0, velocity_sds=1.0)
    rng = np.random.default_rng(4)
    sx, sy = t._ax.size, t._ay.size
    P = rng.random((sx, sy))
    P *= 0.7 / P.sum()
    t._set_density(P.copy())  # the tracker updates its density in place
    t._no_target = 0.3
    cells = np.array([0, 4, 4, 5, 1, 0, 4])
    returns = np.array([True, True, False, False, True, False, True])
    t.update(Looks(cells, returns))

    sensor, grid = model.sensor, model.grid
    fx, fy = t._ax.features(), t._ay.features()
    node_cell = grid.cell_of(fx[:, 0][:, None], fy[:, 0][None, :])  # (sx, sy)
    like = np.ones((sx, sy))
    like_none = 1.0
    for c, z in zip(cells, returns, strict=True):
        p1 = np.where(node_cell == c, sensor.detection_probability(1),
                      sensor.detection_probability(0))
        like *= p1 if z else 1.0 - p1
        like_none *= sensor.p_f if z else 1.0 - sensor.p_f
    post = P * like
    none = 0.3 * like_none
    Z = post.sum() + none
    np.testing.assert_allclose(t.density(), post / Z, rtol=1e-12, atol=1e-300)
    assert t._no_target == pytest.approx(none / Z, rel=1e-12)
    assert t.existence + t._no_target == pytest.approx(1.0, abs=1e-14)


def test_many_positive_repeats_do_not_overflow():
    model = tiny_model()
    t = fresh(model, spacing=2.0, velocity_sds=1.0)
    t.update(Looks(np.full(400, 2), np.ones(400, dtype=bool)))
    P = t.density()
    assert np.all(np.isfinite(P)) and t.existence == pytest.approx(1.0)


# ----------------------------------------------------------------------- existence
def test_existence_under_negative_looks_at_every_cell_has_its_closed_form():
    """Every cell looked at once per step, every look negative: whatever the position,
    the target's likelihood ratio against "no target" is ``r = (1 - p_d) / (1 - p_f)``
    per step, so ``E_k = a r / (a r + 1 - a)`` with ``a = p_s E_{k-1}`` (``a = 1`` at step
    0: the simulator applies no survival before step 0)."""
    model = tiny_model()
    t = fresh(model)
    sensor = model.sensor
    r = (1 - sensor.p_d) / (1 - sensor.p_f)
    every = np.arange(model.grid.n_cells)
    E = 1.0
    for k in range(12):
        t.predict()
        a = E if k == 0 else model.birth_death.survival_probability * E
        assert t.existence == pytest.approx(a, rel=1e-12)
        t.update(Looks(every, np.zeros(len(every), dtype=bool)))
        E = a * r / (a * r + 1 - a)
        assert t.existence == pytest.approx(E, rel=1e-10)
        assert t.estimate().count == pytest.approx(E, rel=1e-10)
        assert len(t.estimate().states) == (1 if E >= 0.5 else 0)


# ---------------------------------------------------------------------- prediction
#: a long axis (40 cells), a target in its middle: the walls are 4+ sd away after STEPS
AXIS_LENGTH, STEPS = 40, 6


@pytest.mark.parametrize("boundary", ["reflect", "die"])
def test_axis_prediction_of_a_point_matches_the_kalman_prediction(boundary):
    """One axis, from a point ``(x0, v0)`` on a node, ``STEPS`` steps of the transition:
    the mean equals ``F^k x0`` (the lattice is symmetric and the linear split keeps
    means: tolerance 1e-9) and the covariance lies between the Kalman prediction's with
    ``Q`` (less 2%: the lattice's discretisation) and with ``Q + diag(h_x^2, h_v^2)/4``
    (the linear split adds at most ``h^2 / 4`` per coordinate and step)."""
    q = 0.05
    Q = q * np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]])
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    axis = AxisGrid(AXIS_LENGTH, AXIS_LENGTH, 4, h_v=0.1, n_half=50)
    K = axis_transition(axis, Q, 1.0, boundary)
    i0, j0 = 80, 50 + 3  # x0 = 20.125, v0 = 0.3
    p = np.zeros(axis.size)
    p[i0 * axis.n_v + j0] = 1.0
    for _ in range(STEPS):
        p = K @ p
    assert p.sum() == pytest.approx(1.0, abs=1e-9)  # no wall reached (either rule)
    feats = axis.features()
    mean = feats.T @ p
    cov = (feats - mean).T @ ((feats - mean) * p[:, None])
    x0 = np.array([axis.x[i0], axis.v[j0]])

    def kalman(Qs):
        m, C = x0.copy(), np.zeros((2, 2))
        for _ in range(STEPS):
            m, C = F @ m, F @ C @ F.T + Qs
        return m, C

    m_kf, C_lo = kalman(Q)
    _, C_hi = kalman(Q + np.diag([axis.h_x**2, axis.h_v**2]) / 4)
    np.testing.assert_allclose(mean, m_kf, atol=1e-9)
    assert np.all(np.diag(cov) >= 0.98 * np.diag(C_lo)), (np.diag(cov), np.diag(C_lo))
    assert np.all(np.diag(cov) <= np.diag(C_hi) + 1e-12), (np.diag(cov), np.diag(C_hi))


def test_transition_conserves_mass_under_reflect_and_loses_only_exits_under_die():
    axis = AxisGrid(5.0, 5, 4, h_v=0.1, n_half=12)
    Q = 2e-3 * np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]])
    reflect = axis_transition(axis, Q, 1.0, "reflect")
    np.testing.assert_allclose(np.asarray(reflect.sum(axis=0)).ravel(), 1.0, atol=1e-12)
    assert reflect.min() >= 0.0
    die = np.asarray(axis_transition(axis, Q, 1.0, "die").sum(axis=0)).ravel()
    assert np.all(die <= 1.0 + 1e-12) and die.min() >= 0.0
    feats = axis.features()
    # a node whose whole successor (4.5 sd) stays inside keeps all its mass
    inside = (feats[:, 0] + feats[:, 1] > 0.5) & (feats[:, 0] + feats[:, 1] < 4.5)
    np.testing.assert_allclose(die[inside], 1.0, atol=1e-12)
    # a node moving out at full speed from the edge loses everything
    out = (feats[:, 0] + feats[:, 1] < -0.3) | (feats[:, 0] + feats[:, 1] > 5.3)
    assert out.any() and np.all(die[out] == 0.0)


def test_four_d_prediction_is_the_product_of_the_axis_transitions_times_survival():
    model = tiny_model()
    t = fresh(model, spacing=2.0, velocity_sds=2.0)
    t.predict()  # step 0: the prior itself
    P0 = t.density()
    t.predict()
    expect = 0.9 * (t._Kx @ P0) @ t._Ky.T.toarray()
    np.testing.assert_allclose(t.density(), expect, rtol=1e-10, atol=1e-14)
    assert t.existence + t._no_target == pytest.approx(1.0, abs=1e-14)


def test_random_initial_prior_is_uniform_over_cells_with_the_birth_velocity():
    model = tiny_model(initial_states=(), n_random_initial=1, birth_velocity_std=0.2)
    t = fresh(model)
    t.predict()
    P = t.cell_count_distribution()
    np.testing.assert_allclose(P[:, 1], 1.0 / model.grid.n_cells, rtol=1e-12)
    E, mean, cov = t.posterior_moments()
    assert E == pytest.approx(1.0)
    np.testing.assert_allclose(mean, [1.5, 0.0, 1.0, 0.0], atol=1e-12)
    # the velocity binned on the grid: its variance is the birth variance within the
    # discretisation (h_v^2 / 12 more, binned Gaussian)
    assert cov[1, 1] == pytest.approx(0.04, abs=t._ax.h_v**2 / 12 + 2e-3)


# ------------------------------------------------------------------------ refusals
@pytest.mark.parametrize(("change", "words"), [
    (dict(initial_states=((1.0, 0, 1.0, 0), (2.0, 0, 1.0, 0))), "starts with 2"),
    (dict(initial_states=((1.0, 0, 1.0, 0),), n_random_initial=1), "starts with 2"),
    (dict(birth_rate=0.01), "Poisson births"),
    (dict(initial_states=(), birth_rate=0.01), "Poisson births"),
])
def test_refuses_models_that_can_hold_two_targets_in_one_line(change, words):
    reason = GridBayesTracker().unsupported_reason(tiny_model(**change))
    assert reason and words in reason and "\n" not in reason


def test_refuses_other_sensors_coupled_axes_and_oversized_grids():
    sup = scenarios.get("superposition").model
    assert "grid sensor" in GridBayesTracker().unsupported_reason(sup)
    m = tiny_model()
    Q = np.eye(4)
    Q[0, 2] = Q[2, 0] = 0.1
    coupled = dataclasses.replace(m, dynamics=Dynamics(q_matrix=tuple(map(tuple, Q))))
    assert "x-y" in GridBayesTracker().unsupported_reason(coupled)
    assert "max_states" in GridBayesTracker(max_states=100).unsupported_reason(m)
    with pytest.raises(ValueError, match="cannot run"):
        GridBayesTracker(max_states=100).reset(m, np.random.default_rng(0))


def test_accepts_the_single_target_models():
    for name in ("single-clean", "single-clutter"):
        assert GridBayesTracker().unsupported_reason(scenarios.get(name).model) is None
    assert GridBayesTracker().unsupported_reason(tiny_model(initial_states=())) is None


# ------------------------------------------------------------------ as a tracker
def test_is_a_registered_reference_that_uses_no_truth():
    cls = get_class("grid-bayes")
    assert cls is GridBayesTracker and cls.reference and not cls.uses_truth
    assert not cls.baseline  # it tracks: the kit's one-target check runs on it
    assert set(cls.conformance_exceptions) <= set(testing.CHECKS)
    assert make("grid-bayes", spacing=0.5).spacing == 0.5


def _short(name: str, steps: int) -> scenarios.Scenario:
    sc = scenarios.get(name)
    return dataclasses.replace(sc, name=f"check-{name}", n_steps=steps)


def test_single_target_runs_are_valid_deterministic_and_reset_cleanly():
    """The kit's interface checks it skips, on the single-target presets: valid
    estimates and ``P_c(t)`` at every step, equal outputs from two fresh trackers, and
    a used tracker after ``reset`` equal to a fresh one."""
    clean, clutter = _short("single-clean", 12), _short("single-clutter", 12)
    policy = testing._RasterWithPrediction
    a = testing._run(GridBayesTracker(spacing=2.0), clutter, 3, policy=policy())
    testing._assert_records_valid(a, clutter)
    b = testing._run(GridBayesTracker(spacing=2.0), clutter, 3, policy=policy())
    testing._assert_same_outputs(a, b, "two fresh trackers")
    used = GridBayesTracker(spacing=2.0)
    testing._run(used, clean, 5, n_steps=6)
    again = testing._run(used, clutter, 3, policy=policy())
    testing._assert_same_outputs(again, a, "used tracker after reset")
    assert all(r.counts.shape == (clutter.grid.n_cells, 2) for r in a)


def test_zero_target_model_reports_nothing():
    t = fresh(tiny_model(initial_states=()))
    t.predict()
    assert t.cell_count_distribution()[:, 1].sum() == 0.0
    t.update(Looks(np.array([0, 1]), np.array([True, True])))
    est = t.estimate()
    assert est.count == 0.0 and est.states.shape == (0, 4)

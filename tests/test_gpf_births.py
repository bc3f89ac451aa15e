"""GPF births from the undetected-target field, against hand computations on tiny grids.

The rule (trackers/gpf/tracker.py, "Births and the initial prior"; trackers/gpf/grid.py, last
paragraph): each looked cell with field value ``u_c > 0`` adds a birth candidate, a
Bernoulli of weight ``u_c`` uniform on the cell; in a cell that returned a detection the
candidate always joins the cluster of the particles that occupy the cell, so that a return
an existing particle explains is not also credited to a new target. After the update a
candidate whose cell returned a detection and whose posterior weight exceeds
``prune_threshold`` becomes a Gaussian (cell centre, position variance ``cell^2 / 12``,
velocity sd ``birth_velocity_std``, at rest) and the field there drops to ``birth_floor``
(on a model with arrivals, whose field is floored; the tests below use one with a tiny
rate, which no update-only step reads otherwise); every other candidate's posterior weight
goes back into the field.

The references below enumerate the joint options of the few Bernoulli variables by hand
(absent / in the looked cell / elsewhere) with the sensor's likelihood ratios
``l(T) = p(z | T) / p(z | 0)``; nothing is taken from the code under test. Tolerance: round-off
(``EXACT``); the Gaussian's mass outside its cell (1e-23 at 10 sd) is below it.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import stats

from mttbench import trackers
from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)

EXACT = 1e-12
SENSOR = RayleighGridSensor(p_d=0.5, snr=10.0, looks_per_step=4)


def _model(grid: Grid, birth_velocity_std: float = 0.1, n_initial: int = 0,
           birth_rate: float = 0.0) -> TrackingModel:
    """The field starts at ``max(n_initial / n_cells, birth_floor)`` in every cell.
    ``birth_rate > 0`` (arrivals): the field is floored at ``birth_floor`` after an update
    and no count bound applies."""
    return TrackingModel(grid, Dynamics(wna_intensity=1e-3),
                         BirthDeath(n_random_initial=n_initial, birth_rate=birth_rate,
                                    birth_velocity_std=birth_velocity_std), SENSOR)


def _ratio(returns: list[bool], T: int) -> float:
    """``prod over looks p(z | T) / p(z | 0)``, from the sensor's p_d(T) formula."""
    pd_t = SENSOR.p_d ** ((1.0 + SENSOR.snr) / (1.0 + T * SENSOR.snr))
    pf = SENSOR.p_d ** (1.0 + SENSOR.snr)
    return float(np.prod([pd_t / pf if z else (1.0 - pd_t) / (1.0 - pf) for z in returns]))


def _joint_posterior(priors: list[dict[str, float]], returns: list[bool], epsilon: float
                     ) -> list[float]:
    """Posterior existence probability of each Bernoulli variable by enumeration.

    ``priors[i]`` maps the options ``"absent"``, ``"cell"`` (the looked cell, which
    returned a detection) and ``"elsewhere"`` to their prior probabilities; the likelihood
    of a joint choice is ``l(T)`` with ``T`` the number in the looked cell. The cut acts on
    the joint choices' posterior (trackers/gpf/grid.py, "missed cells"): those with
    posterior ``<= epsilon`` are dropped and the rest renormalised."""
    weights, present = [], []
    for choice in itertools.product(*[list(p.items()) for p in priors]):
        prior = float(np.prod([pr for _, pr in choice]))
        if prior == 0.0:
            continue
        T = sum(opt == "cell" for opt, _ in choice)
        weights.append(prior * _ratio(returns, T))
        present.append([opt != "absent" for opt, _ in choice])
    post = np.array(weights) / sum(weights)
    post = np.where(post > epsilon, post, 0.0)
    return list(post @ np.array(present, dtype=float) / post.sum())


@pytest.mark.parametrize("epsilon", [0.0, 1e-4])
def test_candidate_in_a_detected_cell_joins_the_particle_that_explains_it(epsilon):
    """A particle (w = 0.9, all its mass in cell 0) and the field's candidate
    (u = 5e-4, below the interaction threshold 1e-3, so only the detection links them)
    share one positive look. Jointly, the detection is explained by the particle and the
    candidate's posterior is ~7.5e-4 (below prune_threshold: it stays in the field);
    updated alone it would be u l(1) / (u l(1) + 1 - u) = 0.34 and become a second
    target. With epsilon = 1e-4 the joint choice "particle absent, candidate in the cell"
    (posterior ~6e-5) is cut."""
    grid = Grid(2, 1, 1.0)
    u, w = 5e-4, 0.9
    t = trackers.make("gpf", epsilon=epsilon, birth_floor=u)
    t.reset(_model(grid, birth_rate=1e-3), np.random.default_rng(0))
    mean = np.array([0.5, 0.0, 0.5, 0.0])
    cov = np.diag([0.05**2, 0.01, 0.05**2, 0.01])
    t.set_particles([w], mean[None], cov[None])
    t.update(Looks(np.array([0]), np.array([True])))

    m_in = (stats.norm.cdf(10.0) - stats.norm.cdf(-10.0)) ** 2  # the particle's mass in cell 0
    particle = {"absent": 1.0 - w, "cell": w * m_in, "elsewhere": w * (1.0 - m_in)}
    candidate = {"absent": 1.0 - u, "cell": u}
    w_post, u_post = _joint_posterior([particle, candidate], [True], epsilon)
    assert u_post < 1e-3  # below prune_threshold: no new target
    alone = u * _ratio([True], 1) / (u * _ratio([True], 1) + 1.0 - u)
    assert alone > 0.3  # what a candidate updated on its own would get

    weights, means, covs = t.particles
    np.testing.assert_allclose(weights, [w_post], rtol=EXACT)
    np.testing.assert_allclose(means, mean[None], atol=EXACT)  # all its mass in the cell
    np.testing.assert_allclose(covs, cov[None], atol=EXACT)
    # the candidate's posterior went back into the field: P_0 is the Poisson-binomial of
    # the particle (w_post) and the field (u_post); cell 1 was not looked at (field u)
    pc = t.cell_count_distribution().dense()
    a, b = w_post * m_in, u_post
    np.testing.assert_allclose(pc[0], [(1 - a) * (1 - b), a * (1 - b) + (1 - a) * b, a * b, 0],
                               atol=EXACT)
    np.testing.assert_allclose(pc[1], [1 - u, u, 0, 0], atol=EXACT)
    assert t.estimate().count == pytest.approx(w_post, rel=EXACT)


def test_candidate_alone_in_a_detected_cell_becomes_a_target_at_the_cell_centre():
    """No particle near cell 4 of a 3 x 2 grid of 0.5 cells; two looks there, one positive,
    one negative. The candidate's posterior is u l / (u l + 1 - u) with l the product of the
    two looks' ratios at T = 1; it exceeds prune_threshold, so it becomes a Gaussian at the
    cell centre (0.75, 0.75), at rest, with position variance 0.5^2 / 12 and velocity
    variance birth_velocity_std^2; the field there drops to birth_floor. Cell 1 looked at
    with a negative return keeps its candidate in the field with the Bernoulli posterior.
    The field starts at 1/6 (one expected target on six cells)."""
    grid = Grid(3, 2, 0.5)
    u, bv, floor = 1.0 / 6.0, 0.07, 1e-3
    t = trackers.make("gpf", epsilon=0.0, birth_floor=floor)
    t.reset(_model(grid, birth_velocity_std=bv, n_initial=1, birth_rate=1e-3),
            np.random.default_rng(0))
    t.update(Looks(np.array([4, 1, 4]), np.array([True, False, False])))

    l4 = _ratio([True, False], 1)
    w_new = u * l4 / (u * l4 + 1.0 - u)
    l1 = _ratio([False], 1)
    u1 = u * l1 / (u * l1 + 1.0 - u)
    weights, means, covs = t.particles
    np.testing.assert_allclose(weights, [w_new], rtol=EXACT)
    np.testing.assert_allclose(means, [[0.75, 0.0, 0.75, 0.0]], atol=EXACT)
    np.testing.assert_allclose(covs, [np.diag([0.25 / 12, bv**2, 0.25 / 12, bv**2])],
                               atol=EXACT)
    # field: u everywhere not looked at, the floor where the target was born, u1 in cell 1
    pc = t.cell_count_distribution().dense()
    field = np.full(grid.n_cells, u)
    field[4], field[1] = floor, u1
    # the new Gaussian's mass per cell (diagonal: product of normal CDF differences)
    x0, x1, y0, y1 = grid.cell_bounds(np.arange(grid.n_cells))
    f = stats.norm(0.75, np.sqrt(0.25 / 12))
    mass = (f.cdf(x1) - f.cdf(x0)) * (f.cdf(y1) - f.cdf(y0))
    a, b = w_new * mass, field
    want = np.stack([(1 - a) * (1 - b), a * (1 - b) + (1 - a) * b, a * b, 0 * a], axis=1)
    np.testing.assert_allclose(pc, want, atol=EXACT)


def test_candidate_below_the_prune_threshold_is_not_born_even_if_detected():
    """One positive look at an empty cell with a tiny field (u = 1e-7): the posterior
    u l(1) / (u l(1) + 1 - u) = 1.0e-4 is below prune_threshold = 1e-3, so no target is
    born; the posterior stays in the field."""
    grid = Grid(2, 2, 1.0)
    u = 1e-7
    t = trackers.make("gpf", epsilon=0.0, birth_floor=u)
    t.reset(_model(grid), np.random.default_rng(0))
    t.update(Looks(np.array([3]), np.array([True])))
    post = u * _ratio([True], 1) / (u * _ratio([True], 1) + 1.0 - u)
    assert 1e-5 < post < 1e-3
    assert len(t.particles[0]) == 0
    np.testing.assert_allclose(t.cell_count_distribution().dense()[3], [1 - post, post, 0, 0],
                               atol=EXACT)

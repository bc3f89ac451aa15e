"""truth-aided's first-detection start on cells of 2.5 units: the new filter is the
uniform distribution over the detected cell (mean its centre, position variance that of a
uniform over a side ``s``, computed here numerically) with the births' velocity spread."""

from __future__ import annotations

import numpy as np

from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.trackers import make


def test_a_first_detection_starts_the_uniform_of_its_cell():
    s, bv = 2.5, 0.3
    grid = Grid(6, 5, s)
    state = np.array([[7.1, 0.2, 4.4, -0.1]])  # cell (2, 1)
    model = TrackingModel(grid, Dynamics(tau=1.0, wna_intensity=1e-3),
                          BirthDeath(initial_states=(tuple(state[0]),), birth_velocity_std=bv),
                          RayleighGridSensor(p_d=0.5, snr=10.0, looks_per_step=4))
    tracker = make("truth-aided", start="first_detection")
    tracker.reset(model, np.random.default_rng(0))
    tracker.predict()
    tracker.observe_truth(state, np.array([0]))
    cell = int(grid.cell_of(state[:, 0], state[:, 2])[0])
    assert cell == 1 * 6 + 2
    tracker.update(Looks(np.array([cell], dtype=np.int64), np.array([True])))
    est = tracker.estimate()
    assert est.states.shape == (1, 4)
    np.testing.assert_allclose(est.states[0, [0, 2]], grid.cell_centers([cell])[0])
    np.testing.assert_allclose(est.states[0, [1, 3]], 0.0)
    # the variance of a uniform over one side, by a fine midpoint grid of the cell
    u = (np.arange(100_000) + 0.5) / 100_000 * s
    var = float(np.var(u))
    np.testing.assert_allclose(np.diag(est.covariances[0]), [var, bv * bv, var, bv * bv],
                               rtol=1e-6)

"""The ``kreucher`` and ``kreucher-50`` presets: Kreucher's settings in cell units, the two
crossings of ``kreucher`` in the simulator, and ``kreucher-50``'s birth-death balance."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mttbench import scenarios
from mttbench.benchmarks.app.reproduce_kreucher import KREUCHER_CROSSINGS
from mttbench.scenarios.model import Dynamics, RayleighGridSensor
from mttbench.scenarios.simulator import simulate_truth
from mttbench.scenarios.spec import dumps, loads

#: Kreucher's Q = diag(20 m^2, 0.2 (m/s)^2, 20, 0.2) on 100 m cells, divided by (100 m)^2
Q_CELLS = np.diag([2e-3, 2e-5, 2e-3, 2e-5])
#: the pairs that meet at each crossing (indices of the preset's initial states: A, B, C)
PAIRS = {30: (0, 1), 70: (0, 2)}
#: the cell (ix, iy) where each pair's nominal paths meet
CELLS = {30: (4, 6), 70: (8, 6)}
SEEDS = range(20)


def _cells(states: np.ndarray) -> np.ndarray:
    """Integer cell coordinates ``(n, 2)`` of unit cells from states ``(n, 4)``."""
    return np.floor(states[:, [0, 2]]).astype(int)


def _share_near(truth: list[np.ndarray], pair: tuple[int, int], k0: int, window: int) -> bool:
    i, j = pair
    return any((_cells(truth[k])[i] == _cells(truth[k])[j]).all()
               for k in range(k0 - window, k0 + window + 1))


def _closest(truth: list[np.ndarray], pair: tuple[int, int], k0: int, window: int) -> float:
    """The smallest Chebyshev distance (cells) between the pair over ``k0 +- window``."""
    i, j = pair
    return min(float(np.abs(truth[k][i, [0, 2]] - truth[k][j, [0, 2]]).max())
               for k in range(k0 - window, k0 + window + 1))


@pytest.mark.parametrize("name", ["kreucher", "kreucher-50"])
def test_presets_load_round_trip_and_use_kreuchers_q_in_cell_units(name):
    sc = scenarios.get(name)
    assert sc.name == name and "2e-3" in sc.description
    assert loads(dumps(sc)) == sc
    m = sc.model
    assert m.grid.cell_size == 1.0 and m.dynamics.tau == 1.0
    np.testing.assert_array_equal(m.dynamics.Q, Q_CELLS)
    assert isinstance(m.sensor, RayleighGridSensor)
    assert (m.sensor.p_d, m.sensor.snr) == (0.5, 10.0)
    assert m.birth_death.birth_velocity_std == 0.1
    assert sc.n_steps == 100


def test_kreucher_is_the_sp05_setting():
    sc = scenarios.get("kreucher")
    m = sc.model
    assert (m.grid.nx, m.grid.ny) == (12, 12)
    assert len(m.birth_death.initial_states) == 3 and m.birth_death.n_random_initial == 0
    assert m.birth_death.survival_probability == 1.0 and m.birth_death.birth_rate == 0.0
    assert m.birth_death.boundary == "reflect"
    assert m.sensor.looks_per_step == 24


def test_kreucher_50_is_kreuchers_detection_setting():
    sc = scenarios.get("kreucher-50")
    m, bd = sc.model, sc.model.birth_death
    assert (m.grid.nx, m.grid.ny) == (50, 50)
    assert bd.initial_states == () and bd.n_random_initial == 10
    assert bd.survival_probability == 0.995 and bd.boundary == "die"
    # Kreucher's removal 0.005; births balance it at 10 targets (before exits)
    assert bd.birth_rate / (1.0 - bd.survival_probability) == pytest.approx(10.0)
    assert m.sensor.looks_per_step == m.grid.n_cells == 2500  # the whole grid, every step


def test_kreucher_50_count_stays_near_ten_and_falls_slowly_with_exits():
    """The description's numbers: 10 targets at first; the mean at step 99 (7.9 in 500
    worlds) below 10 because targets leaving the grid die, but not collapsing."""
    sc = scenarios.get("kreucher-50")
    counts = np.array([[len(s) for s in simulate_truth(sc, seed)[1]] for seed in range(50)])
    assert (counts[:, 0] == 10).all()
    assert 6.5 <= counts[:, -1].mean() <= 9.5


def test_nominal_paths_meet_in_one_cell_at_the_crossings():
    """Without process noise the pairs share the stated cell for a run of about ten steps
    centred on each crossing, and no pair shares a cell anywhere else."""
    sc = scenarios.get("kreucher")
    still = dataclasses.replace(sc, model=dataclasses.replace(
        sc.model, dynamics=Dynamics(tau=1.0, q_matrix=tuple((0.0,) * 4 for _ in range(4)))))
    _, truth = simulate_truth(still, 0)
    shared: dict[tuple[int, int], list[int]] = {(0, 1): [], (0, 2): [], (1, 2): []}
    for k, states in enumerate(truth):
        c = _cells(states)
        for i, j in shared:
            if (c[i] == c[j]).all():
                shared[(i, j)].append(k)
    assert shared[(1, 2)] == []
    assert tuple(sorted(PAIRS)) == KREUCHER_CROSSINGS
    for k0, pair in PAIRS.items():
        steps = shared[pair]
        assert steps == list(range(steps[0], steps[-1] + 1)), steps  # one contiguous visit
        assert 8 <= len(steps) <= 11 and abs(np.mean(steps) - k0) <= 1.0, steps
        assert tuple(_cells(truth[k0])[pair[0]]) == CELLS[k0]


def test_crossings_in_the_simulated_worlds():
    """With Kreucher's Q the targets drift (velocity random walk: about 0.5 cell of
    position by step 30, 1.5 by step 70). Measured on seeds 0-19: A and B share a cell
    within 5 steps of step 30 in 14 of 20 (59% of 1000 worlds) and come within one cell
    of each other within 10 steps in 19 of 20; A and C share a cell within 5 steps of step
    70 in 3 of 20 (9% of 1000) and come within 2 cells within 10 steps in 14 of 20 (63%).
    The preset's description states these fractions."""
    sc = scenarios.get("kreucher")
    truths = [simulate_truth(sc, seed)[1] for seed in SEEDS]
    n = len(truths)
    meet30 = sum(_share_near(t, PAIRS[30], 30, 5) for t in truths) / n
    close30 = sum(_closest(t, PAIRS[30], 30, 10) < 1.0 for t in truths) / n
    meet70 = sum(_share_near(t, PAIRS[70], 70, 5) for t in truths) / n
    close70 = sum(_closest(t, PAIRS[70], 70, 10) < 2.0 for t in truths) / n
    assert meet30 > 0.5, meet30          # most worlds: a real crossing at step 30
    assert close30 >= 0.8, close30
    assert meet70 < 0.5, meet70          # the description: rarely one cell near step 70
    assert close70 > 0.5, close70        # ... but usually within 2 cells

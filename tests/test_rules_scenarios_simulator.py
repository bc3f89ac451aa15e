"""Rules of the simulator (scenarios/simulator.py): reflection exactly at an edge, and
the uniforms behind repeated looks at one cell (numpy's PCG64 stream of the step, read
at ``j n_cells + c``, as the module docstring says)."""

from __future__ import annotations

import numpy as np

from mttbench.scenarios import get as get_scenario
from mttbench.scenarios.simulator import _LOOKS, _reflect, simulate, world_seed


def test_a_target_exactly_on_the_far_edge_bounces_back_inside():
    pos, vel = np.array([6.0, 3.0, 12.0]), np.array([1.0, 1.0, 1.0])
    _reflect(pos, vel, 6.0)
    assert pos[0] < 6.0 and pos[0] == np.nextafter(6.0, 0.0) and vel[0] == -1.0
    assert (pos[1], vel[1]) == (3.0, 1.0)
    assert (pos[2], vel[2]) == (0.0, 1.0)  # two lengths: back where it started


def test_repeated_looks_at_a_cell_read_the_streams_rows_in_order():
    sc = get_scenario("single-clean")  # one target, p_d = 0.5 in its cell
    run = simulate(sc, 5)
    C = sc.grid.n_cells
    for k in range(12):
        held = int(sc.grid.cell_of(run.states[k][:, 0], run.states[k][:, 2])[0])
        other = (held + 1) % C
        u = np.random.Generator(np.random.PCG64(world_seed(sc.name, 5, _LOOKS, k))).random(
            4 * C)
        cells = np.array([held, other, held, held, other, held])
        p = sc.model.sensor.detection_probability(run.counts_in(k, cells))
        assert p[0] == 0.5
        # the j-th look at c (in the order made) reads U[k, j, c] = draw j C + c
        rows = np.array([0, 0, 1, 2, 1, 3])
        want = u[rows * C + cells] < p
        assert run.look(k, cells).returns.tolist() == want.tolist()

"""Rules of the model types (scenarios/model.py) on a grid of cell size 2, written out by
hand: cell numbering at the top edge, centres and bounds, and a moving occlusion's
start."""

from __future__ import annotations

import numpy as np

from mttbench.scenarios.model import Grid, Occlusion, Visibility


def test_cells_centres_and_bounds_on_cells_of_size_two():
    g = Grid(3, 2, cell_size=2.0)  # workspace [0, 6) x [0, 4)
    assert g.cell_of(np.array([0.0, 5.9, 5.9, 1.0, 6.0]),
                     np.array([0.0, 3.9, 4.0, 2.0, 1.0])).tolist() == [0, 5, -1, 3, -1]
    assert g.cell_centers(np.array([0, 5])).tolist() == [[1.0, 1.0], [5.0, 3.0]]
    x0, x1, y0, y1 = g.cell_bounds(np.array([4]))
    assert (x0.tolist(), x1.tolist(), y0.tolist(), y1.tolist()) == ([2.0], [4.0], [2.0], [4.0])


def test_a_moving_occlusion_starts_from_its_rectangle_at_its_first_step():
    g = Grid(5, 1)
    o = Occlusion(x=(1, 1), y=(0, 0), steps=(3, 6), velocity=(1.0, 0.0))
    v = Visibility((o,))
    assert [v.blocked(k, g).tolist() for k in range(8)] == [
        [], [], [], [1], [2], [3], [4], []]
    assert v.is_blocked(4, np.arange(5), g).tolist() == [False, False, True, False, False]

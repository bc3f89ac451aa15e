"""Policy rules against independent references: search-track's own field after its looks
(the closed form ``p_d(1) = p_d``), the sparse top-M with own cells tied with the default
row (distinct cells, by the gains' order), and the P_c(t) check of a row summing below 1
beside rows summing to about 1."""

from __future__ import annotations

import numpy as np
import pytest

from mttbench.benchmarks.engine.information import _top_cells
from mttbench.benchmarks.engine.policies import count_distribution_problem, make_policy
from mttbench.scenarios.spec import loads
from mttbench.trackers.cells import CellCounts

SPEC = """
name = "band"
n_steps = 30

[grid]
nx = 7
ny = 5

[dynamics]
wna_intensity = 0.001

[targets]
initial_states = [[1.5, 0.0, 1.5, 0.0]]
n_random_initial = 2
survival_probability = 0.9
birth_rate = 0.4

[sensor]
kind = "rayleigh"
p_d = 0.6
snr = 4.0
looks_per_step = 3

[[occlusion]]
x = [0, 1]
y = [1, 2]
steps = [2, 20]
velocity = [1.0, 0.5]
"""


def test_search_tracks_own_field_keeps_the_undetected_share_of_each_looked_cell():
    """Without the tracker's field: ``lambda = n0 / C``, predicted to ``p_s lambda + b / C``
    before the looks, then times ``1 - p_d(1)`` in each looked cell (``p_d(1) = p_d`` for
    the Rayleigh sensor), the other cells as predicted."""
    model = loads(SPEC).model
    C = model.grid.n_cells
    pol = make_policy("search-track")
    pol.reset(model, 3, np.random.default_rng(0))
    P = np.tile([0.9, 0.1], (C, 1))
    chosen = pol.select(0, counts=P)
    predicted = 0.9 * 3 / C + 0.4 / C
    want = np.full(C, predicted)
    want[chosen] *= 1.0 - 0.6
    np.testing.assert_allclose(pol._own.dense(), want, rtol=1e-12)


@pytest.mark.parametrize("seed", [None, 0, 1])
@pytest.mark.parametrize("looks", [2, 3, 5, 9, 10])
def test_the_sparse_top_cells_are_distinct_with_own_cells_tied_with_the_default(seed, looks):
    """Own cells of gain 5, 3, 3, 1 and 6 default cells of gain 3 on 10 cells: the cell
    of gain 5 first, then cells of gain 3 (own or default), the cell of gain 1 last; always
    ``looks`` distinct cells."""
    counts = CellCounts(10, np.array([1, 4, 6, 8]), np.tile([0.5, 0.5], (4, 1)),
                        np.array([0.5, 0.5]))
    gain = np.array([5.0, 3.0, 3.0, 1.0])
    rng = None if seed is None else np.random.default_rng(seed)
    got = _top_cells(counts, gain, 3.0, looks, rng)
    assert len(got) == len(np.unique(got)) == looks
    assert 1 in got
    assert (8 in got) == (looks == 10)


def test_a_row_summing_below_one_is_reported_whatever_the_other_rows():
    P = np.tile([0.7, 0.3], (6, 1))
    P[4] = [0.25, 0.25]
    assert "summing to 0.5" in count_distribution_problem(P, 6)
    P[2] = [0.7, 0.3 + 1e-8]
    assert "summing to 0.5" in count_distribution_problem(P, 6)

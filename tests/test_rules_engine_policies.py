"""Rules of the cell-selection policies and their gains (benchmarks/engine/policies.py,
information.py, policy_lookahead.py, policy_search.py) on grids of a few cells, against
a greedy search and a raster walk written out here, and values computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from mttbench.benchmarks.engine import information as info
from mttbench.benchmarks.engine.policies import (
    Oracle,
    RandomCells,
    Raster,
    RenyiGain,
    count_distribution_problem,
)
from mttbench.benchmarks.engine.policy_lookahead import Lookahead
from mttbench.benchmarks.engine.policy_search import SearchTrack, undetected_rows
from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Occlusion,
    RayleighGridSensor,
    TrackingModel,
    Visibility,
)
from mttbench.trackers.cells import CellCounts


def _rng(seed=0):
    return np.random.default_rng(np.random.SeedSequence(seed))


def _model(nx=4, ny=1, occlusions=(), bd=None, looks=2):
    return TrackingModel(grid=Grid(nx, ny), dynamics=Dynamics(wna_intensity=0.01),
                         birth_death=bd or BirthDeath(), sensor=RayleighGridSensor(
                             p_d=0.5, snr=4.0, looks_per_step=looks),
                         visibility=Visibility(tuple(occlusions)))


def _counts(rng, n, k=3):
    return rng.dirichlet(np.full(k, 0.4), size=n)


# ------------------------------------------------------------------ information
def test_the_gain_needs_a_positive_order():
    P = _counts(_rng(), 3)
    with pytest.raises(ValueError, match="alpha must be > 0"):
        info.expected_gain(P, np.array([0.1, 0.5, 0.7]), alpha=0.0)


def _greedy_by_hand(P, pd, L):
    """Greedy by marginal gain G_c(n_c + 1) - G_c(n_c); ties to the fewest looks, then the
    lowest cell."""
    n = np.zeros(len(P), dtype=int)
    for _ in range(L):
        now = np.array([info.gain_of_looks(P[c:c + 1], pd, n[c])[0] for c in range(len(P))])
        nxt = np.array([info.gain_of_looks(P[c:c + 1], pd, n[c] + 1)[0]
                        for c in range(len(P))])
        gain = nxt - now
        best = np.flatnonzero(gain == gain.max())
        n[best[np.argmin(n[best])]] += 1
    return np.repeat(np.arange(len(P)), n).tolist()


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("L", [1, 2, 4, 6])
def test_greedy_looks_with_repeats_equal_the_greedy_by_hand(seed, L):
    rng = _rng(seed)
    P = _counts(rng, 3)
    pd = np.array([0.05, 0.6, 0.8])
    assert info.greedy_looks(P, pd, L, repeats=True, rng=None).tolist() == _greedy_by_hand(
        P, pd, L)


def test_distinct_looks_never_take_a_blind_cell():
    P = _counts(_rng(1), 4)
    got = info.greedy_looks(P, np.array([0.05, 0.6, 0.8]), 3, repeats=False, rng=_rng(),
                            blocked=np.array([0, 1, 2]))
    assert got.tolist() == [3]


def test_the_sparse_greedy_never_looks_at_a_blind_cell_even_its_best():
    rows = np.array([[0.2, 0.5, 0.3], [0.9, 0.1, 0.0]])
    counts = CellCounts(20, np.array([3, 8]), rows, np.array([1.0, 0.0, 0.0]))
    pd = np.array([0.05, 0.6, 0.8])
    for seed in range(5):
        got = info.greedy_looks_sparse(counts, pd, 6, repeats=True, rng=_rng(seed),
                                       blocked=np.array([3]))
        assert 3 not in got.tolist() and len(got) == 6


def test_the_default_pool_hands_out_every_default_cell_once():
    counts = CellCounts(12, np.array([2, 5, 6]), np.full((3, 2), 0.5), np.array([1.0, 0.0]))
    for seed in range(5):
        pool = info._DefaultPool(counts, _rng(seed))
        taken = [pool.take() for _ in range(counts.n_default)]
        assert sorted(taken) == [c for c in range(12) if c not in (2, 5, 6)]


# --------------------------------------------------------------------- policies
def test_the_random_draws_memory_and_its_looks_when_few_cells_are_visible():
    model = _model(nx=40, ny=10, looks=3)
    assert RandomCells.resource_terms({}, model, 3).state_bytes == 150 * 8.0
    assert RandomCells.resource_terms({}, model, 100).state_bytes == 400 * 8.0
    blind = _model(nx=5, occlusions=[Occlusion((0, 2), (0, 0), (0, 9))], looks=4)
    pol = RandomCells()
    pol.reset(blind, 4, _rng())
    assert pol.select(0).tolist() == [3, 4]


def _raster_by_hand(model, m, steps):
    """The sweep over the visible cells: from the pointer's cell (or the next visible),
    m visible cells in order, wrapping; the pointer then stands after the last."""
    C, p, out = model.grid.n_cells, 0, []
    for k in range(steps):
        visible = [c for c in range(C) if c not in set(model.blocked_cells(k).tolist())]
        start = next((i for i, c in enumerate(visible) if c >= p), 0)
        cells = [visible[(start + j) % len(visible)] for j in range(m)]
        out.append(cells)
        p = (cells[-1] + 1) % C
    return out


def test_the_raster_walks_the_visible_cells_from_where_it_stopped():
    model = _model(nx=7, occlusions=[Occlusion((2, 3), (0, 0), (0, 20), velocity=(1.0, 0.0))],
                   looks=3)
    pol = Raster()
    pol.reset(model, 3, _rng())
    got = [pol.select(k).tolist() for k in range(12)]
    assert got == _raster_by_hand(model, 3, 12)


def test_the_oracles_fill_never_lands_on_a_blind_cell():
    model = _model(nx=6, occlusions=[Occlusion((1, 3), (0, 0), (0, 30))], looks=3)
    pol = Oracle()
    pol.reset(model, 3, _rng())
    for k in range(30):
        got = pol.select(k, truth_cells=np.array([5])).tolist()
        assert 5 in got and len(got) == 3 and not {1, 2, 3} & set(got)


def test_a_prediction_of_one_count_column_is_refused():
    assert count_distribution_problem(np.ones((4, 1)), 4) != ""
    assert count_distribution_problem(np.full((4, 2), 0.5), 4) == ""


def test_renyi_scores_the_counts_by_the_sensors_pd_at_each_count():
    model = _model(nx=6, looks=2)
    P = _counts(_rng(3), 6)
    pol = RenyiGain()
    pol.reset(model, 2, _rng(9))
    pd = np.array([model.sensor.p_d ** (1 + model.sensor.snr),  # t = 0: p_f
                   model.sensor.p_d,  # t = 1
                   model.sensor.p_d ** ((1 + model.sensor.snr) / (1 + 2 * model.sensor.snr))])
    want = info.greedy_looks(P, pd, 2, 0.5, False, _rng(9))
    assert pol.select(0, P).tolist() == want.tolist()


# -------------------------------------------------------------------- lookahead
def test_the_lookahead_bracket_and_its_blind_cells():
    model = _model(nx=4, occlusions=[Occlusion((1, 1), (0, 0), (1, 1))])
    la = Lookahead(weight=2.0, horizon=1, discount=0.5)
    la.reset(model, 1, _rng())
    cells, w = la.value_weights(0)
    assert cells.tolist() == [1] and w.tolist() == [2.0]  # 1 + 2 x 0.5 x (blind at 1)
    P = _counts(_rng(4), 4)
    q = la.values(1, P)  # step 1: cell 1 is blind
    g = info.expected_gain(P, model.sensor.detection_probability(np.arange(3)), 0.5)
    assert q[1] == -np.inf and q[[0, 2, 3]].tolist() == g[[0, 2, 3]].tolist()
    q0 = la.values(0, P)
    assert q0[1] == pytest.approx(2.0 * g[1]) and q0[0] == g[0]


# ------------------------------------------------------------------ search-track
def test_search_tracks_own_field_values_and_memory():
    bd = BirthDeath(n_random_initial=2, survival_probability=0.9, birth_rate=0.4)
    model = _model(nx=4, bd=bd, looks=1)
    st = SearchTrack(search_scale=3.0)
    st.reset(model, 1, _rng())
    assert st._own.default == 2 / 4  # the initial count spread over the cells
    assert st.weight != 1.0
    P = _counts(_rng(5), 4)
    lam = np.array([0.1, 0.3, 0.0, 1.2])
    lik = model.sensor.detection_probability(np.arange(3))
    g = info.expected_gain(P, lik, 0.5)
    d = info.expected_gain(undetected_rows(lam, 3), lik, 0.5)
    assert st.values(P, lam) == pytest.approx(g + (st.weight - 1.0) * d)
    chosen = st.select(0, P)  # no tracker field: its own, predicted, then looked at
    prior = 0.9 * 0.5 + 0.4 / 4
    pd1 = model.sensor.p_d
    for c in range(4):
        want = prior * (1 - pd1) if c in chosen.tolist() else prior
        assert st._own.at(np.array([c]))[0] == pytest.approx(want)
    terms = SearchTrack.resource_terms({}, model, 1)
    assert terms.state_bytes == 2 * 16 * 4  # two fields over the 4 cells


def test_the_lookahead_declares_its_visibility_lists():
    # H lists of at most each occlusion's area (3 x 2 and 1 x 1 cells), 16 bytes a cell
    model = _model(nx=6, ny=2, occlusions=[Occlusion((0, 2), (0, 1), (0, 3)),
                                           Occlusion((5, 5), (1, 1), (2, 4))])
    terms = Lookahead.resource_terms({"horizon": 3}, model, 2)
    assert terms.state_bytes == 16.0 * 3 * 7 and terms.looks == 2.0

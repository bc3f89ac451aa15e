"""The search-track policy: its value by hand, no truth, M distinct cells, a closed loop."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mttbench import scenarios, trackers
from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.policies import make_policy
from mttbench.benchmarks.engine.policy_search import search_horizon, track_horizon
from mttbench.scenarios.model import Grid
from mttbench.trackers.cells import CellCounts, CellField

DEFAULT = scenarios.get("default")
MODEL = DEFAULT.model  # 12x12, p_s = 1, no births, p_d 0.5, snr 10, WNA q = 5e-4


def _gain_by_hand(row: list[float], pd: list[float], alpha: float) -> float:
    """Expected Renyi gain of one binary look, scalar loops over outcomes and counts."""
    total = 0.0
    for z in (0, 1):
        lik = [p if z else 1.0 - p for p in pd]
        pz = sum(r * l for r, l in zip(row, lik, strict=True))
        inner = sum(r * l**alpha for r, l in zip(row, lik, strict=True)) / pz**alpha
        total += pz * math.log(inner) / (alpha - 1.0)
    return total


def _policy(n_looks: int, model=MODEL, seed: int = 0, **params):
    pol = make_policy("search-track", **params)
    pol.reset(model, n_looks, np.random.default_rng(seed))
    return pol


def test_horizons_by_hand():
    """``H = 1 / (1 - p_s (1 - M p_d / C))``; WNA noise spreads the position as ``q k^3 / 3``
    (``sum_{j<k} q (1/3 + j + j^2)``), so the track horizon is ``ceil((3 s^2 / q)^(1/3))``."""
    assert search_horizon(0.995, 250, 2500, 0.5) == pytest.approx(1.0 / (1.0 - 0.995 * 0.95))
    assert search_horizon(1.0, 288, 144, 0.5) == 1.0  # every missed target found next step
    F, Q = MODEL.dynamics.F, MODEL.dynamics.Q
    assert track_horizon(F, Q, 1.0) == math.ceil((3.0 / 5e-4) ** (1.0 / 3.0))  # 19
    assert track_horizon(F, Q, 2.0) == math.ceil((12.0 / 5e-4) ** (1.0 / 3.0))


def test_value_of_a_search_cell_against_a_held_target_by_hand():
    """Cell 10 may hold an undetected target (lambda = 0.05, nothing held); cell 20 holds a
    track with probability 1/2 (plus lambda = 0.001). Every other cell is certainly empty.
    ``V = G + (w - 1) D`` with ``w = H_search / H_track`` computed by hand: one look
    (M = 1) on 144 cells at p_s = 1 gives ``H_search = 288``, ``H_track = 19``. renyi (G
    alone) looks at the held target; search-track at the search cell."""
    n = MODEL.grid.n_cells
    pd = [MODEL.sensor.p_f, MODEL.sensor.detection_probability(1)]
    lam_a, lam_b = 0.05, 0.001
    q_a, q_b = -math.expm1(-lam_a), -math.expm1(-lam_b)
    row_a = [1.0 - q_a, q_a]
    row_b = [0.5 * (1.0 - q_b), 1.0 - 0.5 * (1.0 - q_b)]  # 1 or more, last column
    P = np.zeros((n, 2))
    P[:, 0] = 1.0
    P[10], P[20] = row_a, row_b
    field = CellField(n, 0.0)
    field.set(np.array([10, 20]), np.array([lam_a, lam_b]))
    for alpha in (0.5, 2.0):
        w = 288.0 / 19.0
        g_a, g_b = _gain_by_hand(row_a, pd, alpha), _gain_by_hand(row_b, pd, alpha)
        d_a, d_b = g_a, _gain_by_hand([1.0 - q_b, q_b], pd, alpha)
        want_a, want_b = g_a + (w - 1.0) * d_a, g_b + (w - 1.0) * d_b
        pol = _policy(1, alpha=alpha)
        assert pol.weight == pytest.approx(w)
        v = pol.values(P[[10, 20]], np.array([lam_a, lam_b]))
        np.testing.assert_allclose(v, [want_a, want_b], rtol=1e-10)
        assert g_b > g_a and want_a > want_b  # renyi prefers the track, we the search
        assert pol.select(0, counts=P, undetected=field).tolist() == [10]
        renyi = make_policy("renyi", alpha=alpha)
        renyi.reset(MODEL, 1, np.random.default_rng(0))
        assert renyi.select(0, counts=P).tolist() == [20]


def test_weight_one_is_renyi():
    """With ``H_search = H_track`` the value is G alone: the same cells as renyi."""
    rng = np.random.default_rng(3)
    P = rng.dirichlet(np.ones(3), size=MODEL.grid.n_cells)
    pol = _policy(20, search_scale=0.0, track_horizon=False)
    pol.weight = 1.0
    renyi = make_policy("renyi")
    renyi.reset(MODEL, 20, np.random.default_rng(0))
    assert pol.select(0, counts=P).tolist() == renyi.select(0, counts=P).tolist()


def test_own_field_without_the_trackers_intensity():
    """A tracker without an undetected intensity: the policy's own field starts at n0 / C,
    is predicted ``p_s lambda + b / C`` each step and thinned by ``1 - p_d(1)`` per look."""
    model = scenarios.get("births").model  # n0 = 2, p_s = 0.98, b = 0.05, 144 cells
    pol = _policy(24, model=model)
    P = np.tile([1.0, 0.0], (144, 1))
    cells = pol.select(0, counts=P)
    lam = 0.98 * 2.0 / 144 + 0.05 / 144
    pd1 = float(model.sensor.detection_probability(1))
    np.testing.assert_allclose(pol._own.at(cells), lam * (1.0 - pd1))
    rest = np.setdiff1d(np.arange(144), cells)
    np.testing.assert_allclose(pol._own.at(rest), lam)


def test_never_uses_the_truth_and_picks_m_distinct_cells():
    pol = make_policy("search-track")
    assert not pol.uses_truth and pol.uses_prediction and pol.uses_undetected
    rng = np.random.default_rng(1)
    P = rng.dirichlet(np.ones(4), size=MODEL.grid.n_cells)
    field = CellField(MODEL.grid.n_cells, 0.01)
    field.set(np.arange(0, 144, 7), rng.uniform(0, 0.2, 21))
    a = _policy(30, seed=5).select(2, counts=P, truth_cells=None, undetected=field)
    b = _policy(30, seed=5).select(2, counts=P, truth_cells=np.array([3, 50, 99]),
                                   undetected=field)
    assert a.tolist() == b.tolist()
    assert a.dtype == np.int64 and len(a) == 30 and len(np.unique(a)) == 30
    assert a.min() >= 0 and a.max() < MODEL.grid.n_cells
    # more looks than cells: every cell once
    c = _policy(500).select(0, counts=P, undetected=field)
    assert c.tolist() == list(range(MODEL.grid.n_cells))


def test_sparse_path_chooses_the_top_values():
    """On a grid above DENSE_CELLS (60x60) the values are computed per distinct row; the
    cells chosen are the top-M of the dense values (own cells of distinct values above
    the default, then default cells drawn at random)."""
    model = dataclasses.replace(MODEL, grid=Grid(60, 60, 1.0))
    n = model.grid.n_cells
    rng = np.random.default_rng(2)
    own = np.sort(rng.choice(n, 40, replace=False))
    rows = rng.dirichlet(np.ones(3), size=40)
    cc = CellCounts(n, own, rows, np.array([0.999, 0.001, 0.0]))
    field = CellField(n, 0.002)
    fcells = np.sort(rng.choice(n, 30, replace=False))
    field.set(fcells, rng.uniform(0.0, 0.05, 30))
    pol = _policy(100, model=model)
    chosen = pol.select(0, counts=cc, undetected=field)
    assert len(np.unique(chosen)) == 100
    dense = _policy(100, model=model).values(cc.dense(), field.dense())
    default = dense[np.setdiff1d(np.arange(n), np.union1d(own, fcells))][0]
    above = np.nonzero(dense > default)[0]
    assert len(above) < 100  # the rest are default cells
    assert set(above.tolist()) <= set(chosen.tolist())
    np.testing.assert_allclose(dense[np.setdiff1d(chosen, above)], default)


def test_gpf_and_pmb_give_a_copy_of_their_undetected_intensity():
    sc = scenarios.get("births")
    for name in ("gpf", "pmb"):
        t = trackers.make(name)
        t.reset(sc.model, np.random.default_rng(0))
        t.predict()
        f = t.undetected_intensity()
        assert isinstance(f, CellField) and f.total() > 0
        f.affine(0.0, 7.0)
        assert t.undetected_intensity().default != 7.0
    null = trackers.make("null")  # holds no such field: the base's None
    null.reset(sc.model, np.random.default_rng(0))
    assert null.undetected_intensity() is None


@pytest.mark.parametrize("name", ["gpf", "pmb", "kfnn", "null"])
def test_closed_loop_end_to_end(name):
    """A few steps of the harness's loop on ``births`` (the tracker's field; ``null`` has
    none, so the policy's own): valid looks, finite estimates."""
    sc = dataclasses.replace(scenarios.get("births"), n_steps=8)
    pol = make_policy("search-track")
    n = 0
    for rec in play(sc, trackers.make(name), 0, policy=pol):
        cells = rec.looks.cells
        assert len(np.unique(cells)) == 24 and cells.min() >= 0 and cells.max() < 144
        assert np.isfinite(rec.estimate.count)
        n += 1
    assert n == 8


def test_choice_is_a_top_m_over_a_maskable_candidate_set():
    """``choose``: the largest values among the allowed cells only."""
    pol = _policy(3)
    v = np.arange(144, dtype=float)
    allowed = np.ones(144, dtype=bool)
    allowed[[143, 141]] = False
    assert pol.choose(v, 3).tolist() == [141, 142, 143]
    assert pol.choose(v, 3, allowed).tolist() == [139, 140, 142]
    assert pol.choose(v, 3, np.arange(144) < 2).tolist() == [0, 1]

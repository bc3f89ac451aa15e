"""Nothing per step costs ``O(cells)``: the sparse ``P_c(t)`` kernels against the
dense ones they replace, each tracker's ``P_c(t)`` against the dense computation it
replaced, the policies' choices against the dense rule, the simulator's jumped stream
against numpy's generator, and whole runs on a 1e5 x 1e5 grid (1e10 cells: one dense
float array of it would be 80 GB) under a memory bound."""

from __future__ import annotations

import dataclasses
import tracemalloc

import numpy as np
import pytest
from scipy import stats
from scipy.special import expit

from mttbench import scenarios, trackers
from mttbench.benchmarks.engine.information import (
    DENSE_CELLS,
    expected_gain,
    gain_of_looks,
    greedy_looks,
)
from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.policies import Oracle, make_policy
from mttbench.scenarios.model import Grid
from mttbench.scenarios.simulator import (
    pcg64_uniforms,
    simulate,
    stream_uniforms,
    tracker_seed,
)
from mttbench.testing import _assert_count_distribution_valid
from mttbench.trackers import kalman
from mttbench.trackers.cells import (
    BOX_SD,
    CellCounts,
    CellField,
    as_cell_counts,
    bernoulli_cell_counts,
    gaussian_cell_mass,
    gaussian_cell_mass_sparse,
    poisson_binomial,
)
from mttbench.trackers.gpf.grid import reflection_images

#: most mass a Gaussian loses outside its 6-sd box: 2 Phi(-6) per axis
TAIL = 4e-9


# ----------------------------------------------------------------- the sparse kernels
def _in_box(grid: Grid, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """``(K, n_cells)``: the cell meets ``[m - 6 sd, m + 6 sd]`` on both axes (written
    from the edges, independently of the kernel's index arithmetic)."""
    x0, x1, y0, y1 = grid.cell_bounds(np.arange(grid.n_cells))
    sx = np.sqrt(covs[:, 0, 0])[:, None]
    sy = np.sqrt(covs[:, 1, 1])[:, None]
    mx, my = means[:, 0:1], means[:, 1:2]
    return ((x1 > mx - BOX_SD * sx) & (x0 <= mx + BOX_SD * sx)
            & (y1 > my - BOX_SD * sy) & (y0 <= my + BOX_SD * sy))


def _random_gaussians(rng, grid: Grid, K: int) -> tuple[np.ndarray, np.ndarray]:
    W, H = grid.extent
    means = np.column_stack([rng.uniform(-0.3 * W, 1.3 * W, K),
                             rng.uniform(-0.3 * H, 1.3 * H, K)])
    sd = rng.choice([0.04, 0.3, 1.0, 3.0, 100.0], size=(K, 2))
    covs = np.zeros((K, 2, 2))
    covs[:, 0, 0], covs[:, 1, 1] = sd[:, 0] ** 2, sd[:, 1] ** 2
    covs[:, 0, 1] = covs[:, 1, 0] = 0.3 * sd[:, 0] * sd[:, 1]
    return means, covs


def test_sparse_cell_mass_is_the_dense_one_inside_the_box():
    """Inside the 6-sd box every entry is the dense kernel's, bit for bit; outside it
    there is no entry and the dense mass is below the tail bound; entries ordered by
    (component, cell)."""
    rng = np.random.default_rng(0)
    for _ in range(150):
        grid = Grid(int(rng.integers(1, 25)), int(rng.integers(1, 25)), 1.0)
        K = int(rng.integers(0, 7))
        means, covs = _random_gaussians(rng, grid, K)
        dense = gaussian_cell_mass(grid, means, covs)
        comp, cells, mass = gaussian_cell_mass_sparse(grid, means, covs)
        box = _in_box(grid, means, covs)
        assert np.array_equal(np.sort(comp * grid.n_cells + cells),
                              np.flatnonzero(box.ravel()))
        assert np.all(np.diff(comp * grid.n_cells + cells) > 0)
        np.testing.assert_array_equal(mass, dense[comp, cells])
        assert np.all(dense[~box] < TAIL / 2)
        assert np.all(dense.sum(axis=1) - np.bincount(comp, mass, minlength=K) < TAIL)


def test_sparse_cell_mass_of_a_gaussian_off_the_grid_is_empty():
    grid = Grid(10, 8, 1.0)
    comp, cells, mass = gaussian_cell_mass_sparse(
        grid, np.array([[-5.0, 4.0], [5.0, 30.0]]), np.eye(2)[None].repeat(2, 0) * 0.25)
    assert len(comp) == len(cells) == len(mass) == 0


@pytest.mark.parametrize("n_counts", [2, 4, 6])
def test_bernoulli_cell_counts_is_poisson_binomial_of_the_dense_array(n_counts):
    """The same Bernoullis as a dense ``(K + 1, n_cells)`` array (zeros elsewhere, the
    field last): every row equal bit for bit, repeated cells and zero probabilities
    included, and the cells without an entry get the default row."""
    rng = np.random.default_rng(n_counts)
    for _ in range(100):
        n_cells, K = int(rng.integers(1, 40)), int(rng.integers(0, 6))
        dense = np.zeros((K + 1, n_cells))
        comp, cells = [], []
        for k in range(K):
            c = rng.choice(n_cells, int(rng.integers(0, n_cells + 1)), replace=False)
            dense[k, c] = rng.uniform(0, 1, len(c)) * (rng.random(len(c)) < 0.9)
            comp += [k] * len(c)
            cells += list(np.sort(c))
        comp, cells = np.array(comp, dtype=np.int64), np.array(cells, dtype=np.int64)
        default = float(rng.uniform(0, 0.3))
        own = np.sort(rng.choice(n_cells, int(rng.integers(0, n_cells + 1)), replace=False))
        dense[K] = default
        dense[K, own] = rng.uniform(0, 1, len(own))
        cc = bernoulli_cell_counts(n_cells, n_counts, cells, dense[comp, cells], default,
                                   own, dense[K, own])
        np.testing.assert_array_equal(cc.dense(), poisson_binomial(dense, n_counts))
        assert not np.isin(np.setdiff1d(np.arange(n_cells), np.r_[cells, own]), cc.cells).any()


def test_cell_field_is_the_dense_array_bit_for_bit():
    """Random affine maps, per-cell factors and per-cell additions, on the field and on a
    dense array: equal bit for bit at every step; a cell whose value meets the default
    again rejoins it."""
    rng = np.random.default_rng(5)
    n = 50
    field, dense = CellField(n, 0.37), np.full(n, 0.37)
    for _ in range(300):
        u = rng.random()
        if u < 0.4:
            a, b = float(rng.uniform(0.5, 1.0)), float(rng.uniform(0, 0.01))
            field.affine(a, b)
            dense = a * dense + b
        elif u < 0.6:
            cells = np.sort(rng.choice(n, int(rng.integers(0, 8)), replace=False))
            amounts = rng.uniform(0, 0.05, len(cells))
            field.add(cells, amounts)
            dense[cells] = dense[cells] + amounts
        else:
            cells = np.sort(rng.choice(n, int(rng.integers(0, 8)), replace=False))
            f = (1.0 - 0.5) ** rng.integers(1, 4, len(cells))
            field.multiply(cells, f)
            dense[cells] = dense[cells] * f
        np.testing.assert_array_equal(field.dense(), dense)
        np.testing.assert_array_equal(field.at(np.arange(n)), dense)
        assert not np.any(field.values == field.default)
    zero = CellField(n, 0.0)
    zero.multiply(np.arange(10), np.full(10, 0.5))
    zero.affine(0.9, 0.0)
    assert len(zero.cells) == 0  # 0 * anything is the default again


# ---------------------------------------------------------------- trackers' P_c(t)
def _dense_with_tail(P_new: np.ndarray, P_box: np.ndarray, P_full: np.ndarray,
                     K: int, rtol: float = 0.0) -> None:
    """``P_new`` (dense of the new ``P_c``) equals the old dense computation with every
    Gaussian cut to its box (bit for bit, or to round-off where the old code renormalised),
    and the old computation itself within the mass the boxes leave out."""
    if rtol:
        np.testing.assert_allclose(P_new, P_box, rtol=rtol, atol=1e-15)
    else:
        np.testing.assert_array_equal(P_new, P_box)
    assert np.abs(P_new - P_full).max() <= TAIL * max(K, 1)


def _scenario(name: str, n_steps: int, side: int | None = None):
    sc = scenarios.get(name)
    if side is not None:
        model = dataclasses.replace(sc.model, grid=Grid(side, side, 1.0))
        sc = dataclasses.replace(sc, model=model, name=f"{name}-{side}")
    return dataclasses.replace(sc, n_steps=n_steps)


def _kfnn_like_old(grid, m, P, exist, lam):
    """KF-NN's former ``P_c(t)``: the dense cell masses (full, and cut to the boxes) of
    the tracks times their existence, then the untracked field, Poisson-binomial."""
    means, covs = kalman.position_marginal(m, P)
    mass = gaussian_cell_mass(grid, means, covs)
    untracked = -np.expm1(-lam)
    full = poisson_binomial(np.concatenate([mass * exist[:, None], untracked[None]]), 4)
    cut = np.where(_in_box(grid, means, covs), mass, 0.0)
    box = poisson_binomial(np.concatenate([cut * exist[:, None], untracked[None]]), 4)
    return box, full


def _steps(sc, tracker, seed: int, n_steps: int):
    """Drive ``tracker`` by hand on world ``seed`` with random looks at the scenario's
    budget; yields ``(k, looks of step k - 1)`` after each ``predict`` (and, for a
    reference, ``observe_truth``), before the update."""
    run = simulate(sc, seed)
    tracker.reset(sc.model, np.random.default_rng(tracker_seed(sc.name, seed, tracker.name)))
    pol = make_policy("random")
    pol.reset(sc.model, sc.model.sensor.looks_per_step, np.random.default_rng(seed + 1))
    looks = None
    for k in range(n_steps):
        tracker.predict()
        if tracker.uses_truth:
            tracker.observe_truth(run.states[k], run.ids[k])
        yield k, looks
        looks = run.look(k, pol.select(k))
        tracker.update(looks)


def _steps_with_dense_intensity(sc, tracker, seed: int, n_steps: int, monkeypatch):
    """:func:`_steps`, yielding after each predict the undetected intensity the dense
    rules give (``p_s lambda + b / n`` per predict, ``((1 - p_d) / (1 - p_f))^looks`` per
    look, then
    ``+ r m_c`` for each deleted track the tracker recycles, ``m_c`` the dense cell mass
    cut to its 6-sd box) and the number of tracks recycled so far. The tracker module's
    ``recycle`` is wrapped to record what it recycles (its ``r``, means and covariances)
    and still does it."""
    bd, n = sc.model.birth_death, sc.grid.n_cells
    miss = (1.0 - sc.model.sensor.p_d) / (1.0 - sc.model.sensor.p_f)
    module = __import__(type(tracker).__module__, fromlist=["recycle"])
    recycled = []

    def recording(field, grid, r, m, P):
        recycled.append((np.array(r), np.array(m), np.array(P)))
        return original(field, grid, r, m, P)

    original = module.recycle
    monkeypatch.setattr(module, "recycle", recording)
    lam = np.full(n, bd.initial_count_mean / n)
    total = 0
    for _k, looks in _steps(sc, tracker, seed, n_steps):
        if looks is not None:
            cells, counts = np.unique(looks.cells, return_counts=True)
            lam[cells] = lam[cells] * miss ** counts
            for r, m, P in recycled:
                total += len(r)
                if len(r):
                    means, covs = kalman.position_marginal(m, P)
                    mass = np.where(_in_box(sc.grid, means, covs),
                                    gaussian_cell_mass(sc.grid, means, covs), 0.0)
                    add = np.zeros(n)
                    for k in range(len(r)):  # in order, as the sparse sum
                        add = add + r[k] * mass[k]
                    touched = add != 0.0
                    lam[touched] = lam[touched] + add[touched]
            recycled.clear()
        lam = bd.survival_probability * lam + bd.birth_rate / n
        yield lam, total


@pytest.mark.parametrize("name", ["births", "large"])
def test_kfnn_counts_equal_the_dense_computation(name, monkeypatch):
    """The undetected intensity followed densely (``p_s lambda + b / n`` per predict,
    ``((1 - p_d) / (1 - p_f))^looks`` per look, deleted tracks' ``r m_c`` added, bit for
    bit; some are
    recycled in the run) and the tracks' masses
    dense: the new ``P_c(t)`` is that computation with the masses cut to the 6-sd boxes,
    bit for bit, and within the boxes' tail of the uncut one."""
    sc = _scenario(name, {"births": 100, "large": 60}[name])  # long enough to delete
    tr = trackers.make("kfnn")
    n = sc.grid.n_cells
    tracks = 0
    # a world where tracks inside the workspace are deleted (recycled) within the run
    seed = {"births": 0, "large": 2}[name]
    for lam, recycled in _steps_with_dense_intensity(sc, tr, seed, sc.n_steps,  # noqa: B007
                                                     monkeypatch):
        np.testing.assert_array_equal(tr.undetected_intensity().dense(), lam)
        cc = tr.cell_count_distribution()
        assert isinstance(cc, CellCounts) and cc.n_cells == n
        exist = expit(tr._prior_logodds + tr._score)
        box, full = _kfnn_like_old(sc.grid, tr._m, tr._P, exist, lam)
        _dense_with_tail(cc.dense(), box, full, len(tr._m))
        tracks += len(tr._m)
    assert tracks > 0 and recycled > 0


def _truth_aided_old(tr) -> tuple[np.ndarray, np.ndarray]:
    """The truth-aided reference's former dense ``P_c(t)`` (full, and cut to the boxes)."""
    grid, K = tr._grid, len(tr._m)
    if tr._reflect:
        owner, cm, cP = reflection_images(tr._m, tr._P, grid)
    else:
        owner, cm, cP = np.arange(K), tr._m, tr._P
    means, covs = kalman.position_marginal(cm, cP)
    out = []
    for mass in (gaussian_cell_mass(grid, means, covs),
                 np.where(_in_box(grid, means, covs), gaussian_cell_mass(grid, means, covs), 0)):
        if len(owner) > K:
            mass = np.add.reduceat(mass, np.searchsorted(owner, np.arange(K)), axis=0)
        probs = mass / mass.sum(axis=1)[:, None]
        n_pending = len(tr._pending_ids)
        if n_pending:
            p = 1.0 - (1.0 - 1.0 / grid.n_cells) ** n_pending
            probs = np.concatenate([probs, np.full((1, grid.n_cells), p)])
        out.append(poisson_binomial(probs, 4))
    return out[1], out[0]


@pytest.mark.parametrize("start", ["birth", "first_detection"])
@pytest.mark.parametrize("name", ["births", "default"])
def test_truth_aided_counts_equal_the_dense_computation(name, start):
    """Images summed cell by cell in image order, renormalised, the not yet detected
    targets as the last (default) Bernoulli: the former dense computation with the
    masses cut to the boxes, to round-off (the total is summed over the box, not the
    grid), and within the tail of the uncut one. ``default`` reflects at the walls."""
    sc = _scenario(name, 25)
    tr = trackers.make("truth-aided", start=start)
    for _k, _looks in _steps(sc, tr, 1, 25):
        box, full = _truth_aided_old(tr)
        _dense_with_tail(tr.cell_count_distribution().dense(), box, full, 9 * len(tr._m),
                         rtol=1e-13)


def test_null_counts_are_one_default_row():
    cc = trackers.make("null")
    cc.reset(scenarios.get("large").model, np.random.default_rng(0))
    P = cc.cell_count_distribution()
    assert len(P.cells) == 0 and P.n_cells == 2500
    np.testing.assert_array_equal(P.dense(), np.tile([1.0, 0.0], (2500, 1)))


def _stonesoup():
    pytest.importorskip("stonesoup")


# by existence at a threshold of 0.5, so that tracks are deleted (recycled) within 30 steps
@pytest.mark.parametrize("params", [{"association": "distance"},
                                    {"association": "existence", "existence_threshold": 0.5}])
def test_ss_gnn_counts_equal_the_dense_computation(monkeypatch, params):
    _stonesoup()
    from mttbench.trackers.stonesoup.peers import track_key

    sc = _scenario("births", 30)
    tr = trackers.make("ss-gnn", **params)
    tracks = 0
    for lam, recycled in _steps_with_dense_intensity(sc, tr, 4, 30, monkeypatch):  # noqa: B007
        holding = sorted(tr._initiator.holding_tracks, key=track_key)
        m, P = tr._predicted(tr._tracks + holding)
        exist = tr._existence(tr._tracks + holding)
        box, full = _kfnn_like_old(sc.grid, m, P, exist, lam)
        _dense_with_tail(tr.cell_count_distribution().dense(), box, full, len(m))
        tracks += len(m)
    assert tracks > 0 and recycled > 0


def test_ss_gmphd_counts_equal_the_dense_computation():
    """Poisson of the components' predicted intensity per cell: the former matrix product
    summed in another order, so equal to round-off."""
    _stonesoup()
    from mttbench.trackers.stonesoup.peers import poisson_counts

    sc = _scenario("births", 30)
    tr = trackers.make("ss-gmphd")
    comps = 0
    for _k, _looks in _steps(sc, tr, 4, 30):
        m, P = kalman.predict(tr._m, tr._P, tr._F, tr._Q)
        means, covs = kalman.position_marginal(m, P)
        mass = gaussian_cell_mass(sc.grid, means, covs)
        w = tr._p_s * tr._w
        undetected = tr._undetected.dense()
        full = poisson_counts(w @ mass + undetected, 4)
        cut = np.where(_in_box(sc.grid, means, covs), mass, 0.0)
        box = poisson_counts(w @ cut + undetected, 4)
        new = tr.cell_count_distribution().dense()
        np.testing.assert_allclose(new, box, rtol=1e-12, atol=1e-300)
        assert np.abs(new - full).max() <= TAIL * max(w.sum(), 1.0)
        comps += len(w)
    assert comps > 0


# ------------------------------------------------------------------------- policies
def _reference_greedy(P: np.ndarray, pd: np.ndarray, n_looks: int, alpha: float,
                      repeats: bool, rng: np.random.Generator) -> np.ndarray:
    """The renyi rule, one look at a time over every cell (loops, no shortcuts): cells in
    the order of ``rng.permutation``; without repeats the ``n_looks`` largest ``G(1)``
    (the first in that order among equal gains); with repeats the largest marginal gain
    ``G(n + 1) - G(n)``, then the fewest looks, then the first in that order."""
    n_cells = len(P)
    perm = rng.permutation(n_cells)
    if not repeats:
        g = [float(gain_of_looks(P[c:c + 1], pd, 1, alpha)[0]) for c in perm]
        order = sorted(range(n_cells), key=lambda i: -g[i])  # stable: permuted order
        return np.sort(perm[order[:min(n_looks, n_cells)]])
    given = np.zeros(n_cells, dtype=int)
    chosen = []
    for _ in range(n_looks):
        best = None
        for i, c in enumerate(perm):
            n = given[c]
            m = float(gain_of_looks(P[c:c + 1], pd, n + 1, alpha)[0]
                       - gain_of_looks(P[c:c + 1], pd, n, alpha)[0])
            key = (-m, n, i)
            if best is None or key < best[0]:
                best = (key, c)
        chosen.append(best[1])
        given[best[1]] += 1
    return np.sort(np.array(chosen))


@pytest.mark.parametrize("repeats", [False, True])
def test_renyi_on_dense_and_small_cellcounts_chooses_as_the_rule(repeats):
    """A dense array, the same numbers as a CellCounts with default cells (a grid below
    ``DENSE_CELLS``): the same cells, and the ones the rule written out by loops picks
    with the same permutation (exact ties included: many cells share the default row)."""
    rng = np.random.default_rng(7 + repeats)
    pd = scenarios.get("default").model.sensor.detection_probability(np.arange(4))
    for trial in range(6):
        n_cells = 30
        own = np.sort(rng.choice(n_cells, 12, replace=False))
        rows = rng.dirichlet(np.full(4, 0.5), len(own))
        rows[:2] = [0.9, 0.1, 0.0, 0.0]  # own rows equal to the default one: exact ties
        cc = CellCounts(n_cells, own, rows, np.array([0.9, 0.1, 0.0, 0.0]))
        dense = cc.dense()
        n_looks = int(rng.integers(1, 20))
        for alpha in (0.5, 1.0):
            seed = 100 * trial + int(alpha * 10)
            want = _reference_greedy(dense, pd, n_looks, alpha, repeats,
                                     np.random.default_rng(seed))
            got_dense = greedy_looks(dense, pd, n_looks, alpha, repeats,
                                     np.random.default_rng(seed))
            got_cc = greedy_looks(cc, pd, n_looks, alpha, repeats, np.random.default_rng(seed))
            np.testing.assert_array_equal(got_dense, want)
            np.testing.assert_array_equal(got_cc, want)


def _total_gain(P: np.ndarray, pd: np.ndarray, cells: np.ndarray, alpha: float) -> float:
    given = np.bincount(cells, minlength=len(P))
    return float(sum(gain_of_looks(P[c:c + 1], pd, int(given[c]), alpha)[0]
                     for c in np.flatnonzero(given)))


@pytest.mark.parametrize("repeats", [False, True])
def test_sparse_renyi_gains_equal_the_dense_rule(repeats):
    """The sparse path (forced on small grids): without repeats the chosen cells' gains
    are the largest ``G(1)`` (the same multiset as the dense choice); with repeats the
    allocation's total gain is the dense greedy's (ties may pick other cells, never
    other gains)."""
    rng = np.random.default_rng(11 + repeats)
    pd = scenarios.get("default").model.sensor.detection_probability(np.arange(4))
    for _ in range(8):
        n_cells = int(rng.integers(20, 200))
        own = np.sort(rng.choice(n_cells, int(rng.integers(0, n_cells)), replace=False))
        rows = rng.dirichlet(np.full(4, 0.4), len(own))
        default = rng.dirichlet(np.full(4, 0.4))
        cc = CellCounts(n_cells, own, rows, default)
        P = cc.dense()
        L = int(rng.integers(1, 60))
        for alpha in (0.5, 1.0):
            got = greedy_looks(cc, pd, L, alpha, repeats, np.random.default_rng(1),
                               dense_cells=0)
            want = greedy_looks(P, pd, L, alpha, repeats, np.random.default_rng(1))
            assert got.dtype == np.int64 and len(got) == len(want)
            if not repeats:
                assert len(np.unique(got)) == len(got)
                g = expected_gain(P, np.stack([1 - pd, pd]), alpha)
                np.testing.assert_array_equal(np.sort(g[got]), np.sort(g[want]))
            else:
                assert _total_gain(P, pd, got, alpha) == pytest.approx(
                    _total_gain(P, pd, want, alpha), rel=1e-12, abs=1e-15)


@pytest.mark.parametrize("repeats", [False, True])
def test_sparse_renyi_draws_default_cells_uniformly(repeats):
    """Every cell with the default row (a grid above ``DENSE_CELLS``, no own rows): the
    looks go to distinct cells (equal gains: fewest looks first), uniform over the grid
    (chi-square over 20 equal bands, 300 steps of 25 looks; a correct draw fails with
    probability 1e-4)."""
    n_cells = 4 * DENSE_CELLS
    cc = CellCounts(n_cells, np.zeros(0, np.int64), np.zeros((0, 4)),
                    np.array([0.9, 0.08, 0.02, 0.0]))
    pol = make_policy("renyi", repeats=repeats)
    model = dataclasses.replace(scenarios.get("large").model, grid=Grid(n_cells // 200, 200))
    pol.reset(model, 25, np.random.default_rng(3))
    bands = np.zeros(20)
    for k in range(300):
        cells = pol.select(k, counts=cc)
        assert len(np.unique(cells)) == 25 and cells.min() >= 0 and cells.max() < n_cells
        bands += np.bincount(cells * 20 // n_cells, minlength=20)
    assert stats.chisquare(bands).pvalue > 1e-4


def _old_oracle(rng, n_cells: int, m: int, truth_cells: np.ndarray) -> np.ndarray:
    """A second oracle: the other cells listed with ``setdiff1d``."""
    m = min(m, n_cells)
    truth = np.unique(truth_cells)
    truth = truth[(truth >= 0) & (truth < n_cells)]
    if truth.size >= m:
        return np.sort(rng.choice(truth, size=m, replace=False))
    others = np.setdiff1d(np.arange(n_cells), truth, assume_unique=True)
    fill = rng.choice(others, size=m - truth.size, replace=False)
    return np.sort(np.concatenate([truth, fill]))


def test_oracle_draws_exactly_as_before():
    rng = np.random.default_rng(2)
    model = scenarios.get("default").model
    for trial in range(200):
        n_looks = int(rng.integers(1, 160))
        truth = rng.integers(-1, 144, int(rng.integers(0, 30)))
        pol = Oracle()
        pol.reset(model, n_looks, np.random.default_rng(trial))
        want = _old_oracle(np.random.default_rng(trial), 144, n_looks, truth)
        np.testing.assert_array_equal(pol.select(0, truth_cells=truth), want)


# ------------------------------------------------------------------------ simulator
def test_jumped_stream_is_numpy_generator_random():
    """Draw ``n`` of ``Generator.random`` on PCG64, from the state alone: the first
    200,000 draws, and draws around 2^40 and 2^62 (reached with ``PCG64.advance``)."""
    ss = np.random.SeedSequence(12, spawn_key=(3, 1, 7))
    bits = np.random.PCG64(ss)
    state, inc = bits.state["state"]["state"], bits.state["state"]["inc"]
    u = np.random.Generator(np.random.PCG64(ss)).random(200_000)
    idx = np.r_[0, 1, 2, 65535, 65536, 65537, np.random.default_rng(0).integers(0, 200_000, 500)]
    np.testing.assert_array_equal(pcg64_uniforms(state, inc, idx), u[idx])
    for far in (2**40 - 3, 2**62 + 12345):
        b = np.random.PCG64(ss)
        b.advance(far)
        want = np.random.Generator(b).random(5)
        np.testing.assert_array_equal(pcg64_uniforms(state, inc, far + np.arange(5)), want)


@pytest.mark.parametrize("n", [1, 7, 300])
def test_the_prefix_and_the_jumps_give_the_same_draws(n):
    """stream_uniforms draws the prefix when the largest position is small and jumps
    otherwise: both equal the jumps bit for bit, at positions on either side of the
    switch (16 per position asked for, plus 4096)."""
    ss = np.random.SeedSequence(5, spawn_key=(9,))
    bits = np.random.PCG64(ss)
    state, inc = bits.state["state"]["state"], bits.state["state"]["inc"]
    rng = np.random.default_rng(n)
    for top in (16 * n + 4096, 16 * n + 4097, 10**6):
        pos = np.r_[top - 1, rng.integers(0, top, n - 1)]
        np.testing.assert_array_equal(stream_uniforms(state, inc, pos),
                                      pcg64_uniforms(state, inc, pos))


def test_looks_count_the_targets_of_the_looked_cells_only():
    sc = scenarios.get("large")
    run = simulate(sc, 3)
    cells = np.random.default_rng(0).integers(0, sc.grid.n_cells, 400)
    for k in (0, 50, 99):
        np.testing.assert_array_equal(run.counts_in(k, cells), run.cell_counts(k)[cells])


# ------------------------------------------------------------- a 1e5 x 1e5 grid
HUGE = 100_000
#: numpy memory (tracemalloc) a few steps on the huge grid may use; one float per cell
#: would be 80 GB
HUGE_PEAK_MB = 40


def _huge(name: str = "large", n_steps: int = 3):
    return _scenario(name, n_steps, side=HUGE)


@pytest.mark.parametrize("policy", ["raster", "renyi", "random", "oracle"])
@pytest.mark.parametrize("name", ["kfnn", "truth-aided", "null"])
def test_runs_on_a_1e5_by_1e5_grid_in_little_memory(name, policy):
    """Three steps of the ``large`` preset's targets and looks on 1e10 cells, through the
    harness: every ``P_c(t)`` valid (checked without making it dense), and the numpy
    memory traced over the steps stays below :data:`HUGE_PEAK_MB`."""
    sc = _huge()
    tracemalloc.start()
    try:
        for rec in play(sc, trackers.make(name), 0, policy=make_policy(policy)):
            assert rec.looks.cells.max() < HUGE * HUGE
            if rec.counts is not None:
                _assert_count_distribution_valid(rec.counts, HUGE * HUGE, rec.k)
                assert isinstance(rec.counts, CellCounts)
                assert len(rec.counts.cells) < 10_000
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < HUGE_PEAK_MB * 2**20, f"{peak / 2**20:.1f} MB traced"


@pytest.mark.parametrize("name", ["ss-gnn", "ss-gmphd"])
def test_stonesoup_peers_run_on_a_1e5_by_1e5_grid(name):
    _stonesoup()
    sc = _huge()
    for rec in play(sc, trackers.make(name), 0, policy=make_policy("renyi")):
        _assert_count_distribution_valid(rec.counts, HUGE * HUGE, rec.k)


def test_counts_of_a_huge_grid_are_validated_without_densifying():
    """The conformance kit's check of a CellCounts over 1e10 cells: its rows only."""
    good = CellCounts(HUGE * HUGE, np.array([5, HUGE * HUGE - 1]), np.eye(3)[:2],
                      np.array([1.0, 0.0, 0.0]))
    _assert_count_distribution_valid(good, HUGE * HUGE, 0)
    bad = CellCounts(HUGE * HUGE, np.array([5]), np.array([[0.5, 0.6, -0.1]]),
                     np.array([1.0, 0.0, 0.0]))
    with pytest.raises(AssertionError, match="negative"):
        _assert_count_distribution_valid(bad, HUGE * HUGE, 0)
    assert as_cell_counts(good) is good


# ------------------------------------------------------------ KF-NN's sparse association
def _gating_instance(rng, K: int, D: int):
    pred = rng.uniform(0, 30, (K, 2))
    n = min(K, D)
    near = pred[rng.choice(K, n, replace=False)] + rng.normal(0, 0.5, (n, 2))
    z = np.concatenate([near, rng.uniform(0, 30, (D - n, 2))])
    A = rng.normal(0, 1, (K, 2, 2)) * rng.choice([0.2, 1.0, 6.0], (K, 1, 1))
    S = A @ A.transpose(0, 2, 1) + 0.05 * np.eye(2)
    return pred, S, z


def test_gated_pairs_are_the_dense_admissible_pairs():
    """Every pair of the full ``(K, D)`` array with ``d2 < gate``, the same ``d2`` bit for
    bit, row-major; a track with a non-finite mean is tried against every detection."""
    from mttbench.trackers.kfnn import gated_pairs

    rng = np.random.default_rng(4)
    for trial in range(40):
        K, D = int(rng.integers(1, 60)), int(rng.integers(1, 60))
        pred, S, z = _gating_instance(rng, K, D)
        if trial % 5 == 0:
            pred[0] = np.nan
        gate = float(rng.choice([4.6, 13.8, 18.4]))
        full = kalman.mahalanobis_sq(z[None] - pred[:, None], S[:, None])
        want_r, want_c = np.nonzero(np.isfinite(full) & (full < gate))
        rows, cols, d2 = gated_pairs(pred, S, z, gate)
        np.testing.assert_array_equal(rows, want_r)
        np.testing.assert_array_equal(cols, want_c)
        np.testing.assert_array_equal(d2, full[want_r, want_c])


@pytest.mark.parametrize("method", ["global", "greedy"])
def test_associate_pairs_equals_the_dense_association(method):
    """The same pairs as :func:`associate` on the full array (continuous costs: one
    optimum); with exactly tied costs, the same number of pairs and the same total."""
    from mttbench.trackers.kfnn import associate, associate_pairs

    rng = np.random.default_rng(8)
    for trial in range(60):
        K, D = int(rng.integers(1, 50)), int(rng.integers(1, 50))
        pred, S, z = _gating_instance(rng, K, D)
        gate = 13.8
        full = kalman.mahalanobis_sq(z[None] - pred[:, None], S[:, None])
        if trial % 3 == 0:
            full = np.round(full)  # exact ties
        rows, cols = np.nonzero(full < gate)
        got = associate_pairs(rows, cols, full[rows, cols], gate, method)
        want = associate(full, gate, method)
        if trial % 3 == 0 and method == "global":
            assert len(got[0]) == len(want[0])
            assert full[got].sum() == pytest.approx(full[want].sum(), rel=1e-12)
            assert len(np.unique(got[0])) == len(np.unique(got[1])) == len(got[0])
        else:
            np.testing.assert_array_equal(got[0], want[0])
            np.testing.assert_array_equal(got[1], want[1])


@pytest.mark.parametrize("association", ["global", "greedy"])
def test_kfnn_sparse_association_keeps_the_estimates(monkeypatch, association):
    """``large`` with the oracle's looks (25 tracks held): the pairs-only association
    (forced) and the full array give the same estimates bit for bit."""
    import mttbench.trackers.kfnn as kfnn

    sc = _scenario("large", 25)
    runs = []
    for limit in (10**9, 0):
        monkeypatch.setattr(kfnn, "DENSE_PAIRS", limit)
        tr = trackers.make("kfnn", association=association)
        runs.append([r.estimate for r in play(sc, tr, 1, policy=make_policy("oracle"))])
    for a, b in zip(*runs, strict=True):
        assert a.count == b.count and np.array_equal(a.states, b.states)
    assert max(a.count for a in runs[0]) >= 20

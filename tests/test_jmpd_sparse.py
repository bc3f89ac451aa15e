"""The JMPD family without per-cell arrays.

* :mod:`mttbench.trackers.jmpd.sparse` against brute force: :class:`CellIndex` (direct
  table and hash, crowded buckets included) against a dictionary, :func:`unique_cells`
  against ``np.unique``, :class:`CellTable` against a dense mirror.
* ``P_c(t)`` as :class:`~mttbench.trackers.cells.CellCounts`: its ``dense()`` equals, bit
  for bit, the dense computation the trackers used before (written out below as it
  was) on small grids, for ``jmpd``, ``jmpd-ip`` and ``jmpd-ap`` (with and without the
  undetected targets in ``P_c``), and ``jmpd-ap``'s per-cell undetected-target values
  equal the former dense recurrences, through the rescaling of the shares.
* The hash path (every grid forced onto it) gives the same runs as the direct table.
* A 1e5 x 1e5 grid (1e10 cells) runs with no more traced memory than a 50x50 grid.

Every comparison is exact (``np.array_equal``): the same operations on the same values.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from mttbench import scenarios
from mttbench.benchmarks.engine.policies import make_policy
from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.scenarios.simulator import simulate
from mttbench.trackers.cells import CellCounts
from mttbench.trackers.jmpd import JMPDAPTracker, JMPDIPTracker, JMPDTracker, sparse
from mttbench.trackers.jmpd.estimation import cell_count_distribution_from
from mttbench.trackers.jmpd.sparse import CellIndex, CellTable, unique_cells


# ============================================================================ sparse.py
def _brute_rows(keys: np.ndarray, cells: np.ndarray) -> np.ndarray:
    where = {int(k): i for i, k in enumerate(keys)}
    return np.array([where.get(int(c), len(keys)) for c in cells.reshape(-1)],
                    dtype=np.int64).reshape(cells.shape)


@pytest.mark.parametrize("n_keys", [0, 1, 7, 3000])
@pytest.mark.parametrize("n_cells", [900, 10**10])
def test_cell_index_equals_a_dictionary(n_keys, n_cells):
    """Both paths against a dictionary, for cells in range, the sentinel ``n_cells`` and
    beyond, int32 and int64 queries of any shape; 3000 random keys put several keys in
    some hash buckets (the crowded path runs; consecutive keys spread without any)."""
    rng = np.random.default_rng(n_keys)
    keys = np.unique(rng.integers(0, min(n_cells, 10**9), n_keys))
    queries = np.concatenate([keys, rng.integers(0, n_cells, 500), [n_cells, n_cells + 3]])
    queries = rng.permutation(queries)
    want = _brute_rows(keys, queries)
    for direct in ([True, False] if n_cells < 10**4 else [False]):
        index = CellIndex(keys, n_cells, direct=direct)
        assert index.direct == direct
        for q in (queries, queries.reshape(-1, 1)):
            assert np.array_equal(index(q), want.reshape(q.shape))
        if n_cells < 2**31:
            assert np.array_equal(index(queries.astype(np.int32)), want)
    if n_keys == 3000 and n_cells > 10**4:  # random keys: some buckets hold several
        assert CellIndex(keys, n_cells, direct=False)._crowded is not None
    # the default choice: direct only on small grids
    assert CellIndex(keys, n_cells).direct == (n_cells < sparse.DIRECT_MAX)


@pytest.mark.parametrize("n_cells", [700, 10**10])
def test_unique_cells_equals_np_unique(n_cells):
    rng = np.random.default_rng(3)
    for size, spread in [(0, 10), (1, 10), (5000, 40), (5000, 10**6), (20000, 10**9)]:
        cells = rng.integers(0, min(spread, n_cells), size)
        want = np.unique(cells)
        for direct in ([True, False] if n_cells < 10**4 else [False]):
            got = unique_cells(cells.reshape(-1, 1) if size else cells, n_cells, direct=direct)
            assert got.dtype == np.int64 and np.array_equal(got, want)


def test_cell_table_equals_a_dense_mirror():
    """Random sets (new and known cells, repeated steps) read back as a dense array."""
    rng = np.random.default_rng(5)
    n = 300
    table = CellTable(n, a=(0.25, np.float64), s=(-1, np.int64))
    a, s = np.full(n, 0.25), np.full(n, -1)
    for step in range(40):
        cells = np.unique(rng.integers(0, n, rng.integers(0, 25)))
        vals = rng.random(len(cells))
        table.set(cells, a=vals, s=step)
        a[cells], s[cells] = vals, step
        q = rng.integers(0, n, 50)
        assert np.array_equal(table.get("a", q), a[q]) and np.array_equal(table.get("s", q), s[q])
    assert np.array_equal(table.dense("a"), a) and np.array_equal(table.dense("s"), s)
    assert table.n_default == np.count_nonzero(s == -1)
    assert np.all(np.diff(table.cells) > 0)
    with pytest.raises(ValueError, match="every column"):
        table.set([1], a=0.5)


# ================================================================= P_c against dense
def _dense_pc_before(cells: np.ndarray, weights: np.ndarray, n_cells: int,
                     n_counts: int) -> np.ndarray:
    """``P_c(t)`` as a dense computation, ``(n_cells, n_counts)``: a
    bincount over every cell of the grid."""
    c = cells.T
    t_max = c.shape[0]
    rank = np.ones(c.shape, dtype=np.int64)
    for j in range(1, t_max):
        for k in range(j):
            rank[j] += c[k] == c[j]
    n_in = np.zeros(c.shape, dtype=np.int64)
    for j in range(t_max):
        for k in range(t_max):
            n_in[j] += c[k] == c[j]
    slot, particle = np.nonzero((rank == 1) & (c < n_cells))
    key = c[slot, particle] * n_counts + np.minimum(n_in[slot, particle], n_counts - 1)
    P = np.bincount(key, weights=weights[particle], minlength=n_cells * n_counts)
    P = P.reshape(n_cells, n_counts).astype(np.float64, copy=False)
    P[:, 0] = np.maximum(1.0 - P[:, 1:].sum(axis=1), 0.0)
    P /= P.sum(axis=1, keepdims=True)
    return P


def _ap_dense_pc_before(t: JMPDAPTracker) -> np.ndarray:
    """``jmpd-ap``'s ``P_c(t)`` computed densely, from the same draw
    (cached by the tracker until the next predict) and the undetected values as dense
    arrays."""
    J = t._model.grid.n_cells
    n_counts = min(t._T, 4) + 1
    P = _dense_pc_before(t._kinematic_cells(), np.full(t._N, 1.0 / t._N), J, n_counts)
    if not t.undetected_in_policy:
        return P
    remaining = np.array([t._remaining().mean()])
    u, u_step, v = (t._undetected.dense(k) for k in ("u", "u_step", "v"))
    share = v / t._v_total
    pi_init = -np.expm1(remaining[..., None] * np.log1p(-np.minimum(share, 1.0 - 1e-12)))
    gap = t._k - u_step
    if t._p_s == 1.0:
        arrivals = u + t._alpha * gap
    else:
        keep = t._p_s ** gap
        arrivals = u * keep + t._alpha * (1.0 - keep) / (1.0 - t._p_s)
    pi_arr = -np.expm1(-arrivals)
    pi = (1.0 - (1.0 - pi_init[0]) * (1.0 - pi_arr))[:, None]
    shifted = np.zeros_like(P)
    shifted[:, 1:] = P[:, :-1]
    shifted[:, -1] += P[:, -1]
    return P * (1.0 - pi) + shifted * pi


def _closed_loop(tracker, sc, steps: int, policy: str = "renyi", seed: int = 2):
    """Yield ``(k, P_c)`` of ``steps`` managed steps (``P_c`` taken before the looks,
    the policy given its dense form), after which the step's update and estimate run."""
    run = simulate(sc, seed)
    tracker.reset(sc.model, np.random.default_rng(seed))
    pol = make_policy(policy)
    pol.reset(sc.model, sc.model.sensor.looks_per_step, np.random.default_rng(seed + 1))
    for k in range(steps):
        tracker.predict()
        P = tracker.cell_count_distribution()
        assert isinstance(P, CellCounts) and P.n_cells == sc.grid.n_cells
        yield k, P
        cells = pol.select(k, counts=P.dense() if pol.uses_prediction else None)
        tracker.update(run.look(k, cells))
        tracker.estimate()


@pytest.mark.parametrize("n_cells", [50, 90_000])
def test_pc_function_equals_the_dense_computation(n_cells):
    """:func:`cell_count_distribution_from` on clustered particles (several targets per
    cell, empty slots, weights that are not equal) on a grid below and above
    ``DIRECT_MAX`` (the direct table and the hash): ``dense()`` bit for bit."""
    rng = np.random.default_rng(n_cells)
    n, t_max, n_counts = 400, 6, 4
    centre = rng.integers(0, n_cells - 10, 5)
    cells = centre[rng.integers(0, 5, (n, t_max))] + rng.integers(0, 3, (n, t_max))
    cells = np.where(rng.random((n, t_max)) < 0.75, cells, n_cells)
    w = rng.random(n)
    w /= w.sum()
    P = cell_count_distribution_from(cells, w, n_cells, n_counts)
    assert np.array_equal(P.dense(), _dense_pc_before(cells, w, n_cells, n_counts))
    assert np.array_equal(P.cells, np.unique(cells[cells < n_cells]))


@pytest.mark.parametrize("cls", [JMPDTracker, JMPDIPTracker])
@pytest.mark.parametrize("preset", ["default", "births"])
def test_jmpd_pc_equals_the_dense_computation(cls, preset):
    """``P_c(t)`` of ``jmpd`` / ``jmpd-ip`` over 15 managed steps: ``dense()`` equals the
    former dense computation bit for bit, with rows only for the occupied cells."""
    sc = scenarios.get(preset)
    tr = cls(n_particles=300, t_max=5)
    for _, P in _closed_loop(tr, sc, 15):
        p = tr._particles
        want = _dense_pc_before(p.cells().T, p.w, sc.grid.n_cells, p.t_max + 1)
        assert np.array_equal(P.dense(), want)
        occupied = np.unique(tr.cells[tr.mask])
        assert np.array_equal(P.cells, occupied)
        assert np.array_equal(P.default, np.eye(p.t_max + 1)[0])


@pytest.mark.parametrize("undetected", [True, False])
@pytest.mark.parametrize("preset", ["kreucher", "births"])
def test_ap_pc_equals_the_dense_computation(preset, undetected):
    """``jmpd-ap``'s ``P_c(t)`` over 12 managed steps equals, after ``dense()``, the former
    dense computation bit for bit; with the undetected targets the rows are those of the
    occupied cells and of the cells looked at so far, and the default row is a cell's
    never looked at (``pi > 0``)."""
    sc = scenarios.get(preset)
    tr = JMPDAPTracker(n_particles=150, undetected_in_policy=undetected)
    for k, P in _closed_loop(tr, sc, 12):
        assert np.array_equal(P.dense(), _ap_dense_pc_before(tr))
        occupied = np.unique(tr._kinematic_cells()[tr._kinematic_cells() < sc.grid.n_cells])
        own = np.union1d(occupied, tr._undetected.cells) if undetected else occupied
        assert np.array_equal(P.cells, own)
        if undetected:
            assert P.default[1] > 0.0
            assert len(tr._undetected.cells) > 0 or k == 0  # looked cells have their own
        else:
            assert np.array_equal(P.default, np.eye(P.n_counts)[0])


@pytest.mark.parametrize(("p_s", "births"), [(1.0, 0.0), (0.95, 0.2), (1.0, 0.1)])
def test_ap_undetected_values_follow_the_dense_recurrences(p_s, births):
    """The per-cell undetected values (arrival intensity ``u`` and its step, shares ``v``)
    equal the former dense arrays updated look by look (module docstring, 6), exactly,
    over 45 steps of a 6x6 grid looked at everywhere (twice at some cells): the shares'
    total falls below 1e-6 about every 20 steps and is rescaled by the dense sum."""
    grid = Grid(6, 6)
    model = TrackingModel(grid, Dynamics(wna_intensity=1e-3),
                          BirthDeath(n_random_initial=2, survival_probability=p_s,
                                     birth_rate=births),
                          RayleighGridSensor(0.5, 10.0, 40))
    tr = JMPDAPTracker(n_particles=60)
    tr.reset(model, np.random.default_rng(4))
    J, p_d, alpha = grid.n_cells, model.sensor.p_d, births / grid.n_cells
    # arrivals from step 1 on: the intensity's clock starts at step 0
    u, u_step, v, v_total = np.zeros(J), np.full(J, 0), np.full(J, 1.0 / J), 1.0
    rng = np.random.default_rng(5)
    rescaled = 0
    for _ in range(45):
        tr.predict()
        cells = np.concatenate([np.arange(J), rng.integers(0, J, 4)])
        tr.update(Looks(cells, rng.random(len(cells)) < 0.01))
        lc, n_looks = np.unique(cells, return_counts=True)
        miss = ((1.0 - p_d) / (1.0 - model.sensor.p_f)) ** n_looks  # l(0) per look
        gap = tr._k - u_step[lc]
        if p_s == 1.0:
            u[lc] = (u[lc] + alpha * gap) * miss
        else:
            keep = p_s ** gap
            u[lc] = (u[lc] * keep + alpha * (1.0 - keep) / (1.0 - p_s)) * miss
        u_step[lc] = tr._k
        v_new = v[lc] * miss
        v_total += float((v_new - v[lc]).sum())
        v[lc] = v_new
        if v_total < 1e-6:
            v /= v.sum()
            v_total = 1.0
            rescaled += 1
        for name, want in (("u", u), ("u_step", u_step), ("v", v)):
            assert np.array_equal(tr._undetected.dense(name), want), name
        assert tr._v_total == v_total
    assert rescaled >= 2
    # the diagnostic (cells never looked at summed together): the dense sum to round-off
    tr.predict()
    gap = tr._k - u_step
    keep = p_s ** gap
    arrivals = u + alpha * gap if p_s == 1.0 else u * keep + alpha * (1 - keep) / (1 - p_s)
    assert tr.undetected_mass == pytest.approx(tr._remaining().mean() + arrivals.sum(),
                                               rel=1e-12, abs=1e-15)


# ===================================================================== the hash path
def _record(make, sc, steps: int, policy: str) -> list[np.ndarray]:
    out = []
    tracker = make()
    for _, P in _closed_loop(tracker, sc, steps, policy=policy):
        out.append(P.dense())
        if hasattr(tracker, "_particles"):
            out.append(tracker._particles.w.copy())
    out.append(tracker.estimate().states)
    return out


@pytest.mark.parametrize(("name", "preset", "policy"), [
    ("jmpd", "default", "renyi"), ("jmpd-ip", "crossing", "renyi"),
    ("jmpd-ap", "kreucher", "renyi"), ("jmpd-ap", "births", "raster"),
])
def test_hash_path_gives_the_same_runs(monkeypatch, name, preset, policy):
    """Every table forced onto the hash path (as on grids of more than ``DIRECT_MAX``
    cells): ``P_c``, weights and estimates equal the direct tables' bit for bit."""
    make = {"jmpd": lambda: JMPDTracker(n_particles=300),
            "jmpd-ip": lambda: JMPDIPTracker(n_particles=300),
            "jmpd-ap": lambda: JMPDAPTracker(n_particles=150)}[name]
    sc = scenarios.get(preset)
    direct = _record(make, sc, 10, policy)
    monkeypatch.setattr(sparse, "DIRECT_MAX", 0)
    assert not CellIndex(np.arange(3), sc.grid.n_cells).direct
    hashed = _record(make, sc, 10, policy)
    assert len(direct) == len(hashed)
    for a, b in zip(direct, hashed, strict=True):
        assert np.array_equal(a, b)


# ======================================================================= a huge grid
def _huge_grid_run(make, side: int, steps: int = 4) -> tuple[CellCounts, object]:
    """Two targets (declared, near a corner) on a ``side x side`` grid, births and deaths,
    20 looks per step (the targets' cells and random ones), built without the simulator
    (whose world draws a uniform per cell)."""
    grid = Grid(side, side)
    model = TrackingModel(grid, Dynamics(wna_intensity=1e-3),
                          BirthDeath(initial_states=((10.5, 0.1, 20.5, 0.0),
                                                     (30.5, -0.1, 40.5, 0.1)),
                                     survival_probability=0.99, birth_rate=0.05,
                                     boundary="die"),
                          RayleighGridSensor(0.5, 10.0, 20))
    tracker = make()
    rng = np.random.default_rng(0)
    tracker.reset(model, np.random.default_rng(1))
    truth = np.array(model.birth_death.initial_states)
    for _ in range(steps):
        tracker.predict()
        P = tracker.cell_count_distribution()
        at = grid.cell_of(truth[:, 0], truth[:, 2])
        cells = np.concatenate([at, rng.integers(0, grid.n_cells, 18)])
        p = np.r_[np.full(2, 0.9), np.full(18, model.sensor.p_f)]
        tracker.update(Looks(cells.astype(np.int64), rng.random(20) < p))
        est = tracker.estimate()
        truth = truth @ model.dynamics.F.T
    return P, est


@pytest.mark.parametrize("name", ["jmpd", "jmpd-ip", "jmpd-ap"])
def test_huge_grid_runs_in_the_memory_of_a_small_one(name):
    """A 1e5 x 1e5 grid (1e10 cells; one byte per cell would be 10 GB): four managed
    steps trace at most twice the peak memory of the same run on 50x50 plus 1 MB (both
    well under a megabyte here), and ``P_c`` has rows for a few hundred cells."""
    make = {"jmpd": lambda: JMPDTracker(n_particles=300, t_max=4),
            "jmpd-ip": lambda: JMPDIPTracker(n_particles=300, t_max=4),
            "jmpd-ap": lambda: JMPDAPTracker(n_particles=100, init_fraction=0.5)}[name]
    for side in (50, 100_000):  # compile the kernels (int32 and int64 cells), fill caches:
        _huge_grid_run(make, side)  # a cold numba cache traces its compilation (~5 MB)
    peaks = {}
    for side in (50, 100_000):
        tracemalloc.start()
        try:
            P, est = _huge_grid_run(make, side)
            peaks[side] = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    assert peaks[100_000] <= 2 * peaks[50] + 1e6, peaks
    assert P.n_cells == 10**10 and len(P.cells) < 5000
    assert np.all(np.isfinite(P.rows)) and np.allclose(P.rows.sum(axis=1), 1.0)
    assert np.all(np.isfinite(est.states)) and 0 < est.count <= 4

"""pmb's compiled passes (``trackers/pmb/update_kernels.py``) against the numpy forms they
replace, byte for byte (so ``-0.0`` and NaN payloads count): numpy's ``maximum``,
``minimum`` and ``clip`` on special values, the cell ratios, the association marginals
(loopy graphs, iteration caps, huge and zero weights), the update (degenerate and far
Gaussians, existence 0 and 1, several rows per track), the mixture bound, the PPP's
field operations, the tracker's update from random states, and whole runs with and
without the kernels (per step a digest of every array of the tracker's state, the
estimate and the update's diagnostics). Each comparison picks the backend with
``use_backend``, the switch ``MTTBENCH_NO_NUMBA`` sets.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys

import numpy as np
import pytest

from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.policies import AllCells
from mttbench.benchmarks.engine.specs import TrackerSpec, resolve_scenarios
from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.trackers.cells import CellField
from mttbench.trackers.gpf.grid import _gl_table, position_regression
from mttbench.trackers.jmpd import use_backend
from mttbench.trackers.pmb import lbp, update
from mttbench.trackers.pmb.backend import compiled_pmb_kernels
from mttbench.trackers.pmb.tracker import COMPONENT_FLOOR, PMBTracker, reduce_rows

pytest.importorskip("mttbench.trackers.grid_kernels", reason="numba is not installed")


@pytest.fixture(scope="module")
def uk():
    """The kernels' module, loaded (they load in a thread: :mod:`.pmb.backend`); here
    they must be in before any comparison, or both sides would run numpy."""
    with use_backend("compiled"):
        assert compiled_pmb_kernels(wait=None) is not None
    from mttbench.trackers.pmb import update_kernels
    return update_kernels


def _equal(a, b) -> bool:
    if isinstance(a, tuple | list):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b, strict=True))
    a, b = np.asarray(a), np.asarray(b)
    return (a.dtype == b.dtype and a.shape == b.shape
            and np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes())


def _nan(payload: int) -> float:
    return float(np.array([payload], np.uint64).view(float)[0])


SPECIAL = np.array([0.0, -0.0, 1.0, -1.0, 1e-300, np.inf, -np.inf, _nan(0x7FF8000000000001),
                    _nan(0xFFF8000000000002), 0.5, 2.0])


def test_maximum_minimum_and_clip_follow_numpy(uk):
    """Every pair of special values (signed zeros, infinities, NaNs with payloads), in
    arrays long enough for numpy's vector loops and of one element."""
    a, b = np.meshgrid(SPECIAL, SPECIAL, indexing="ij")
    a, b = a.ravel(), b.ravel()
    for n in (1, len(a)):
        x, y = a[:n], b[:n]
        for np_f, k_f in ((np.maximum, uk._maximum), (np.minimum, uk._minimum)):
            got = np.array([k_f(float(p), float(q)) for p, q in zip(x, y, strict=True)])
            assert _equal(np_f(x, y), got)
        got = np.array([uk._clip(float(p), 0.0, 1.0) for p in x])
        assert _equal(np.clip(x, 0.0, 1.0), got)


def _sensor(rng) -> RayleighGridSensor:
    return RayleighGridSensor(p_d=float(rng.uniform(0.3, 0.9)), snr=float(rng.uniform(2, 20)))


def _ratios_both(uk, sensor, cells, returns):
    want = update.cell_ratios(sensor, cells, returns)
    U, lms, positive = uk.cell_ratios(cells, returns, *update.one_look_ratios(sensor),
                                      update.MAX_LOG)
    return want, update.CellRatios(U, lms[0], lms[1], lms[2], positive)


def test_cell_ratios_equal_the_numpy_form(uk):
    """Repeated looks, cells with only returns (150 at one cell: the log clip), none."""
    rng = np.random.default_rng(1)
    clipped = 0
    for i in range(200):
        sensor = _sensor(rng)
        cells = rng.integers(0, 30, int(rng.integers(0 if i else 1, 60)))
        returns = rng.random(len(cells)) < rng.uniform(0.0, 1.0)
        if i % 20 == 0:
            sensor = RayleighGridSensor(p_d=0.5, snr=10.0)
            cells = np.concatenate([cells, np.full(150, 7)])
            returns = np.concatenate([returns, np.ones(150, bool)])
        want, got = _ratios_both(uk, sensor, cells, returns)
        assert _equal([want.cells, want.L, want.M, want.S, want.positive],
                      [got.cells, got.L, got.M, got.S, got.positive])
        clipped += np.exp(update.MAX_LOG) in want.L
    assert clipped >= 10


def _marginals_both(uk, w0, ei, ej, w, beta, tol=lbp.LBP_TOL, max_iter=lbp.LBP_MAX_ITER):
    a = lbp.association_marginals(w0, ei, ej, w, beta, tol=tol, max_iter=max_iter)
    b = uk.association_marginals(w0, ei, ej, w, beta, tol, max_iter)
    return [a.p_missed, a.p_edge, a.p_unused, a.iterations, a.converged, a.cluster], list(b)


def test_association_marginals_equal_the_numpy_form(uk):
    """Random bipartite graphs (loops, isolated tracks and measurements, several
    clusters), weights from 0 to 1e30, iteration caps that stop before convergence, and
    the empty graph."""
    rng = np.random.default_rng(2)
    loopy = capped = 0
    for i in range(300):
        T, J = int(rng.integers(1, 9)), int(rng.integers(1, 9))
        pairs = np.argwhere(rng.random((T, J)) < rng.uniform(0.0, 0.7))
        pairs = pairs[rng.permutation(len(pairs))]  # edges in any order
        ei, ej = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
        w = np.exp(rng.uniform(-8, 4, len(ei)))
        w[rng.random(len(w)) < 0.1] = 0.0
        if i % 10 == 0 and len(w):
            w[0] = 1e30
        w0 = np.exp(rng.uniform(-3, 1, T))
        beta = 1.0 + np.exp(rng.uniform(-6, 3, J))
        max_iter = int(rng.choice([1, 3, lbp.LBP_MAX_ITER]))
        want, got = _marginals_both(uk, w0, ei, ej, w, beta, max_iter=max_iter)
        assert _equal(want[:3], got[:3]) and want[3:5] == [got[3], bool(got[4])]
        assert _equal(want[5], got[5])
        loopy += len(ei) > T + J - 1
        capped += not want[4]
    assert loopy >= 20 and capped >= 20
    want, got = _marginals_both(uk, np.ones(3), np.zeros(0, np.int64), np.zeros(0, np.int64),
                                np.zeros(0), np.full(2, 2.0))
    assert _equal(want[:3], got[:3]) and want[3:5] == [got[3], bool(got[4])]


def _states(rng, n: int, extent: float) -> tuple[np.ndarray, np.ndarray]:
    """``n`` random states and covariances: position sds from 0.02 to 6 cells, position
    and velocity correlated; some degenerate (no x variance, a singular position block,
    no position-velocity correlation) and some far outside the grid."""
    A = rng.normal(size=(n, 4, 4)) * np.exp(rng.uniform(-4.0, 1.8, (n, 1, 1)))
    P = A @ np.swapaxes(A, -1, -2) + 1e-9 * np.eye(4)
    m = np.zeros((n, 4))
    m[:, [0, 2]] = rng.uniform(-2.0, extent + 2.0, (n, 2))
    m[:, [1, 3]] = rng.normal(size=(n, 2))
    if n > 4 and rng.random() < 0.5:
        P[0, 0, :] = P[0, :, 0] = 0.0
        m[1, [0, 2]] = -50.0
        P[2, [1, 3], :] = P[2, :, [1, 3]] = 0.0
        P[3, 2, :] = P[3, :, 2] = P[3, 0, :] = P[3, :, 0] = 0.0
    return m, P


def _update_case(rng):
    """A pmb update's inputs: 1-6 tracks of 1-3 rows on a small grid, looks with repeats
    and many returns (so that tracks share detected cells), the PPP at the detections."""
    nx, ny = (int(v) for v in rng.integers(3, 10, 2))
    grid = Grid(nx, ny, float(rng.choice([1.0, 0.5, 2.0])))
    sensor = _sensor(rng)
    T = int(rng.integers(1, 7))
    n_rows = rng.integers(1, 4, T)
    own = np.repeat(np.arange(T), n_rows)
    m, P = _states(rng, len(own), nx * grid.cell_size)
    alpha = rng.random(len(own)) + 0.01
    alpha /= np.bincount(own, weights=alpha)[own]
    r = rng.uniform(0.0, 1.0, T)
    r[rng.random(T) < 0.1] = 1.0
    r[rng.random(T) < 0.1] = 0.0
    cells = rng.integers(0, nx * ny, int(rng.integers(1, 40)))
    returns = rng.random(len(cells)) < rng.uniform(0.1, 0.8)
    return grid, sensor, r, own, alpha, m, P, cells, returns


def _pmb_update_both(uk, grid, sensor, r, own, alpha, m, P, cells, returns, lam):
    want_r, ratios = _ratios_both(uk, sensor, cells, returns)
    assert _equal([want_r.cells, want_r.L, want_r.M, want_r.S, want_r.positive],
                  [ratios.cells, ratios.L, ratios.M, ratios.S, ratios.positive])
    with use_backend("numpy"), np.errstate(divide="ignore", invalid="ignore"):
        want = update.pmb_update(r, m, P, want_r, lam, grid, own=own, alpha=alpha)
        B, resid = position_regression(P)  # degenerate rows: the same inf and NaN
    got = uk.pmb_update(r, own, alpha, m, P, B, resid, ratios.cells, ratios.L, ratios.M,
                        ratios.S, ratios.positive, lam, grid.cell_size, grid.nx, grid.ny,
                        update.RANGE_SIGMAS, lbp.LBP_TOL, lbp.LBP_MAX_ITER, *_gl_table())
    mg = want.marginals
    return ([want.r, want.own, want.alpha, want.means, want.covs, want.hyp, want.meas_cells,
             want.r_new, mg.p_missed, mg.p_edge, mg.p_unused, mg.iterations, mg.converged,
             mg.cluster, want.n_pairs], list(got))


def test_pmb_update_equals_the_numpy_form(uk):
    """Every output of the update, the marginals included, on 300 random updates; edges,
    tracks sharing detected cells (more than one iteration of the messages) and source
    rows counted, so that each occurs."""
    rng = np.random.default_rng(3)
    seen = {"edges": 0, "shared": 0, "sources": 0}
    for _ in range(300):
        grid, sensor, r, own, alpha, m, P, cells, returns = _update_case(rng)
        J = len(np.unique(cells[returns]))
        lam = np.exp(rng.uniform(-8, 0, J)) * (rng.random(J) < 0.9)
        want, got = _pmb_update_both(uk, grid, sensor, r, own, alpha, m, P, cells, returns,
                                     lam)
        assert _equal(want[:11], got[:11])
        assert [want[11], want[12], want[14]] == [got[11], bool(got[12]), got[14]]
        assert _equal(want[13], got[13])
        seen["edges"] += len(want[9]) > 0
        seen["shared"] += want[11] > 1
        seen["sources"] += len(want[1]) > len(own)
    assert seen["edges"] >= 100 and seen["shared"] >= 10 and seen["sources"] >= 100


def test_pmb_update_without_rows_or_detections(uk):
    rng = np.random.default_rng(4)
    grid, sensor, r, own, alpha, m, P, cells, returns = _update_case(rng)
    J = len(np.unique(cells[returns]))
    empty = np.zeros(0, np.int64)
    want, got = _pmb_update_both(uk, grid, sensor, np.zeros(0), empty, np.zeros(0),
                                 np.zeros((0, 4)), np.zeros((0, 4, 4)), cells, returns,
                                 np.full(J, 0.01))
    assert _equal(want[:11], got[:11]) and want[14] == got[14] == 0
    no_returns = np.zeros(len(cells), bool)
    want, got = _pmb_update_both(uk, grid, sensor, r, own, alpha, m, P, cells, no_returns,
                                 np.zeros(0))
    assert _equal(want[:11], got[:11]) and len(want[9]) == 0


def test_reduce_rows_equals_the_numpy_form(uk):
    """Rows of one track truncated to the same cell (merged), weights below the floor,
    ties (equal weights: the lexsort's index order), zero weights, tracks without rows,
    more rows than ``max_components`` (1 to 4)."""
    rng = np.random.default_rng(5)
    merged = bounded = 0
    for _ in range(400):
        T = int(rng.integers(1, 6))
        R = int(rng.integers(0, 14))
        own = rng.integers(0, T, R)
        hyp = np.where(rng.random(R) < 0.4, -1, rng.integers(0, 3, R))
        a = np.round(rng.random(R), 1) * (rng.random(R) < 0.9)  # ties, zeros
        a[rng.random(R) < 0.2] = 0.01  # below the floor
        m, P = _states(rng, R, 5.0)
        mc = int(rng.integers(1, 5))
        want = reduce_rows(own, a, m, P, hyp, T, mc)
        got = uk.reduce_rows(own, a, m, P, hyp, T, mc, COMPONENT_FLOOR)
        assert _equal(list(want), list(got))
        merged += len(set(zip(own[hyp >= 0], hyp[hyp >= 0], strict=True))) < np.sum(hyp >= 0)
        bounded += np.any(np.bincount(own, minlength=T) > mc)
    assert merged >= 50 and bounded >= 50


def test_field_operations_equal_cellfield(uk):
    """``at``, ``multiply`` and ``add`` on a sparse field: new cells, cells whose value
    becomes the default again (they rejoin it), an empty operation."""
    rng = np.random.default_rng(6)
    for _ in range(300):
        n = 60
        field = CellField(n, 0.25)
        own = np.unique(rng.integers(0, n, int(rng.integers(0, 20))))
        field.set(own, rng.choice([0.5, 1.0, 0.0, 2.0], len(own)))
        cells = np.unique(rng.integers(0, n, int(rng.integers(0, 20))))
        add = bool(rng.random() < 0.5)
        ops = rng.choice([0.5, 2.0, 1.0, 0.25, -0.25, 0.0], len(cells))
        look = rng.integers(0, n, 10)
        assert _equal(field.at(look), uk.field_at(field.default, field.cells, field.values,
                                                  look))
        got = uk.field_apply(field.default, field.cells, field.values, cells, ops, add)
        (field.add if add else field.multiply)(cells, ops)
        assert _equal([field.cells, field.values], list(got))


def _model(rng) -> TrackingModel:
    nx = int(rng.integers(4, 10))
    bd = BirthDeath(n_random_initial=2, survival_probability=0.98,
                    birth_rate=float(rng.choice([0.0, 0.1])),
                    boundary=str(rng.choice(["reflect", "die"])))
    return TrackingModel(Grid(nx, nx), Dynamics(wna_intensity=1e-3), bd,
                         RayleighGridSensor(p_d=0.5, snr=10.0, looks_per_step=12))


def _tracker_state(tr: PMBTracker) -> list:
    lu = tr.last_update
    mg = lu.marginals
    f = tr.intensity
    return [tr._r, tr._own, tr._a, tr._m, tr._P, tr._tid, np.array([tr._next_tid]),
            np.array([f.default]), f.cells, f.values, lu.r, lu.own, lu.alpha, lu.means,
            lu.covs, lu.hyp, lu.meas_cells, lu.r_new, mg.p_missed, mg.p_edge, mg.p_unused,
            mg.cluster, np.array([mg.iterations, mg.converged, lu.n_pairs])]


def test_tracker_update_equals_the_numpy_form(uk):
    """Whole updates (the compiled pass, then merge and recycling) from random states:
    several steps of random looks from random tracks and a sparse PPP, at parameters that
    recycle and merge."""
    rng = np.random.default_rng(7)
    for i in range(30):
        model = _model(rng)
        params = [{}, {"recycle_threshold": 0.3, "max_tracks": 2},
                  {"merge_threshold": 9.0, "max_components": 1}][i % 3]
        states = []
        for backend in ("numpy", "compiled"):
            with use_backend(backend):
                tr = PMBTracker(**params)
                tr.reset(model, np.random.default_rng(0))
                T = int(np.random.default_rng(i).integers(1, 5))
                m, P = _states(np.random.default_rng(i), T, model.grid.nx)
                tr.set_tracks(np.random.default_rng(i).uniform(0.0, 1.0, T), m,
                              P + 0.05 * np.eye(4))
                tr.set_intensity(0.02)
                looks_rng = np.random.default_rng(100 + i)
                steps = []
                for _ in range(4):
                    tr.predict()
                    cells = looks_rng.integers(0, model.grid.n_cells, 12)
                    tr.update(Looks(cells, looks_rng.random(12) < 0.5))
                    steps.append(_tracker_state(tr) + [tr.estimate().states])
                states.append(steps)
        assert _equal(*states)


def test_estimate_equals_the_numpy_form(uk):
    """The ``round_sum`` selection: ties in existence and in row weights (index order),
    every track's heaviest row."""
    rng = np.random.default_rng(8)
    model = _model(rng)
    for _ in range(200):
        T = int(rng.integers(0, 8))
        own = np.sort(np.concatenate([np.arange(T), rng.integers(0, max(T, 1), 6)]))[
            : T + (6 if T else 0)]
        r = np.round(rng.random(T), 1)
        a = np.round(rng.random(len(own)), 1)
        m, P = _states(rng, len(own), 5.0)
        got = []
        for backend in ("numpy", "compiled"):
            with use_backend(backend):
                tr = PMBTracker()
                tr.reset(model, np.random.default_rng(0))
                tr._r, tr._own, tr._a, tr._m, tr._P = r, own, a, m, P
                tr._tid = 10 + np.arange(T)
                est = tr.estimate()
                got.append([np.array([est.count]), est.states, est.covariances, est.labels])
        assert _equal(*got)


def _digests(scenario: str, spec: str, steps: int, all_cells: bool) -> list[str]:
    out = []
    tracker = TrackerSpec.parse(spec).make()
    for k, rec in enumerate(play(resolve_scenarios([scenario])[0], tracker, 0,
                                 policy=AllCells() if all_cells else None, n_steps=steps)):
        digest = hashlib.sha256()
        arrays = [tracker._r, tracker._own, tracker._a, tracker._m, tracker._P,
                  tracker._tid, np.array([tracker._next_tid]),
                  np.array([tracker.intensity.default]), tracker.intensity.cells,
                  tracker.intensity.values, rec.estimate.states, rec.estimate.covariances,
                  rec.estimate.labels,
                  np.array([rec.estimate.count])]
        if tracker.last_update is not None and k % 5 == 0:
            arrays += _tracker_state(tracker)[10:]
        for a in arrays:
            a = np.asarray(a)
            digest.update(f"{a.dtype}{a.shape}".encode() + np.ascontiguousarray(a).tobytes())
        out.append(digest.hexdigest())
    return out


#: (scenario, tracker, steps, every cell looked at): reflecting walls (``default``),
#: clusters (``crossing``), dying walls and births (``births``), heavy clutter (the
#: envelope point ``env-pf-0.1``: many new Bernoullis, recycling), the large grid, the
#: one-Gaussian TOMB, merging, a small ``max_tracks``
RUNS = [("default", "pmb", 30, False), ("crossing", "pmb", 55, True),
        ("births", "pmb", 40, False), ("env-pf-0.1", "pmb", 25, False),
        ("large", "pmb", 10, False), ("default", "pmb:max_components=1", 20, False),
        ("crossing", "pmb:merge_threshold=4", 30, True),
        ("default", "pmb:recycle_threshold=0.2,max_tracks=2", 30, False)]


@pytest.mark.parametrize(("scenario", "spec", "steps", "all_cells"), RUNS,
                         ids=[f"{s}-{t}" for s, t, _, _ in RUNS])
def test_runs_are_identical_with_and_without_kernels(uk, scenario, spec, steps, all_cells):
    runs = []
    for backend in ("numpy", "compiled"):
        with use_backend(backend):
            runs.append(_digests(scenario, spec, steps, all_cells))
    assert runs[0] == runs[1]


def test_no_numba_runs_the_numpy_forms():
    """``MTTBENCH_NO_NUMBA=1``: pmb's kernels are not loaded, not even numba."""
    code = ("import sys; from mttbench.trackers.pmb.backend import compiled_pmb_kernels; "
            "assert compiled_pmb_kernels(wait=None) is None; assert 'numba' not in sys.modules")
    env = dict(os.environ, MTTBENCH_NO_NUMBA="1")
    subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=120)

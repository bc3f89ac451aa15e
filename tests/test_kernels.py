"""The numba kernels of ``trackers/jmpd/kernels.py`` against the numpy forms they replace.

Every comparison is exact (bit for bit): the kernels promise the same IEEE
operations in the same order, so the same seed gives the same numbers with or
without numba. The resampling and likelihood kernels are also run through the
numpy tests of ``test_jmpd.py`` (its ``backend`` fixture). Each test picks the
backend with ``use_backend``, so ``MTTBENCH_NO_NUMBA`` does not matter here.
"""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest

from mttbench import scenarios
from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.scenarios.simulator import simulate
from mttbench.trackers.jmpd import (
    JMPDTracker,
    apply_boundary,
    compiled_kernels,
    flat_cells,
    use_backend,
)

kernels = pytest.importorskip("mttbench.trackers.jmpd.kernels", reason="numba is not installed")


def _edge_values(length: float) -> list[float]:
    """Finite positions on and around the edges of ``[0, length)`` and far outside."""
    return [0.0, -0.0, length, np.nextafter(length, 0.0), np.nextafter(length, np.inf),
            -1e-300, -5e-324, np.nextafter(0.0, 1.0), 3 * length, -3 * length,
            2 * length, -length, 1e6, -1e6]


def _tracker(boundary: str, cell_size: float, nx: int = 7, ny: int = 5,
             rng: np.random.Generator | None = None) -> JMPDTracker:
    model = TrackingModel(Grid(nx, ny, cell_size), Dynamics(wna_intensity=1e-3),
                          BirthDeath(n_random_initial=2, boundary=boundary),
                          RayleighGridSensor())
    tr = JMPDTracker(n_particles=500, t_max=4)
    tr.reset(model, np.random.default_rng(3) if rng is None else rng)
    return tr


class ZeroNoise(np.random.Generator):
    """A generator whose standard normals (the process noise) are all zero."""

    def standard_normal(self, size=None, dtype=np.float64, out=None):
        if out is None:
            return np.zeros(size, dtype)
        out[...] = 0.0
        return out


@pytest.mark.parametrize("boundary", ["reflect", "die"])
@pytest.mark.parametrize("cell_size", [1.0, 0.7, 0.9])
def test_boundary_cells_counts_equals_numpy_forms(boundary, cell_size):
    """One compiled pass equals ``apply_boundary`` + ``flat_cells`` + the count of
    valid slots: states and validity bit for bit, cells and counts exactly."""
    tr = _tracker(boundary, cell_size)
    grid = Grid(7, 5, cell_size)
    width, height = grid.extent
    rng = np.random.default_rng(4)
    X = tr.states.transpose(2, 1, 0).copy()  # component-major (4, t_max, N)
    X[0] = rng.uniform(-0.5 * width, 1.5 * width, X[0].shape)
    X[2] = rng.uniform(-0.5 * height, 1.5 * height, X[2].shape)
    ex, ey = _edge_values(width), _edge_values(height)
    X[0, 0, :len(ex)] = ex
    X[2, 1, :len(ey)] = ey
    X[0, 2, :len(ex)], X[2, 2, :len(ey)] = ex, ey[::-1]  # both axes out at once
    valid = rng.random(tr.mask.T.shape) < 0.8
    X_k, valid_k = X.copy(), valid.copy()
    cells_k = np.empty(valid_k.shape, dtype=np.int32)
    counts_k = np.empty(valid_k.shape[1], dtype=np.int64)
    kernels.boundary_cells_counts(
        X_k[0], X_k[1], X_k[2], X_k[3], valid_k, width, height,
        np.nextafter(width, 0.0), np.nextafter(height, 0.0), grid.nx, grid.ny,
        1.0 / cell_size, cell_size == 1.0, boundary == "reflect", cells_k, counts_k)

    apply_boundary(X, valid, width, height, boundary == "reflect")
    cells = flat_cells(X[0], X[2], grid)
    assert np.array_equal(X_k.view(np.uint64), X.view(np.uint64))
    assert np.array_equal(valid_k, valid)
    assert np.array_equal(cells_k, cells)
    assert np.array_equal(counts_k, valid.sum(axis=0))
    # every cell is on the grid, the far edge included
    assert cells_k.min() >= 0 and cells_k.max() < grid.n_cells


def test_boundary_cells_counts_beyond_int32_cells():
    """A 100000 x 50000 grid (5e9 cells, more than int32 holds): the cells are int64, the
    compiled pass equals the numpy forms and ``Grid.cell_of`` exactly, above ``2^31``
    too."""
    grid = Grid(100_000, 50_000)
    width, height = grid.extent
    rng = np.random.default_rng(6)
    T, N = 3, 400
    X = np.empty((4, T, N))
    X[0] = rng.uniform(-0.1 * width, 1.1 * width, (T, N))
    X[2] = rng.uniform(0.9 * height, 1.1 * height, (T, N))  # rows near the top: big cells
    X[1], X[3] = rng.normal(0, 1, (T, N)), rng.normal(0, 1, (T, N))
    valid = rng.random((T, N)) < 0.8
    X_k, valid_k = X.copy(), valid.copy()
    cells_k = np.empty((T, N), dtype=np.int64)
    counts_k = np.empty(N, dtype=np.int64)
    kernels.boundary_cells_counts(
        X_k[0], X_k[1], X_k[2], X_k[3], valid_k, width, height, np.nextafter(width, 0.0),
        np.nextafter(height, 0.0), grid.nx, grid.ny, 1.0, True, True, cells_k, counts_k)
    apply_boundary(X, valid, width, height, True)
    cells = flat_cells(X[0], X[2], grid)
    assert cells.dtype == np.int64
    assert np.array_equal(X_k.view(np.uint64), X.view(np.uint64))
    assert np.array_equal(cells_k, cells) and np.array_equal(counts_k, valid.sum(axis=0))
    assert np.array_equal(cells, grid.cell_of(X[0], X[2]))
    assert cells.max() > 2**31


def test_tracker_runs_beyond_int32_cells_are_identical_with_and_without_kernels():
    """``jmpd`` on a 1e5 x 1e5 grid (int64 cells, hashed look tables), six steps of
    hand-made looks (the targets' cells and random ones): the same states, weights,
    cells, ``P_c`` and estimates with and without the kernels."""
    grid = Grid(100_000, 100_000)
    model = TrackingModel(grid, Dynamics(wna_intensity=1e-3),
                          BirthDeath(initial_states=((99_990.5, 0.1, 99_980.5, 0.0),)),
                          RayleighGridSensor())
    digests = []
    for use_kernels in (True, False):
        with use_backend("compiled" if use_kernels else "numpy"):
            tr = JMPDTracker(n_particles=400, t_max=3)
            tr.reset(model, np.random.default_rng(2))
            tr.states[:, 0] = model.birth_death.initial_states[0]
            tr.mask[:, 0] = True
            rng = np.random.default_rng(3)
            digest = hashlib.sha256()
            for _ in range(6):
                tr.predict()
                P = tr.cell_count_distribution()
                target = tr.slot_cells[0, 0]
                cells = np.concatenate([[target], rng.integers(0, grid.n_cells, 9)])
                tr.update(Looks(cells.astype(np.int64), np.r_[True, np.zeros(9, bool)]))
                est = tr.estimate()
                for a in (tr.states, tr.mask, tr.log_weights, tr.slot_cells, est.states,
                          P.cells, P.rows):
                    digest.update(np.ascontiguousarray(a).tobytes())
            assert tr.slot_cells.dtype == np.int64 and tr.slot_cells.max() > 2**31
            digests.append(digest.hexdigest())
    assert digests[0] == digests[1]


@pytest.mark.parametrize("use_kernels", [False, True])
def test_far_edge_stays_in_the_last_cell(use_kernels):
    """On ``Grid(3, 3, 0.9)``, ``nextafter(2.7, 0) * (1 / 0.9)`` rounds to 3.0: the
    index is clamped to the last column/row (it used to spill into the next row)."""
    with use_backend("compiled" if use_kernels else "numpy"):
        tr = _tracker("reflect", 0.9, nx=3, ny=3, rng=ZeroNoise(np.random.PCG64(3)))
        assert tr.uses_compiled_kernels == use_kernels
        grid = Grid(3, 3, 0.9)
        edge = np.nextafter(grid.extent[0], 0.0)
        assert int(edge * (1.0 / 0.9)) == 3  # the case this test is about
        X = tr.states
        X[..., 0] = edge
        X[..., 2] = edge
        X[..., 1] = X[..., 3] = 0.0  # stay put (the generator draws no process noise)
        tr.predict()
    X = tr.states  # the move wrote them into the other buffer
    born = X[..., 0] != edge  # births land elsewhere
    assert np.any(~born)
    assert np.all(tr.slot_cells[~born] == 8)
    assert np.array_equal(tr.slot_cells, grid.cell_of(X[..., 0], X[..., 2]))


def _run_digest(sc, use_kernels: bool, **params) -> str:
    """SHA-256 of states, validity, weights, cells and estimates over 12 steps."""
    run = simulate(sc, 1)
    with use_backend("compiled" if use_kernels else "numpy"):
        tr = JMPDTracker(n_particles=1500, t_max=4, **params)
        tr.reset(sc.model, np.random.default_rng(5))
        assert tr.uses_compiled_kernels == use_kernels
        digest = hashlib.sha256()
        n_cells = sc.grid.n_cells
        for k in range(12):
            tr.predict()
            if isinstance(sc.model.sensor, RayleighGridSensor):
                m = sc.model.sensor.looks_per_step
                looks = run.look(k, (np.arange(m) * 7 + 5 * k) % n_cells)
            else:
                looks = run.measure(k)
            tr.update(looks)
            est = tr.estimate()
            for a in (tr.states, tr.mask, tr.log_weights, tr.slot_cells, est.states):
                digest.update(np.ascontiguousarray(a).tobytes())
    assert tr.n_resamples > 0
    return digest.hexdigest()


def _edge_scenario():
    """``default`` with the ``die`` boundary and 0.9-sized cells."""
    sc = scenarios.get("default")
    model = dataclasses.replace(
        sc.model, grid=Grid(sc.grid.nx, sc.grid.ny, 0.9),
        birth_death=dataclasses.replace(sc.model.birth_death, boundary="die"))
    return dataclasses.replace(sc, model=model)


@pytest.mark.parametrize("case", [
    ("default", {}), ("default", {"proposal": "ip"}), ("crossing", {}),
    ("large", {}), ("superposition", {}), ("edges", {}),
])
def test_tracker_runs_are_identical_with_and_without_kernels(case):
    name, params = case
    sc = _edge_scenario() if name == "edges" else scenarios.get(name)
    with_kernels = _run_digest(sc, True, **params)
    without = _run_digest(sc, False, **params)
    assert with_kernels == without


def test_environment_variable_switches_the_kernels_off(monkeypatch):
    with use_backend("auto"):  # looked up afresh on the next call
        monkeypatch.setenv("MTTBENCH_NO_NUMBA", "1")
        assert compiled_kernels() is None
    with use_backend("auto"):
        monkeypatch.setenv("MTTBENCH_NO_NUMBA", "0")
        assert compiled_kernels() is kernels
    with use_backend("numpy"):
        assert compiled_kernels() is None
        with use_backend("compiled"):  # whatever the environment says
            monkeypatch.setenv("MTTBENCH_NO_NUMBA", "1")
            assert compiled_kernels() is kernels
        assert compiled_kernels() is None  # the previous choice is back

"""The numba kernels of ``trackers.kernels`` against the numpy forms they replace.

Every comparison is exact (bit for bit): the kernels promise the same IEEE
operations in the same order, so the same seed gives the same numbers with or
without numba. The resampling and likelihood kernels are also run through the
numpy tests of ``test_jmpd.py`` (its ``backend`` fixture).
"""

from __future__ import annotations

import dataclasses
import hashlib

import mttbench.trackers.jmpd as jmpd_module
import numpy as np
import pytest
from mttbench.scenarios.model import BirthDeath, Dynamics, Grid, RayleighGridSensor, TrackingModel
from mttbench.scenarios.simulator import simulate
from mttbench.trackers.jmpd import JMPDTracker

from mttbench import scenarios

kernels = pytest.importorskip("mttbench.trackers.kernels", reason="numba is not installed")


@pytest.fixture(autouse=True)
def _kernels_allowed(monkeypatch):
    """These tests choose the backend themselves, whatever MTTBENCH_NO_NUMBA says."""
    monkeypatch.delenv("MTTBENCH_NO_NUMBA", raising=False)


def _edge_values(length: float) -> list[float]:
    """Finite positions on and around the edges of ``[0, length)`` and far outside."""
    return [0.0, -0.0, length, np.nextafter(length, 0.0), np.nextafter(length, np.inf),
            -1e-300, -5e-324, np.nextafter(0.0, 1.0), 3 * length, -3 * length,
            2 * length, -length, 1e6, -1e6]


def _tracker(boundary: str, cell_size: float, nx: int = 7, ny: int = 5) -> JMPDTracker:
    model = TrackingModel(Grid(nx, ny, cell_size), Dynamics(wna_intensity=1e-3),
                          BirthDeath(n_random_initial=2, boundary=boundary),
                          RayleighGridSensor())
    tr = JMPDTracker(n_particles=500, t_max=4)
    tr.reset(model, np.random.default_rng(3))
    return tr


@pytest.mark.parametrize("boundary", ["reflect", "die"])
@pytest.mark.parametrize("cell_size", [1.0, 0.7, 0.9])
def test_boundary_cells_counts_equals_numpy_forms(boundary, cell_size, monkeypatch):
    """One compiled pass equals ``_apply_boundary`` + ``_update_cells`` + the count
    of valid slots: states and validity bit for bit, cells and counts exactly."""
    monkeypatch.setattr(jmpd_module, "_KERNELS", None)
    tr = _tracker(boundary, cell_size)
    width, height = tr._grid.extent
    rng = np.random.default_rng(4)
    X = tr._X
    X[0] = rng.uniform(-0.5 * width, 1.5 * width, X[0].shape)
    X[2] = rng.uniform(-0.5 * height, 1.5 * height, X[2].shape)
    ex, ey = _edge_values(width), _edge_values(height)
    X[0, 0, :len(ex)] = ex
    X[2, 1, :len(ey)] = ey
    X[0, 2, :len(ex)], X[2, 2, :len(ey)] = ex, ey[::-1]  # both axes out at once
    tr._valid[:] = rng.random(tr._valid.shape) < 0.8
    X_k, valid_k = X.copy(), tr._valid.copy()
    cells_k = np.empty(valid_k.shape, dtype=np.int32)
    counts_k = np.empty(valid_k.shape[1], dtype=np.int64)
    grid = tr._grid
    kernels.boundary_cells_counts(
        X_k[0], X_k[1], X_k[2], X_k[3], valid_k, width, height,
        np.nextafter(width, 0.0), np.nextafter(height, 0.0), grid.nx, grid.ny,
        1.0 / cell_size, cell_size == 1.0, boundary == "reflect", cells_k, counts_k)

    tr._apply_boundary()
    tr._update_cells()
    assert np.array_equal(X_k.view(np.uint64), tr._X.view(np.uint64))
    assert np.array_equal(valid_k, tr._valid)
    assert np.array_equal(cells_k, tr._raw_cells)
    assert np.array_equal(counts_k, tr._valid.sum(axis=0))
    # every cell is on the grid, the far edge included
    assert cells_k.min() >= 0 and cells_k.max() < grid.n_cells


@pytest.mark.parametrize("use_kernels", [False, True])
def test_far_edge_stays_in_the_last_cell(use_kernels, monkeypatch):
    """On ``Grid(3, 3, 0.9)``, ``nextafter(2.7, 0) * (1 / 0.9)`` rounds to 3.0: the
    index is clamped to the last column/row (it used to spill into the next row)."""
    if not use_kernels:
        monkeypatch.setattr(jmpd_module, "_KERNELS", None)
    tr = _tracker("reflect", 0.9, nx=3, ny=3)
    edge = np.nextafter(tr._grid.extent[0], 0.0)
    assert int(edge * (1.0 / 0.9)) == 3  # the case this test is about
    tr._X[0] = edge
    tr._X[2] = edge
    tr._X[1] = tr._X[3] = 0.0  # stay put
    tr._L[:] = 0.0
    tr._FL[:, 4:] = 0.0
    tr.predict()
    born = tr._X[0] != edge  # births land elsewhere
    assert np.all(tr._raw_cells[~born] == 8)
    assert np.array_equal(tr._raw_cells, tr._grid.cell_of(tr._X[0], tr._X[2]))


def _run_digest(sc, use_kernels: bool, monkeypatch, **params) -> str:
    """SHA-256 of states, validity, weights, cells and estimates over 12 steps."""
    monkeypatch.setattr(jmpd_module, "_KERNELS", False if use_kernels else None)
    run = simulate(sc, 1)
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
        for a in (tr.states, tr.mask, tr.log_weights, tr._raw_cells, est.states):
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
    ("default", {}), ("default", {"proposal": "ip"}), ("crossing", {"move_steps": 1}),
    ("large", {}), ("superposition", {}), ("edges", {}),
])
def test_tracker_runs_are_identical_with_and_without_kernels(case, monkeypatch):
    name, params = case
    sc = _edge_scenario() if name == "edges" else scenarios.get(name)
    with_kernels = _run_digest(sc, True, monkeypatch, **params)
    without = _run_digest(sc, False, monkeypatch, **params)
    assert with_kernels == without


def test_environment_variable_switches_the_kernels_off(monkeypatch):
    monkeypatch.setattr(jmpd_module, "_KERNELS", False)
    monkeypatch.setenv("MTTBENCH_NO_NUMBA", "1")
    assert jmpd_module.compiled_kernels() is None
    monkeypatch.setattr(jmpd_module, "_KERNELS", False)
    monkeypatch.setenv("MTTBENCH_NO_NUMBA", "0")
    assert jmpd_module.compiled_kernels() is kernels

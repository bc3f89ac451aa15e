"""JMPD-AP's compiled proposal on a grid narrower than its proposal window on one axis
only: the two axes' windows then differ in width (``wx = min(width, nx)``, ``wy =
min(width, ny)``). The reference is the numpy form of the same tracker (the kernels
promise its results bit for bit), on a grid narrow in x and on its transpose."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.trackers.jmpd import JMPDAPTracker, use_backend

pytest.importorskip("mttbench.trackers.jmpd.ap_kernels", reason="numba is not installed")


def _digest(model: TrackingModel, compiled: bool) -> str:
    grid = model.grid
    digest = hashlib.sha256()
    with use_backend("compiled" if compiled else "numpy"):
        tr = JMPDAPTracker(n_particles=200, init_fraction=0.5, position_noise_floor=1.2)
        tr.reset(model, np.random.default_rng(5))
        rng = np.random.default_rng(6)
        for _ in range(8):
            tr.predict()
            cells = rng.integers(0, grid.n_cells, 12).astype(np.int64)
            tr.update(Looks(cells, rng.random(12) < 0.3))
            est = tr.estimate()
            held = tr.valid[..., None]
            for a in (tr.valid, np.where(held, tr.pos, 0.0), est.states,
                      np.array([est.count, tr.count_mean])):
                digest.update(np.ascontiguousarray(a).tobytes())
        assert tr.uses_compiled_kernels == compiled
    return digest.hexdigest()


@pytest.mark.parametrize("nx, ny", [(3, 30), (30, 3)])
def test_windows_of_different_widths_per_axis_match_the_numpy_form(nx, ny):
    starts = ((1.5, 0.0, 0.3 * ny, 0.1), (0.4 * nx, 0.05, 2.5, 0.0)) if nx < ny else \
        ((0.3 * nx, 0.1, 1.5, 0.0), (2.5, 0.0, 0.4 * ny, 0.05))
    model = TrackingModel(Grid(nx, ny), Dynamics(wna_intensity=0.05),
                          BirthDeath(initial_states=starts), RayleighGridSensor())
    assert _digest(model, True) == _digest(model, False)

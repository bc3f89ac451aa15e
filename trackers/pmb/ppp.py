"""The Poisson point process of undetected targets, held over the cells.

Intensity ``lambda_c`` = expected number of undetected targets in cell ``c``, uniform
within the cell, stored as a :class:`~mttbench.trackers.cells.CellField` (one value shared
by every cell never touched plus the cells that differ): nothing costs ``O(cells)``.

* prior: ``lambda_c = n0 / n_cells`` (the model's initial count mean spread over the grid);
* predict (Williams 2015, the PPP prediction with a uniform Poisson birth):
  ``lambda <- p_s lambda + birth_rate / n_cells`` (no spatial diffusion: the undetected
  targets are not moved, as in the GPF's field and KF-NN's intensity; fine for slow targets);
* update: ``lambda_c <- lambda_c M_c`` in every looked cell (:mod:`.update`: the targets
  missed by its looks), nothing elsewhere (its detection probability is 0 outside the
  looked cells);
* recycling (Williams 2015, "recycling"): a Bernoulli whose existence falls below the
  tracker's ``recycle_threshold`` is moved into the PPP, ``lambda_c += r m_c`` with
  ``m_c`` its Gaussian's mass in cell ``c`` (within its 6-sd box, x-y correlation ignored:
  :func:`~mttbench.trackers.cells.gaussian_cell_mass_sparse`); its velocity is forgotten.
  So does a new Bernoulli too weak to keep (``lambda_j += r`` at its cell).
"""

from __future__ import annotations

import numpy as np

from ...scenarios.model import Grid
from .. import kalman
from ..cells import _MIN_STD_CELLS, BOX_SD, CellField, gaussian_cell_mass_sparse
from ..grid_backend import compiled_grid_kernels


def predict_intensity(field: CellField, survival: float, birth_rate: float) -> None:
    """``lambda <- survival lambda + birth_rate / n_cells`` in every cell (in place)."""
    field.affine(float(survival), float(birth_rate) / field.n_cells)


def add_intensity(field: CellField, cells: np.ndarray, amounts: np.ndarray) -> None:
    """``lambda_c += amount`` at ``cells`` (repeats summed), in place (the sums by
    :func:`..grid_kernels.cell_sums` with the compiled backend, bit for bit)."""
    cells = np.asarray(cells, dtype=np.int64).reshape(-1)
    if not len(cells):
        return
    kernels = compiled_grid_kernels()
    if kernels is not None:  # one pass instead of a sort and a bincount
        amounts = np.ascontiguousarray(amounts, dtype=float).reshape(-1)
        if len(amounts) != len(cells):  # as np.bincount refuses them
            raise ValueError(f"{len(amounts)} amounts for {len(cells)} cells")
        field.add(*kernels.cell_sums(np.ascontiguousarray(cells), amounts))
        return
    u, inv = np.unique(cells, return_inverse=True)
    field.add(u, np.bincount(inv.reshape(-1), weights=np.asarray(amounts, float).reshape(-1),
                             minlength=len(u)))


def recycle(field: CellField, grid: Grid, r: np.ndarray, m: np.ndarray, P: np.ndarray
            ) -> None:
    """Bernoullis ``r (K,)``, ``m (K, 4)``, ``P (K, 4, 4)`` into the PPP: ``lambda_c +=
    r m_c`` over each Gaussian's 6-sd box (in place; the masses by
    :func:`..grid_kernels.recycle_into_field` with the compiled backend, bit for bit)."""
    if not len(r):
        return
    kernels = compiled_grid_kernels()
    if kernels is not None:  # the same sums in one call (bit for bit)
        field.cells, field.values = kernels.recycle_into_field(
            field.default, field.cells, field.values, float(grid.cell_size), grid.nx, grid.ny,
            np.ascontiguousarray(m, float), np.ascontiguousarray(P, float),
            _MIN_STD_CELLS * grid.cell_size, float(BOX_SD), np.ascontiguousarray(r, float))
        return
    comp, cells, mass = gaussian_cell_mass_sparse(grid, *kalman.position_marginal(m, P))
    add_intensity(field, cells, r[comp] * mass)

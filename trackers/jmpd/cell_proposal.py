"""Cell-wise pieces of the measurement-directed proposal: a Gaussian's mass per cell of a
window around its mean, and draws from the Gaussian truncated to one cell.

With a diagonal predictive covariance (the Rao-Blackwellised predictive of
:mod:`.rb`) a position's law factorises over the axes, so the mass of cell
``(ix, iy)`` is ``g_x(ix) g_y(iy)`` and a draw inside the cell is one truncated normal
per axis (Morelande, Kreucher and Kastella, IEEE TSP 2007, eqs. 28-31). Everything is
computed in the lower tail (``Phi(a) - Phi(b)`` flipped to ``Phi(-b) - Phi(-a)`` when
``a > 0``), so a cell several standard deviations from the mean keeps its relative
precision.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr, ndtri


def interval_mass(mean: np.ndarray, sd: np.ndarray, lo: np.ndarray, hi: np.ndarray
                  ) -> np.ndarray:
    """``P(lo <= x < hi)`` for ``x ~ N(mean, sd^2)`` (broadcast; ``hi >= lo``)."""
    za = (lo - mean) / sd
    zb = (hi - mean) / sd
    upper = za > 0.0  # both bounds above the mean: use the mirrored lower tail
    return np.where(upper, ndtr(-za) - ndtr(-zb), ndtr(zb) - ndtr(za))


def truncated_normal(mean: np.ndarray, sd: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                     u: np.ndarray) -> np.ndarray:
    """Inverse-CDF draws of ``N(mean, sd^2)`` truncated to ``[lo, hi)`` from uniforms
    ``u`` in ``[0, 1)`` (all broadcast). An interval with no representable mass (beyond
    about 37.5 sd, where ``ndtr`` underflows) gets a uniform draw in it instead: wrong in
    shape there (the density still falls by ``e`` every ``1 / z`` sd), reached by the
    tracker only when a predictive has no mass in any cell of its window."""
    za = (lo - mean) / sd
    zb = (hi - mean) / sd
    upper = za > 0.0
    # lower-tail coordinates: [a, b] with a < b <= 0 when mirrored
    a = np.where(upper, -zb, za)
    b = np.where(upper, -za, zb)
    pa, pb = ndtr(a), ndtr(b)
    z = ndtri(pa + u * (pb - pa))
    z = np.where(upper, -z, z)
    x = mean + sd * z
    flat = ~(pb > pa) | ~np.isfinite(x)
    if flat.any():
        x = np.where(flat, lo + u * (hi - lo), x)
    # rounding may put a draw a hair outside its cell
    return np.clip(x, lo, np.nextafter(hi, lo))


def axis_window(mean: np.ndarray, sd: np.ndarray, n_cells_axis: int, cell_size: float,
                half: int, *, width: int | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masses of a window of cells around each mean along one axis.

    ``mean``, ``sd`` of any shape ``S``. By default the window is the ``2 half + 1``
    cells centred on the mean's cell (clipped to the grid); with ``width``, the
    ``width`` cells from the one holding ``mean - 4 sd`` (shifted to stay inside the
    grid), so two cells cover a narrow predictive that straddles a cell edge. Returns
    ``index (S + (w,))`` int64 (cell index along the axis, -1 outside the grid),
    ``mass (S + (w,))`` (0 outside the grid) and ``inside (S)``, the mass inside
    ``[0, n cell_size)``.
    """
    if width is None:
        first = np.clip(np.floor(mean / cell_size), 0, n_cells_axis - 1).astype(np.int64) - half
        width = 2 * half + 1
    else:
        first = np.clip(np.floor((mean - 4.0 * sd) / cell_size), 0,
                        max(n_cells_axis - width, 0)).astype(np.int64)
    index = first[..., None] + np.arange(width)
    ok = (index >= 0) & (index < n_cells_axis)
    # the normal CDF at the window's width + 1 edges, from both tails (each cell's mass
    # is then a difference in the tail that keeps its precision, as in interval_mass)
    edges = (first[..., None] + np.arange(width + 1)) * cell_size
    z = (edges - mean[..., None]) / sd[..., None]
    lower, upper = ndtr(z), ndtr(-z)
    mass = np.where(z[..., :-1] > 0.0, upper[..., :-1] - upper[..., 1:],
                    lower[..., 1:] - lower[..., :-1])
    mass = np.where(ok, mass, 0.0)
    inside = interval_mass(mean, sd, 0.0, n_cells_axis * cell_size)
    return np.where(ok, index, -1), mass, inside

"""Which form of the grid arithmetic runs: the numba kernels (:mod:`.grid_kernels`) or
the numpy forms (:mod:`.gpf.grid`, :mod:`.cells`, :mod:`.cell_evidence`).

One switch with the JMPD's (:mod:`.jmpd.backend`): numba installed, the environment
variable ``MTTBENCH_NO_NUMBA`` unset (or ``0``) and :func:`.jmpd.backend.use_backend`
not ``"numpy"``. Both forms give the same numbers bit for bit, so the choice changes
speed only; the numpy forms are the reference the tests compare against.
"""

from __future__ import annotations

from types import ModuleType

import numpy as np

from . import cells
from .jmpd.backend import compiled_kernels

_KERNELS: ModuleType | None = None
_GPF_KERNELS: ModuleType | None = None


def compiled_grid_kernels() -> ModuleType | None:
    """:mod:`.grid_kernels` (imports numba on first use and compiles or loads every
    kernel: :func:`.grid_kernels.warm_up`) when the compiled backend is on, else None.
    The trackers that use them call it in ``reset``, so that no timed step pays."""
    global _KERNELS
    if compiled_kernels() is None:
        return None
    if _KERNELS is None:
        try:
            from . import grid_kernels
        except ImportError:  # scipy without the expected C function
            return None
        grid_kernels.warm_up()
        _KERNELS = grid_kernels
    return _KERNELS


def compiled_gpf_kernels() -> ModuleType | None:
    """:mod:`.gpf.update_kernels` (the GPF's grid update in two compiled passes; compiles
    or loads them: its ``warm_up``) when the compiled backend is on, else None; the GPF
    calls it in ``reset``."""
    global _GPF_KERNELS
    if compiled_grid_kernels() is None:
        return None
    if _GPF_KERNELS is None:
        from .gpf import update_kernels
        update_kernels.warm_up()
        _GPF_KERNELS = update_kernels
    return _GPF_KERNELS


def looked_in_boxes(ix_lo: np.ndarray, ix_hi: np.ndarray, iy_lo: np.ndarray,
                    iy_hi: np.ndarray, looked: np.ndarray, nx: int, ny: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`.cells.looked_in_boxes` (the same pairs in the same order), by the kernel
    when the compiled backend is on."""
    kernels = compiled_grid_kernels()
    if kernels is None:
        return cells.looked_in_boxes(ix_lo, ix_hi, iy_lo, iy_hi, looked, nx, ny)
    return kernels.looked_in_boxes(*(np.ascontiguousarray(a, dtype=float)
                                     for a in (ix_lo, ix_hi, iy_lo, iy_hi)),
                                   np.ascontiguousarray(looked, dtype=np.int64), nx, ny)

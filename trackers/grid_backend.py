"""Which form of the grid arithmetic runs: the numba kernels (:mod:`.grid_kernels`) or
the numpy forms (:mod:`.gpf.grid`, :mod:`.cells`, :mod:`.cell_evidence`).

One switch with the JMPD's (:mod:`.jmpd.backend`): numba installed, the environment
variable ``MTTBENCH_NO_NUMBA`` unset (or ``0``) and :func:`.jmpd.backend.use_backend`
not ``"numpy"``. Both forms give the same numbers bit for bit, so the choice changes
speed only; the numpy forms are the reference the tests compare against.
"""

from __future__ import annotations

import subprocess
import sys
import threading
from types import ModuleType

import numpy as np

from . import cells
from .jmpd.backend import compiled_kernels

_KERNELS: ModuleType | None = None
_GPF_KERNELS: ModuleType | None = None
_GPF_THREAD: threading.Thread | None = None
#: how long the GPF's ``reset`` waits for its kernels (about 2 s when they are cached; a
#: compile goes on in the background meanwhile)
GPF_WAIT_S = 15.0


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


def compiled_gpf_kernels(wait: float | None = 0.0) -> ModuleType | None:
    """:mod:`.gpf.update_kernels` (the GPF's step in compiled passes) once they are
    loaded, when the compiled backend is on; else None, and the GPF runs the numpy forms,
    which give the same numbers bit for bit. The first call starts a thread that has a
    child process compile them into numba's disk cache (about 50 s of CPU after an
    install or an edit, docs/speed.md; 2 s when they are cached) and then loads them
    here (0.2 s): so a run in a fresh install is not held up by the compile, and a
    compile does not hold numba's compiler lock in this process. ``wait``: seconds to
    wait for them (None: until done). The GPF's ``reset`` waits :data:`GPF_WAIT_S`, the
    tests that compare the forms until done."""
    global _GPF_THREAD
    if compiled_grid_kernels() is None:
        return None
    if _GPF_KERNELS is None:
        if _GPF_THREAD is None:
            _GPF_THREAD = threading.Thread(target=_load_gpf_kernels, daemon=True,
                                           name="mttbench-gpf-kernels")
            _GPF_THREAD.start()
        if wait is None or wait > 0:
            _GPF_THREAD.join(wait)
    return _GPF_KERNELS


def _load_gpf_kernels() -> None:
    global _GPF_KERNELS
    # the compile in a child process (same interpreter and environment); a failure
    # leaves the numpy forms
    child = subprocess.run(
        [sys.executable, "-c", f"import {__package__}.gpf.update_kernels as k; k.warm_up()"],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        check=False)
    if child.returncode != 0:
        return
    from .gpf import update_kernels
    update_kernels.warm_up()
    _GPF_KERNELS = update_kernels


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

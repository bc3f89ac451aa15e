"""Which form of the grid arithmetic runs: the numba kernels (:mod:`.grid_kernels`) or
the numpy forms (:mod:`.gpf.grid`, :mod:`.cells`, :mod:`.cell_evidence`).

One switch with the JMPD's (:mod:`.jmpd.backend`): numba installed, the environment
variable ``MTTBENCH_NO_NUMBA`` unset (or ``0``) and :func:`.jmpd.backend.use_backend`
not ``"numpy"``. Both forms give the same numbers bit for bit, so the choice changes
speed only; the numpy forms are the reference the tests compare against.
"""

from __future__ import annotations

import importlib
import subprocess
import sys
import threading
from types import ModuleType

import numpy as np

from . import cells
from .compiled import loads_without_compiling
from .jmpd.backend import compiled_kernels

_KERNELS: ModuleType | None = None
#: how long the GPF's ``reset`` waits for its kernels (about 0.2 s when they are cached; a
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


cells.use_field_kernels(compiled_grid_kernels)


class BackgroundKernels:
    """A compiled kernels' module loaded off the caller's thread: the first :meth:`get`
    starts a thread that imports and warms the module here (0.2 s) when numba's disk
    cache holds every kernel (:func:`.compiled.loads_without_compiling`); otherwise it
    first has a child process compile them into that cache (about a minute of CPU after
    an install or an edit). So a run in a fresh install is not held up by the compile, a
    compile does not hold numba's compiler lock in this process, and a warm cache costs
    no child's imports (2-5 s of CPU in every process that runs the tracker); a failed
    compile leaves the numpy forms (same numbers)."""

    def __init__(self, module: str) -> None:
        self.module = module  # absolute name; the module has ``warm_up()``
        self._loaded: ModuleType | None = None
        self._thread: threading.Thread | None = None

    def get(self, wait: float | None = 0.0) -> ModuleType | None:
        """The module once loaded, when the compiled backend is on; else None.
        ``wait``: seconds to wait for it (None: until done)."""
        if compiled_grid_kernels() is None:
            return None
        if self._loaded is None:
            if self._thread is None:
                self._thread = threading.Thread(target=self._load, daemon=True,
                                                name=f"mttbench-{self.module}")
                self._thread.start()
            if wait is None or wait > 0:
                self._thread.join(wait)
        return self._loaded

    def _load(self) -> None:
        if not loads_without_compiling(self.module):
            child = subprocess.run(
                [sys.executable, "-c", f"import {self.module} as k; k.warm_up()"],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                check=False)
            if child.returncode != 0:
                return
        module = importlib.import_module(self.module)
        module.warm_up()
        self._loaded = module


_GPF = BackgroundKernels(f"{__package__}.gpf.update_kernels")


def compiled_gpf_kernels(wait: float | None = 0.0) -> ModuleType | None:
    """:mod:`.gpf.update_kernels` (the GPF's step in compiled passes) once loaded in the
    background (:class:`BackgroundKernels`), when the compiled backend is on; else None,
    and the GPF runs the numpy forms, which give the same numbers bit for bit. The GPF's
    ``reset`` waits :data:`GPF_WAIT_S`, the tests that compare the forms until done."""
    return _GPF.get(wait)


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

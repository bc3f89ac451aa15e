"""Which form of pmb's update runs: the compiled passes (:mod:`.update_kernels`) or the
numpy forms (:mod:`.update`, :mod:`.lbp`, :func:`.tracker.reduce_rows`), which give the
same numbers bit for bit and stay the reference.

The switch is the grid kernels' (:func:`..grid_backend.compiled_grid_kernels`: numba
installed, ``MTTBENCH_NO_NUMBA`` unset, :func:`..jmpd.backend.use_backend` not
``"numpy"``). The kernels load as the GPF's do (:func:`..grid_backend.
compiled_gpf_kernels`): a child process compiles them into numba's disk cache (about a
minute of CPU after an install or an edit, 2-5 s when they are cached: the child's
imports), then this process loads them; until then pmb runs the numpy forms.
"""

from __future__ import annotations

import subprocess
import sys
import threading
from types import ModuleType

from ..grid_backend import compiled_grid_kernels

_KERNELS: ModuleType | None = None
_THREAD: threading.Thread | None = None
#: how long pmb's ``reset`` waits for its kernels (a compile goes on in the background
#: meanwhile; the GPF's ``reset`` waits as long)
WAIT_S = 15.0


def compiled_pmb_kernels(wait: float | None = 0.0) -> ModuleType | None:
    """:mod:`.update_kernels` once loaded, when the compiled backend is on; else None
    (the numpy forms run: same numbers). The first call starts the thread that compiles
    (in a child process) and loads them; ``wait``: seconds to wait for them (None: until
    done)."""
    global _THREAD
    if compiled_grid_kernels() is None:
        return None
    if _KERNELS is None:
        if _THREAD is None:
            _THREAD = threading.Thread(target=_load, daemon=True, name="mttbench-pmb-kernels")
            _THREAD.start()
        if wait is None or wait > 0:
            _THREAD.join(wait)
    return _KERNELS


def _load() -> None:
    global _KERNELS
    # the compile in a child process (same interpreter and environment), so that it does
    # not hold numba's compiler lock here; a failure leaves the numpy forms
    child = subprocess.run(
        [sys.executable, "-c", f"import {__package__}.update_kernels as k; k.warm_up()"],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        check=False)
    if child.returncode != 0:
        return
    from . import update_kernels
    update_kernels.warm_up()
    _KERNELS = update_kernels

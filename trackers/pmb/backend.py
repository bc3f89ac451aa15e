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

from types import ModuleType

from ..grid_backend import BackgroundKernels

_PMB = BackgroundKernels(f"{__package__}.update_kernels")
#: how long pmb's ``reset`` waits for its kernels (a compile goes on in the background
#: meanwhile; the GPF's ``reset`` waits as long)
WAIT_S = 15.0


def compiled_pmb_kernels(wait: float | None = 0.0) -> ModuleType | None:
    """:mod:`.update_kernels` once loaded in the background (:class:`..grid_backend.
    BackgroundKernels`), when the compiled backend is on; else None (the numpy forms run:
    same numbers). ``wait``: seconds to wait for them (None: until done)."""
    return _PMB.get(wait)

"""Which form of the per-slot passes runs: the numba kernels or the numpy forms.

:mod:`.kernels` imports numba (about 0.5 s, plus about 2 s to load the cached kernels
on the reference machine), so it is imported on first use only, by
:func:`compiled_kernels`; the environment variable ``MTTBENCH_NO_NUMBA`` (set to
anything but ``0`` or the empty string) keeps it off. Both forms give the same numbers
bit for bit, so the choice changes speed only. :func:`use_backend` picks one for a
block of code (tests, measurements).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType
from typing import Literal

_KERNELS: ModuleType | None | bool = False  # False: not looked up yet


def compiled_kernels() -> ModuleType | None:
    """:mod:`.kernels` (numba), imported on first use; None when numba is not installed
    or ``MTTBENCH_NO_NUMBA`` is set (not ``0``). Results are the same either way: every
    kernel equals its numpy form bit for bit."""
    global _KERNELS
    if _KERNELS is False:
        if os.environ.get("MTTBENCH_NO_NUMBA", "") not in ("", "0"):
            _KERNELS = None
        else:
            try:
                from . import kernels
            except ImportError:
                _KERNELS = None
            else:
                _KERNELS = kernels
    return _KERNELS


@contextmanager
def use_backend(backend: Literal["auto", "numpy", "compiled"]) -> Iterator[None]:
    """Within the block, :func:`compiled_kernels` returns None (``"numpy"``: the numpy
    forms run), the kernels whatever ``MTTBENCH_NO_NUMBA`` says (``"compiled"``;
    ImportError without numba), or looks them up afresh on its next call (``"auto"``,
    which reads ``MTTBENCH_NO_NUMBA`` again). The previous choice is restored on exit.

    A tracker decides at ``reset`` whether its ``predict`` runs the compiled pass
    (``uses_compiled_kernels``), so reset it inside the block.
    """
    global _KERNELS
    if backend == "numpy":
        chosen: ModuleType | None | bool = None
    elif backend == "compiled":
        from . import kernels
        chosen = kernels
    elif backend == "auto":
        chosen = False
    else:
        raise ValueError(f"backend must be 'auto', 'numpy' or 'compiled', got {backend!r}")
    previous, _KERNELS = _KERNELS, chosen
    try:
        yield
    finally:
        _KERNELS = previous


def compiled_ap_kernels() -> ModuleType | None:
    """:mod:`.ap_kernels` (numba, ``jmpd-ap``'s per-particle passes) when
    :func:`compiled_kernels` is on, else None (the numpy forms run; same numbers)."""
    if compiled_kernels() is None:
        return None
    try:
        from . import ap_kernels
    except ImportError:  # scipy without the expected C functions
        return None
    return ap_kernels

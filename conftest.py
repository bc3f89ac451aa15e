"""Loaded by pytest before ``tests/`` and ``benchmarks/bench/``: numpy's elementary
functions pinned to the same code on every x86 machine the suite runs on.

Importing :mod:`mttbench` before numpy turns numpy's AVX-512 targets off
(:func:`mttbench.numpy_targets_above_avx2`; the xdist and Dask workers inherit the
variable). The tests that hold a compiled kernel to its numpy form bit for bit, and whole
runs to their digests, would otherwise compare numpy's AVX-512 ``exp`` and ``log`` with
the C library's on an AVX-512 machine, not two implementations of one computation
(docs/suite_time.md, "AVX-512"). If numpy was loaded first, pytest stops with the
variable to set.
"""

from __future__ import annotations

import pytest

import mttbench  # before numpy: it sets the variable numpy reads once


def pytest_configure(config) -> None:
    active = mttbench.numpy_dispatch_above_avx2()
    if active:
        raise pytest.UsageError(
            f"numpy dispatches to {' '.join(active)} in this process, so "
            f"the compiled kernels' bit-for-bit tests would compare different exp/log code; "
            f"start pytest with NPY_DISABLE_CPU_FEATURES="
            f"\"{mttbench.numpy_targets_above_avx2()}\" (numpy was imported before mttbench, "
            f"or the variable names other targets)")

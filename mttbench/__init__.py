"""mttbench: head-to-head benchmarks of multi-target trackers with an unknown number of targets.

The package has three layers, each a folder of the repository::

    mttbench.scenarios    model types, scenario files (TOML) and presets, the simulator
    mttbench.trackers     the Tracker interface, its registry, the trackers
    mttbench.benchmarks   engine/: jobs, the step loop, metrics, policies, executors, store;
                          app/: command line, compare, tune, reproduce, summaries, reports

and a small public face, importable from here (loaded on first use, so
``import mttbench`` stays cheap)::

    import mttbench
    scenario = mttbench.load_scenario("crossing")         # a preset name or a .toml path
    tracker = mttbench.make_tracker("gpf", epsilon=1e-3)  # a registered tracker
    jobs = mttbench.build_jobs([scenario], [mttbench.TrackerSpec("gpf")], None, None,
                               seeds=range(5))
    results = mttbench.run_sweep(jobs, "reports/mine")    # tidy table, one row per step

``mttbench.testing.check_tracker`` is the conformance kit for trackers written
elsewhere; outside packages register trackers and policies through the entry-point
groups ``mttbench.trackers`` and ``mttbench.policies``.
"""

from __future__ import annotations

import os
import sys
from importlib import import_module
from typing import Any

__version__ = "0.1.0"

def numpy_targets_above_avx2() -> str:
    """numpy's dispatch targets above AVX2, by the names of the installed numpy (from 2.4:
    X86_V4, AVX512_ICL, AVX512_SPR; before: AVX512F ... AVX512_SPR), read from its
    metadata without importing it.

    On an AVX-512 CPU numpy runs ``exp``, ``log`` and other ufuncs in its own AVX-512 code,
    which rounds differently from the C library that the compiled kernels and an AVX2
    machine's numpy use; a particle filter's resampling turns such a last bit into another
    run. So importing ``mttbench`` before numpy (the command line, its workers, the tests)
    turns them off: a seed gives the same numbers on AVX2 and AVX-512 machines, and the
    compiled kernels equal their numpy forms bit for bit on both.
    ``NPY_DISABLE_CPU_FEATURES=`` (set, empty) keeps numpy's AVX-512 code."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        major, minor = (int(x) for x in version("numpy").split(".")[:2])
    except (PackageNotFoundError, ValueError):
        major, minor = 0, 0
    if (major, minor) >= (2, 4):
        return "X86_V4 AVX512_ICL AVX512_SPR"
    return ("AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL "
            "AVX512_ICL AVX512_SPR")


def numpy_dispatch_above_avx2() -> list[str]:
    """numpy's dispatch targets above AVX2 that are active in this process (imports
    numpy): empty once :func:`numpy_targets_above_avx2` took effect, or on a CPU without
    AVX-512."""
    try:
        from numpy._core import _multiarray_umath as umath
    except ImportError:  # numpy 1.x
        from numpy.core import _multiarray_umath as umath
    return [name for name in umath.__cpu_dispatch__
            if umath.__cpu_features__.get(name) and ("AVX512" in name or name == "X86_V4")]


if "numpy" not in sys.modules and "NPY_DISABLE_CPU_FEATURES" not in os.environ:
    os.environ["NPY_DISABLE_CPU_FEATURES"] = numpy_targets_above_avx2()

#: glibc's heap as :func:`steady_heap` sets it: blocks up to 32 MiB (glibc's own ceiling
#: for its moving threshold) from the heap, whose free top goes back to the system only
#: beyond 256 MiB
HEAP_MMAP_THRESHOLD = 32 * 2**20
HEAP_TRIM_THRESHOLD = 256 * 2**20


def steady_heap() -> bool:
    """Fix glibc's allocation thresholds (``mallopt``), so that a step's temporaries
    reuse the heap instead of being mapped, unmapped or trimmed and page-faulted back every
    step. By default glibc's thresholds move with what the process freed before, so the
    same step cost up to 1.4x more CPU in a fresh process than after others, and the large
    JMPDs paid 10-45% of their CPU in page faults (docs/bench_gates.md). Returns whether it
    took effect: not outside glibc, nor when ``MALLOC_MMAP_THRESHOLD_`` or
    ``MALLOC_TRIM_THRESHOLD_`` is set (those settings are kept)."""
    if not sys.platform.startswith("linux") or any(
            name in os.environ for name in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")):
        return False
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # malloc.h
    return bool(mallopt(m_mmap_threshold, HEAP_MMAP_THRESHOLD)) and bool(
        mallopt(m_trim_threshold, HEAP_TRIM_THRESHOLD))


steady_heap()

#: public name -> (module, attribute)
_API = {
    "Tracker": ("mttbench.trackers.base", "Tracker"),
    "Estimate": ("mttbench.trackers.base", "Estimate"),
    "register": ("mttbench.trackers.base", "register"),
    "Param": ("mttbench.trackers.params", "Param"),
    "ParameterError": ("mttbench.trackers.params", "ParameterError"),
    "make_tracker": ("mttbench.trackers.base", "make"),
    "available_trackers": ("mttbench.trackers.base", "available"),
    "Scenario": ("mttbench.scenarios.spec", "Scenario"),
    "ScenarioError": ("mttbench.scenarios.spec", "ScenarioError"),
    "load_scenario": ("mttbench.scenarios.spec", "get"),
    "Looks": ("mttbench.scenarios.model", "Looks"),
    "TrackingModel": ("mttbench.scenarios.model", "TrackingModel"),
    "simulate": ("mttbench.scenarios.simulator", "simulate"),
    "Policy": ("mttbench.benchmarks.engine.policies", "Policy"),
    "register_policy": ("mttbench.benchmarks.engine.policies", "register_policy"),
    "TrackerSpec": ("mttbench.benchmarks.engine.specs", "TrackerSpec"),
    "PolicySpec": ("mttbench.benchmarks.engine.specs", "PolicySpec"),
    "Job": ("mttbench.benchmarks.engine.loop", "Job"),
    "build_jobs": ("mttbench.benchmarks.engine.loop", "build_jobs"),
    "play": ("mttbench.benchmarks.engine.loop", "play"),
    "run_job": ("mttbench.benchmarks.engine.loop", "run_job"),
    "run_sweep": ("mttbench.benchmarks.engine.sweep", "run_sweep"),
    "ConfigError": ("mttbench.benchmarks.engine.errors", "ConfigError"),
    "summarize": ("mttbench.benchmarks.app.summary", "summarize"),
}

__all__ = sorted(_API)


def __getattr__(name: str) -> Any:
    try:
        module, attr = _API[name]
    except KeyError:
        raise AttributeError(f"module 'mttbench' has no attribute {name!r}") from None
    value = getattr(import_module(module), attr)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])

"""The tracker layer's numba-compiled kernel modules, and whether their disk cache is warm.

Each module below compiles its kernels (numba, cached on disk) the first time they run in
a process and keeps them in numba's disk cache (an index ``<module>.<function>-<line>.
pyXY.nbi`` per kernel in ``__pycache__`` next to the module, or under
``NUMBA_CACHE_DIR``); a later process loads them in milliseconds. With a cold cache the
first runs of a sweep compile them, each worker process its own (about 165 s of CPU for
all of them on a 2-core x86-64 machine). ``make``'s install step pays that once, in two
processes (:func:`warm_up_in_processes`, about 105 s of wall time; ``python -m
mttbench.trackers.compiled`` does the same, with a warning from runpy, the package having
imported this module); the sweep's default wall-time limit of a run allows for it while
the cache is cold (``mttbench.benchmarks.app.resources``).

:func:`cold_modules` looks for the index files only: it imports neither numba nor the
modules, so asking costs a few file-system lookups.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import os
import sys
import tempfile
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

#: the modules with disk-cached kernels, each with a ``warm_up()`` that compiles (or
#: loads) every kernel for the argument types its callers pass
MODULES = (
    "mttbench.trackers.grid_kernels",
    "mttbench.trackers.gpf.update_kernels",
    "mttbench.trackers.jmpd.ap_kernels",
    "mttbench.trackers.jmpd.kernels",
    "mttbench.trackers.pmb.update_kernels",
)
#: disk-cached kernels that only the modules above call (compiled through their warm-up).
#: Numba checks a cached kernel against its own file only: after editing one of these,
#: delete the callers' caches too (``find trackers -name '*.nb[ic]' -delete``), or a
#: caller keeps the old helper compiled into it. The same holds for ``grid_kernels``,
#: whose kernels the GPF's and pmb's call too
HELPERS = ("mttbench.trackers.gpf.cluster_kernels", "mttbench.trackers.gpf.step_kernels",
           "mttbench.trackers.numba_exact")


def _has_index(origin: Path, cache_dir: str | None) -> bool:
    """Whether numba's disk cache holds an index for a kernel of the module at ``origin``."""
    pattern = f"{origin.stem}.*.nbi"
    if any((origin.parent / "__pycache__").glob(pattern)):
        return True
    # a cache directory of the user's: numba keeps a sub-folder per source folder there
    return bool(cache_dir) and any(Path(cache_dir).rglob(pattern))


def cold_modules(modules: tuple[str, ...] = MODULES + HELPERS) -> list[str]:
    """The modules of ``modules`` with no kernel in numba's disk cache yet (their first use
    in a process compiles them). None with ``MTTBENCH_NO_NUMBA=1`` (nothing compiles)."""
    if os.environ.get("MTTBENCH_NO_NUMBA"):
        return []
    cache_dir = os.environ.get("NUMBA_CACHE_DIR")
    cold = []
    for name in modules:
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:
            raise ModuleNotFoundError(f"no module named {name!r}")
        if not _has_index(Path(spec.origin), cache_dir):
            cold.append(name)
    return cold


def loads_without_compiling(name: str, also: tuple[str, ...] = MODULES) -> bool:
    """Whether loading the kernels of the module ``name`` (and of the modules of ``also``
    loaded in this process by then: by default every kernel module) would find each one
    compiled in numba's disk cache: every ``cache=True`` kernel has an index whose source
    stamp is its file's now (numba's SHA-256 of the source) with an entry for this
    machine's code generator and the function's bytecode now, the key numba looks up.
    Kernels inlined always are skipped (compiled only inside their callers), and so are
    the :data:`HELPERS`: a caller loaded from the cache holds their code and never asks
    for them, so a helper's stale index (its file edited, the callers not) does not make a
    load compile, and checking it would have every process compile again forever (the
    compile loads the callers from the cache and leaves the helper's index stale).
    Imports the module (and numba), compiles nothing, reads a few small files.

    An entry is per signature, so a signature no run has compiled yet is not seen: loading
    it compiles that one. False on anything unexpected (numba's private cache layout is
    read here: ``Dispatcher._cache``): the caller then compiles as if the cache were cold.
    """
    if os.environ.get("MTTBENCH_NO_NUMBA"):
        return False
    try:
        from numba.core.dispatcher import Dispatcher

        importlib.import_module(name)
        for module in [sys.modules[m] for m in (name, *also) if m in sys.modules]:
            for kernel in vars(module).values():
                if not (isinstance(kernel, Dispatcher)
                        and kernel.py_func.__module__ == module.__name__):
                    continue  # not a kernel, or another module's (checked there)
                cache_file = getattr(kernel._cache, "_cache_file", None)
                if cache_file is None or kernel.targetoptions.get("inline") == "always":
                    continue  # no disk cache asked for, or compiled only inside its callers
                codegen = kernel.targetctx.codegen()
                entries = cache_file._load_index()  # {} when absent or stale
                if not any(kernel._cache._index_key(key[0], codegen) == key for key in entries):
                    return False
        return True
    except Exception:
        return False


#: :data:`MODULES` in groups of about equal compile time with a cold cache, for
#: :func:`warm_up_in_processes` (grid and GPF kernels 105 s, JMPD and pmb 70 s of CPU on an
#: x86-64 core; docs/suite_time.md); pmb's kernels call some of the first group's, which it
#: loads when that group has cached them by then, else compiles too
WARM_UP_GROUPS = (
    ("mttbench.trackers.grid_kernels", "mttbench.trackers.gpf.update_kernels"),
    ("mttbench.trackers.jmpd.kernels", "mttbench.trackers.jmpd.ap_kernels",
     "mttbench.trackers.pmb.update_kernels"),
)


def warm_up(modules: tuple[str, ...] = MODULES) -> None:
    """Compile (or load from the disk cache) every kernel of ``modules``."""
    for name in modules:
        importlib.import_module(name).warm_up()


@contextlib.contextmanager
def serialised_cache_writes(lock_file: Path) -> Iterator[None]:
    """While open, every write of numba's disk cache in this process holds an exclusive
    ``flock`` on ``lock_file``. Numba adds an entry by reading the kernel's index, picking
    a free data-file name and writing both back: two processes adding different signatures
    of one kernel (a helper that both compile) at once could each keep the other's entry
    out of the index, or leave one entry pointing at the other's code. (numba's private
    ``IndexDataCacheFile.save``, as :func:`loads_without_compiling` reads its index.)"""
    import fcntl

    from numba.core import caching

    original = caching.IndexDataCacheFile.save

    def save(self, key, data):
        with open(lock_file, "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
            original(self, key, data)

    caching.IndexDataCacheFile.save = save
    try:
        yield
    finally:
        caching.IndexDataCacheFile.save = original


def _warm_up_serialised(modules: tuple[str, ...], lock_file: str) -> None:
    with serialised_cache_writes(Path(lock_file)):
        warm_up(modules)


def can_serialise_cache_writes() -> bool:
    """Whether :func:`serialised_cache_writes` works here: POSIX ``fcntl``, and numba's
    cache writes where this numba keeps them."""
    try:
        import fcntl  # noqa: F401

        from numba.core import caching
    except ImportError:
        return False
    return callable(getattr(getattr(caching, "IndexDataCacheFile", None), "save", None))


def warm_up_in_processes(groups: tuple[tuple[str, ...], ...] = WARM_UP_GROUPS) -> None:
    """:func:`warm_up` of each group of modules in a process of its own (fresh: ``spawn``),
    side by side, their cache writes serialised (:func:`serialised_cache_writes`). Where
    they cannot be (:func:`can_serialise_cache_writes`: not POSIX, or a numba that keeps
    its cache writes elsewhere), one group after the other in this process."""
    if not can_serialise_cache_writes():
        warm_up(tuple(name for group in groups for name in group))
        return
    with (tempfile.TemporaryDirectory(prefix="mttbench-warm-up-") as folder,
          ProcessPoolExecutor(len(groups), mp_context=get_context("spawn")) as pool):
        lock_file = str(Path(folder) / "numba-cache.lock")
        for done in [pool.submit(_warm_up_serialised, group, lock_file) for group in groups]:
            done.result()  # a group's error, raised here


if __name__ == "__main__":  # make's install step
    warm_up_in_processes()

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

Numba checks a cached kernel against its own source file only, so a kernel that calls
another module's keeps that module's code as it was when it was compiled. Every kernel
module therefore calls :func:`drop_stale_caches` on import: when the sources of the
modules others call (:data:`CALLED`) differ from those the cache was compiled with, it
deletes every cached kernel, which then compile again (once, a few minutes of CPU).
"""

from __future__ import annotations

import contextlib
import hashlib
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
#: disk-cached kernels that only the modules above call (compiled through their warm-up)
HELPERS = ("mttbench.trackers.gpf.cluster_kernels", "mttbench.trackers.gpf.step_kernels",
           "mttbench.trackers.numba_exact")
#: the modules of :data:`MODULES` and :data:`HELPERS` whose kernels another module's
#: kernels call. Numba checks a cached kernel against its own file only, so a caller
#: loaded from the cache runs these as they were when it was compiled: an edit (or a
#: ``git pull``) that changes one of them and not its callers would run the old code,
#: silently. :func:`drop_stale_caches` drops every cached kernel when their sources change
CALLED = ("mttbench.trackers.grid_kernels", "mttbench.trackers.gpf.update_kernels",
          "mttbench.trackers.jmpd.kernels", "mttbench.trackers.gpf.cluster_kernels",
          "mttbench.trackers.gpf.step_kernels", "mttbench.trackers.numba_exact")
#: the file, in the cache folder of :data:`CALLED`'s first module, holding the digest of
#: their sources when the cached kernels were compiled
STAMP_NAME = "mttbench-called-kernels.sha256"


def _has_index(origin: Path) -> bool:
    """Whether numba's disk cache holds an index for a kernel of the module at ``origin``."""
    return any(_cache_folder(origin).glob(f"{origin.stem}.*.nbi"))


def cold_modules(modules: tuple[str, ...] = MODULES + HELPERS) -> list[str]:
    """The modules of ``modules`` with no kernel in numba's disk cache yet (their first use
    in a process compiles them); every one of ours when the cache is stale (:func:
    `stale_caches`: the next import drops it). None with ``MTTBENCH_NO_NUMBA=1`` (nothing
    compiles)."""
    if os.environ.get("MTTBENCH_NO_NUMBA"):
        return []
    stale = stale_caches()  # every cached kernel of ours is dropped at the next import
    return [name for name in modules
            if (stale and name in MODULES + HELPERS) or not _has_index(_origin(name))]


def _origin(name: str) -> Path:
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None:
        raise ModuleNotFoundError(f"no module named {name!r}")
    return Path(spec.origin)


def _cache_folder(origin: Path) -> Path:
    """Where numba keeps the disk cache of the module at ``origin``: ``__pycache__``
    beside it, or under ``NUMBA_CACHE_DIR`` a folder named for the source folder (numba's
    ``_CacheLocator.get_suitable_cache_subpath``). Numba's last resort, a user-wide folder
    when neither can be written, is not looked at."""
    cache_dir = os.environ.get("NUMBA_CACHE_DIR")
    if not cache_dir:
        return origin.parent / "__pycache__"
    folder = os.path.dirname(os.path.abspath(origin))
    hashed = hashlib.sha1(folder.encode()).hexdigest()
    return Path(cache_dir) / f"{os.path.basename(folder)}_{hashed}"


def _cached_files(modules: tuple[str, ...]) -> list[Path]:
    """The index (``.nbi``) and data (``.nbc``) files of ``modules``' cached kernels."""
    files = []
    for name in modules:
        origin = _origin(name)
        files += sorted(_cache_folder(origin).glob(f"{origin.stem}.*.nb[ic]"))
    return files


def called_digest(called: tuple[str, ...] = CALLED) -> str:
    """SHA-256 over the names and sources of ``called``."""
    digest = hashlib.sha256()
    for name in called:
        digest.update(name.encode() + b"\0" + _origin(name).read_bytes() + b"\0")
    return digest.hexdigest()


def _stamp(called: tuple[str, ...]) -> Path:
    return _cache_folder(_origin(called[0])) / STAMP_NAME


def _recorded(stamp: Path, digest: str) -> bool:
    """Whether ``stamp`` holds ``digest``."""
    try:
        return stamp.read_text() == digest
    except OSError:
        return False


def stale_caches(called: tuple[str, ...] = CALLED,
                 cached: tuple[str, ...] = MODULES + HELPERS) -> bool:
    """Whether numba's disk cache holds kernels of ``cached`` compiled when the sources of
    ``called`` were other than now (or with no record of them). Reads a few files."""
    return not _recorded(_stamp(called), called_digest(called)) and bool(_cached_files(cached))


_CHECKED: set[tuple[tuple[str, ...], tuple[str, ...]]] = set()


def drop_stale_caches(called: tuple[str, ...] = CALLED,
                      cached: tuple[str, ...] = MODULES + HELPERS) -> bool:
    """Delete every cached kernel of ``cached`` when the sources of ``called`` changed
    since they were compiled (:func:`stale_caches`), and record the sources' digest; the
    next use of a kernel compiles it (a few minutes of CPU for all of them, once). Every
    kernel module calls it on import, before any kernel runs; once per process (a
    forked worker inherits its parent's check), under an exclusive ``flock`` so that two
    processes starting together drop and record once. True when it deleted files. A cache
    folder this process cannot write is left alone (numba caches elsewhere then)."""
    key = (called, cached)
    if key in _CHECKED:
        return False
    stamp, digest = _stamp(called), called_digest(called)
    dropped: list[Path] = []
    try:
        if _recorded(stamp, digest):
            _CHECKED.add(key)
            return False
        stamp.parent.mkdir(parents=True, exist_ok=True)
        with open(stamp.with_name(STAMP_NAME + ".lock"), "a") as lock:
            _lock(lock)  # released when the file closes
            if not _recorded(stamp, digest):  # another process may have dropped meanwhile
                dropped = _cached_files(cached)
                for file in dropped:
                    file.unlink(missing_ok=True)
                partial = stamp.with_name(f".{STAMP_NAME}.{os.getpid()}")
                partial.write_text(digest)
                os.replace(partial, stamp)
    except OSError:
        return False
    _CHECKED.add(key)
    return bool(dropped)


def _lock(file) -> None:
    try:
        import fcntl
    except ImportError:  # not POSIX: two processes starting together may both drop
        return
    fcntl.flock(file, fcntl.LOCK_EX)


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

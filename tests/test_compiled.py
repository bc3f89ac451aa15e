"""The compiled kernel modules' list and the disk-cache check behind the default run limit
(``mttbench.trackers.compiled``)."""

from __future__ import annotations

import fcntl
import importlib
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_packaging import import_edges

from mttbench.trackers import compiled

PACKAGE = Path(compiled.__file__).parent


def test_every_disk_cached_kernel_module_is_listed():
    """A module with ``cache=True`` kernels missing from the list would be neither warmed by
    ``make`` nor seen cold by the default run limit."""
    found = set()
    for path in PACKAGE.rglob("*.py"):
        if re.search(r"njit\([^)]*cache\s*=\s*True", path.read_text(encoding="utf-8")):
            rel = path.relative_to(PACKAGE).with_suffix("")
            found.add("mttbench.trackers." + ".".join(rel.parts))
    assert found == set(compiled.MODULES + compiled.HELPERS)
    for name in compiled.MODULES:
        assert callable(importlib.import_module(name).warm_up)


def _fake_module(tmp_path, monkeypatch, name="kern"):
    # a package name of its own per test: find_spec imports (and caches) the package
    package = "fakekernels_" + re.sub(r"\W", "_", tmp_path.name)
    pkg = tmp_path / package
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / f"{name}.py").write_text("def warm_up():\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    return pkg, f"{package}.{name}"


def test_a_module_is_cold_until_numba_indexed_one_of_its_kernels(tmp_path, monkeypatch):
    monkeypatch.delenv("MTTBENCH_NO_NUMBA", raising=False)
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    pkg, name = _fake_module(tmp_path, monkeypatch)
    assert compiled.cold_modules((name,)) == [name]
    (pkg / "__pycache__").mkdir()
    # another module's index, and this module's compiled data without its index: still cold
    (pkg / "__pycache__" / "other.f-3.py311.nbi").write_bytes(b"")
    (pkg / "__pycache__" / "kern.f-3.py311.1.nbc").write_bytes(b"")
    assert compiled.cold_modules((name,)) == [name]
    (pkg / "__pycache__" / "kern.f-3.py311.nbi").write_bytes(b"")
    assert compiled.cold_modules((name,)) == []


def test_a_users_numba_cache_dir_is_searched(tmp_path, monkeypatch):
    monkeypatch.delenv("MTTBENCH_NO_NUMBA", raising=False)
    _, name = _fake_module(tmp_path, monkeypatch)
    cache = tmp_path / "numba-cache"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache))
    assert compiled.cold_modules((name,)) == [name]
    # numba keeps a folder per source folder there, named by its own rule
    from numba.core.caching import _CacheLocator

    origin = importlib.util.find_spec(name).origin
    folder = cache / _CacheLocator.get_suitable_cache_subpath(origin)
    (cache / "elsewhere").mkdir(parents=True)
    (cache / "elsewhere" / "kern.g-9.py311.nbi").write_bytes(b"")  # another project's
    assert compiled.cold_modules((name,)) == [name]
    folder.mkdir(parents=True)
    (folder / "kern.g-9.py311.nbi").write_bytes(b"")
    assert compiled.cold_modules((name,)) == []


def test_without_numba_nothing_is_cold(tmp_path, monkeypatch):
    _, name = _fake_module(tmp_path, monkeypatch)
    monkeypatch.setenv("MTTBENCH_NO_NUMBA", "1")
    assert compiled.cold_modules((name,)) == []


def test_after_warm_up_no_module_is_cold(monkeypatch):
    """The install's warm-up (``compiled.warm_up()``, run by ``make``)
    leaves every listed module indexed in the disk cache."""
    monkeypatch.delenv("MTTBENCH_NO_NUMBA", raising=False)
    compiled.warm_up()
    assert compiled.cold_modules() == []


def test_the_warm_up_groups_hold_every_module_once():
    grouped = [name for group in compiled.WARM_UP_GROUPS for name in group]
    assert sorted(grouped) == sorted(compiled.MODULES)


@pytest.mark.parametrize("missing", ["no.such.module", "nosuchmodule_mttbench"])
def test_a_listed_module_that_does_not_exist_is_an_error(missing):
    with pytest.raises(ModuleNotFoundError):
        compiled.cold_modules((missing,))


KERNELS_SOURCE = """
from numba import njit


@njit(cache=True)
def double(x):
    return 2.0 * x


@njit(cache=True)
def triple(x):
    return 3.0 * x


@njit(cache=True, inline="always")
def inlined(x):
    return x + 1.0


@njit
def uncached(x):
    return x - 1.0


def warm_up():
    double(1.0)
    triple(1.0)
"""


def _kernel_module(tmp_path, monkeypatch):
    monkeypatch.delenv("MTTBENCH_NO_NUMBA", raising=False)
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    pkg, name = _fake_module(tmp_path, monkeypatch)
    (pkg / "kern.py").write_text(KERNELS_SOURCE)
    return pkg, name


def test_loads_without_compiling_only_when_every_cached_kernel_is_in_the_cache(tmp_path,
                                                                              monkeypatch):
    """Numba's own cache lookup decides: no index, one kernel of two compiled, or a source
    edited after the compile (a stale stamp) all mean a load would compile."""
    pkg, name = _kernel_module(tmp_path, monkeypatch)
    assert not compiled.loads_without_compiling(name, also=())
    module = importlib.import_module(name)
    module.double(1.0)  # one of the two cached kernels compiled and written to the cache
    assert not compiled.loads_without_compiling(name, also=())
    module.triple(1.0)  # both: the inlined one and the uncached one do not count
    assert compiled.loads_without_compiling(name, also=())
    assert not compiled.cold_modules((name,))
    # the same source again (a new process would see the same stamp): still in the cache
    importlib.reload(module)
    assert compiled.loads_without_compiling(name, also=())
    # an edit after the compile: numba's stamp no longer matches, so every kernel recompiles
    (pkg / "kern.py").write_text(KERNELS_SOURCE + "\n# edited\n")
    importlib.reload(module)
    assert not compiled.loads_without_compiling(name, also=())
    module.warm_up()
    assert compiled.loads_without_compiling(name, also=())
    # the modules of ``also`` loaded in the process count too
    second = tmp_path / f"{tmp_path.name}_second"
    second.mkdir()
    other_pkg, other = _fake_module(second, monkeypatch, name="other")
    (other_pkg / "other.py").write_text(KERNELS_SOURCE)
    importlib.import_module(other)
    assert not compiled.loads_without_compiling(name, also=(other,))
    assert compiled.loads_without_compiling(name, also=(other + "_not_loaded",))


HELPER_SOURCE = """
from numba import njit


@njit(cache=True)
def halve(x):
    return 0.5 * x
"""

CALLER_SOURCE = """
from numba import njit

from .helper import halve


@njit(cache=True)
def quarter(x):
    return halve(halve(x))


def warm_up():
    quarter(1.0)
"""


def _helper_and_caller(pkg: Path, name: str) -> tuple[str, str]:
    """A helper kernel module and its caller beside the kernel module ``name``: their
    names."""
    (pkg / "helper.py").write_text(HELPER_SOURCE)
    (pkg / "caller.py").write_text(CALLER_SOURCE)
    return name.replace(".kern", ".helper"), name.replace(".kern", ".caller")


def test_a_helpers_stale_index_does_not_make_its_callers_load_compile(tmp_path, monkeypatch):
    """A helper kernel called only from other kernels: once its file is edited its own
    index is stale, but its caller loads from the cache without it (the caller's code holds
    the helper's), so the check of the caller (with the helpers left out, as by default)
    says no compile, and a load indeed compiles nothing."""
    pkg, name = _kernel_module(tmp_path, monkeypatch)
    helper_name, caller_name = _helper_and_caller(pkg, name)
    importlib.import_module(caller_name).warm_up()  # both compiled into the cache
    (pkg / "helper.py").write_text(HELPER_SOURCE + "\n# edited\n")
    helper = importlib.reload(importlib.import_module(helper_name))
    caller = importlib.reload(importlib.import_module(caller_name))
    assert not compiled.loads_without_compiling(helper_name, also=())  # stale
    assert compiled.loads_without_compiling(caller_name, also=())
    assert compiled.loads_without_compiling.__defaults__ == (compiled.MODULES,)
    assert caller.quarter(8.0) == 2.0
    assert caller.quarter.stats.cache_hits and not caller.quarter.stats.cache_misses
    assert not helper.halve.signatures  # the helper was not compiled for the load


@pytest.mark.parametrize("cache_dir", [False, True], ids=["in-tree", "NUMBA_CACHE_DIR"])
def test_a_callers_cache_is_dropped_when_a_module_it_calls_changes(tmp_path, monkeypatch,
                                                                   cache_dir):
    """Numba loads a caller compiled with the old helper after the helper's file changed
    (the first half shows it, so the second can fail); :func:`compiled.drop_stale_caches`
    deletes the cache then, and only then, and the caller runs the new helper."""
    pkg, name = _kernel_module(tmp_path, monkeypatch)
    from numba.core import config

    folder = str(tmp_path / "numba-cache") if cache_dir else ""
    if cache_dir:
        monkeypatch.setenv("NUMBA_CACHE_DIR", folder)
    monkeypatch.setattr(config, "CACHE_DIR", folder)  # numba read the environment on import
    helper_name, caller_name = _helper_and_caller(pkg, name)
    called, cached = (helper_name,), (helper_name, caller_name)

    def fresh_process(check: bool):
        """The helper and caller imported anew, after the check a kernel module makes."""
        monkeypatch.setattr(compiled, "_CHECKED", set())
        dropped = compiled.drop_stale_caches(called, cached) if check else None
        importlib.reload(importlib.import_module(helper_name))
        return dropped, importlib.reload(importlib.import_module(caller_name))

    dropped, caller = fresh_process(check=True)
    assert dropped is False and caller.quarter(8.0) == 2.0  # compiled, cached, stamped
    files = compiled._cached_files(cached)
    assert {f.name.split(".")[0] for f in files} == {"helper", "caller"}  # numba's folder
    assert not compiled.stale_caches(called, cached)
    mtimes = {f: f.stat().st_mtime_ns for f in files}
    dropped, caller = fresh_process(check=True)
    assert dropped is False and caller.quarter(8.0) == 2.0
    assert caller.quarter.stats.cache_hits  # loaded, not compiled: the cache was kept
    assert {f: f.stat().st_mtime_ns for f in files} == mtimes

    (pkg / "helper.py").write_text(HELPER_SOURCE.replace("0.5 * x", "0.25 * x"))
    assert compiled.stale_caches(called, cached)
    _, caller = fresh_process(check=False)
    assert caller.quarter(8.0) == 2.0  # numba alone: the old helper, silently
    dropped, caller = fresh_process(check=True)
    assert dropped is True and caller.quarter(8.0) == 0.5  # the new one
    assert not caller.quarter.stats.cache_hits
    assert not compiled.stale_caches(called, cached)
    dropped, caller = fresh_process(check=True)
    assert dropped is False and caller.quarter(8.0) == 0.5 and caller.quarter.stats.cache_hits


def test_a_cache_without_a_record_of_its_sources_is_stale(tmp_path, monkeypatch):
    """Kernels cached before the digest was recorded (an older checkout) may hold any
    version of the modules they call: stale, and cold to the default run limit."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("MTTBENCH_NO_NUMBA", raising=False)
    ours = compiled.MODULES + compiled.HELPERS
    assert not compiled.stale_caches() and compiled.cold_modules() == list(ours)
    origin = Path(importlib.util.find_spec(compiled.MODULES[0]).origin)
    folder = compiled._cache_folder(origin)
    folder.mkdir(parents=True)
    (folder / f"{origin.stem}.f-3.py311.nbi").write_bytes(b"")
    assert compiled.stale_caches() and compiled.cold_modules() == list(ours)
    (folder / compiled.STAMP_NAME).write_text(compiled.called_digest())
    assert not compiled.stale_caches()
    assert compiled.cold_modules() == [m for m in ours if m != compiled.MODULES[0]]
    (folder / compiled.STAMP_NAME).write_text(compiled.called_digest()[::-1])
    assert compiled.stale_caches()


def test_called_holds_every_kernel_module_another_kernel_module_imports():
    ours = set(compiled.MODULES + compiled.HELPERS)
    called = set()
    for name in ours:
        origin = Path(importlib.util.find_spec(name).origin)
        called |= (import_edges(name, origin, ours) & ours) - {name}
    assert called == set(compiled.CALLED)


def test_every_kernel_module_drops_stale_caches_on_import():
    """Each kernel module asks before any of its kernels can load (a fresh process, the
    check replaced by one that records who asked)."""
    code = (
        "import sys\n"
        "from mttbench.trackers import compiled\n"
        "asked = set()\n"
        "compiled.drop_stale_caches = lambda: asked.add(sys._getframe(1).f_globals['__name__'])\n"
        f"for name in {compiled.MODULES + compiled.HELPERS!r}:\n"
        "    __import__(name)\n"
        "print(sorted(asked))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == repr(sorted(compiled.MODULES + compiled.HELPERS))


def test_loads_without_compiling_is_false_without_numba(tmp_path, monkeypatch):
    _, name = _kernel_module(tmp_path, monkeypatch)
    importlib.import_module(name).warm_up()
    assert compiled.loads_without_compiling(name, also=())
    monkeypatch.setenv("MTTBENCH_NO_NUMBA", "1")
    assert not compiled.loads_without_compiling(name, also=())


def test_background_kernels_start_no_child_when_the_cache_holds_them(tmp_path, monkeypatch):
    """A warm cache is loaded in this process (the child's imports cost seconds of CPU in
    every process that runs the GPF or pmb); a cold one is compiled by a child first."""
    from mttbench.trackers import grid_backend

    if grid_backend.compiled_grid_kernels() is None:
        pytest.skip("the compiled backend is off")
    _, name = _kernel_module(tmp_path, monkeypatch)
    children = []

    def child(args, **kwargs):
        children.append(args)
        importlib.import_module(name).warm_up()  # what the child would leave in the cache
        return grid_backend.subprocess.CompletedProcess(args, 0)

    monkeypatch.setattr(grid_backend.subprocess, "run", child)
    # the fake module alone (the checkout's kernel modules may be stale after an edit)
    monkeypatch.setattr(grid_backend, "loads_without_compiling",
                        lambda module: compiled.loads_without_compiling(module, also=()))
    cold = grid_backend.BackgroundKernels(name)
    assert cold.get(wait=None) is importlib.import_module(name)
    assert len(children) == 1 and children[0][-1] == f"import {name} as k; k.warm_up()"
    warm = grid_backend.BackgroundKernels(name)
    assert warm.get(wait=None) is importlib.import_module(name)
    assert len(children) == 1


def test_warm_up_in_processes_caches_every_group_and_raises_a_groups_error(tmp_path,
                                                                          monkeypatch):
    """Each group compiled in a child process of its own: this process then finds every
    kernel in the cache; a group that fails raises its error here."""
    pkg, name = _kernel_module(tmp_path, monkeypatch)
    _, caller = _helper_and_caller(pkg, name)
    (pkg / "broken.py").write_text("def warm_up():\n    raise RuntimeError('no compiler')\n")
    broken = name.replace(".kern", ".broken")
    assert not compiled.loads_without_compiling(name, also=())
    compiled.warm_up_in_processes(((name,), (caller,)))
    assert compiled.loads_without_compiling(name, also=())
    assert compiled.loads_without_compiling(caller, also=())
    with pytest.raises(RuntimeError, match="no compiler"):
        compiled.warm_up_in_processes(((name,), (broken,)))


def test_a_numba_without_its_cache_writes_where_expected_cannot_serialise(monkeypatch):
    from numba.core import caching

    assert compiled.can_serialise_cache_writes()
    monkeypatch.delattr(caching.IndexDataCacheFile, "save")
    assert not compiled.can_serialise_cache_writes()


def test_without_serialised_writes_the_groups_warm_up_here_one_after_the_other(tmp_path,
                                                                               monkeypatch):
    """(Not POSIX, or a numba that keeps its cache writes elsewhere.) No process is
    started: every group's kernels are compiled in this process."""
    pkg, name = _kernel_module(tmp_path, monkeypatch)
    _, caller = _helper_and_caller(pkg, name)

    def no_pool(*args, **kwargs):
        raise AssertionError("a process pool was started")

    monkeypatch.setattr(compiled, "can_serialise_cache_writes", lambda: False)
    monkeypatch.setattr(compiled, "ProcessPoolExecutor", no_pool)
    compiled.warm_up_in_processes(((name,), (caller,)))
    assert importlib.import_module(name).double.signatures
    assert importlib.import_module(caller).quarter.signatures


SERIALISED_CHILD = """
import fcntl
import importlib
import sys
from pathlib import Path

real_flock = fcntl.flock


def flock(file, operation):
    print("locking", flush=True)  # the kernel is compiled; its cache write waits here
    real_flock(file, operation)


fcntl.flock = flock
from mttbench.trackers import compiled

kern = importlib.import_module(sys.argv[1])
with compiled.serialised_cache_writes(Path(sys.argv[2])):
    kern.double(1.0)
print("saved", flush=True)
"""


def test_a_serialised_cache_write_waits_for_the_lock(tmp_path, monkeypatch):
    """While another process holds the lock, a compiled kernel is not written to the cache;
    once it is released, it is."""
    pkg, name = _kernel_module(tmp_path, monkeypatch)
    lock_file = tmp_path / "numba-cache.lock"
    env = {**os.environ,
           "PYTHONPATH": os.pathsep.join(filter(None, [str(tmp_path),
                                                       os.environ.get("PYTHONPATH")]))}
    written = lambda: list((pkg / "__pycache__").glob("kern.double-*.nbi"))  # noqa: E731
    with open(lock_file, "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        child = subprocess.Popen([sys.executable, "-c", SERIALISED_CHILD, name, str(lock_file)],
                                 env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 text=True)
        line = child.stdout.readline()
        assert line == "locking\n", child.communicate(timeout=60)
        time.sleep(0.2)  # time to write, were it not waiting
        assert child.poll() is None and not written()
    out, err = child.communicate(timeout=120)  # the lock released with the file
    assert child.returncode == 0 and out == "saved\n", err
    assert written()

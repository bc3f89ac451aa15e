"""The compiled kernel modules' list and the disk-cache check behind the default run limit
(``mttbench.trackers.compiled``)."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

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
    (cache / "fakekernels_abc").mkdir(parents=True)
    (cache / "fakekernels_abc" / "kern.g-9.py311.nbi").write_bytes(b"")
    assert compiled.cold_modules((name,)) == []


def test_without_numba_nothing_is_cold(tmp_path, monkeypatch):
    _, name = _fake_module(tmp_path, monkeypatch)
    monkeypatch.setenv("MTTBENCH_NO_NUMBA", "1")
    assert compiled.cold_modules((name,)) == []


def test_after_warm_up_no_module_is_cold(monkeypatch):
    """The install's warm-up (``python -m mttbench.trackers.compiled``, run by ``make``)
    leaves every listed module indexed in the disk cache."""
    monkeypatch.delenv("MTTBENCH_NO_NUMBA", raising=False)
    compiled.warm_up()
    assert compiled.cold_modules() == []


@pytest.mark.parametrize("missing", ["no.such.module", "nosuchmodule_mttbench"])
def test_a_listed_module_that_does_not_exist_is_an_error(missing):
    with pytest.raises(ModuleNotFoundError):
        compiled.cold_modules((missing,))

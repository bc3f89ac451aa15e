"""The architecture, checked from the outside.

1. A plain (non-editable) install works away from the checkout and installs no generic
   top-level name: only ``mttbench`` (the layer folders live under it).
2. An outside package registers a tracker and a policy through entry points; a broken
   entry point is listed with its reason and stops nothing; a tracker named by class path
   runs without any entry point.
3. The import graph of the package's sources has no cycle and keeps the layering
   (scenarios below trackers below benchmarks; nothing imports the command line), and no
   source anywhere imports the bare names ``trackers``, ``scenarios`` or ``benchmarks``.

Parts 1 and 2 run ``python -m mttbench`` in subprocesses from empty working directories.
The install of part 1 is built once per test session, also under pytest-xdist (the
workers share it through a lock file).
"""

from __future__ import annotations

import ast
import fcntl
import filecmp
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pandas as pd
import pytest

REPO = Path(__file__).resolve().parents[1]
#: the repository's folders installed as subpackages of ``mttbench`` (pyproject.toml)
LAYERS = ("trackers", "scenarios", "benchmarks")
BARE_NAMES = frozenset(LAYERS)
PYTHON = sys.executable


def run_python(args: list[str], cwd: Path, pythonpath: list[Path], *, timeout: float = 600,
               extra_env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``python <args>`` from ``cwd`` with exactly ``pythonpath`` on PYTHONPATH."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    env["PYTHONPATH"] = os.pathsep.join(str(p) for p in pythonpath)
    env["PYTHONNOUSERSITE"] = "1"
    env.update(extra_env or {})
    # its own process group, ended when the command returns: a GPF run in the temporary
    # install leaves its kernels' background compile behind (by design: it fills the
    # install's numba cache for a next run), which nothing here reads and which would
    # otherwise take CPU from the rest of the suite for minutes
    with subprocess.Popen([PYTHON, *args], cwd=cwd, env=env, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True, start_new_session=True) as proc:
        try:
            stdout, stderr = proc.communicate(timeout=timeout)
        finally:
            _stop_group(proc)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


def _stop_group(proc: subprocess.Popen) -> None:
    """Kill whatever is left of ``proc``'s process group (``proc`` leads it)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:  # nothing left
        pass
    proc.wait()


def ok(proc: subprocess.CompletedProcess) -> subprocess.CompletedProcess:
    assert proc.returncode == 0, (
        f"{proc.args} exited {proc.returncode}\n--- stdout\n{proc.stdout}\n--- stderr\n"
        f"{proc.stderr}")
    return proc


# ============================================================ 1. a plain install
#: top-level entries of the checkout that a build does not need (or must not see:
#: a stale build/ folder would leak deleted modules into the wheel)
_NOT_COPIED = {".git", ".venv", "build", "dist", "tests", "docs", ".cache", ".hypothesis",
               ".pytest_cache", ".ruff_cache", ".benchmarks"}


def _ignore(folder: str, names: list[str]) -> set[str]:
    here = Path(folder)
    skip = {n for n in names if n == "__pycache__" or n.endswith(".egg-info")}
    if here == REPO:
        skip |= _NOT_COPIED & set(names)
    elif here == REPO / "reports":  # run outputs; only reference/ ships
        skip |= {n for n in names if n not in ("reference", "README.md")}
    return skip


def _build_and_install(site: Path, work: Path) -> float:
    """Copy the checkout's sources to ``work`` and ``pip install`` them (not editable) into
    ``site``. Building from a copy leaves the checkout untouched. Returns the seconds."""
    t0 = time.perf_counter()
    src = work / "src"
    shutil.copytree(REPO, src, ignore=_ignore)
    proc = subprocess.run(
        [PYTHON, "-m", "pip", "install", "--no-deps", "--no-input", "--disable-pip-version-check",
         "--target", str(site), str(src)],
        cwd=work, capture_output=True, text=True, timeout=900, check=False)
    assert proc.returncode == 0, f"pip install failed:\n{proc.stdout}\n{proc.stderr}"
    _copy_numba_cache(site / "mttbench")
    return time.perf_counter() - t0


def _copy_numba_cache(package: Path) -> int:
    """Copy the checkout's numba disk cache (``__pycache__/*.nbi`` indexes, ``*.nbc``
    data) next to each module of the installed ``package`` whose source is byte for byte
    the checkout's; returns the number of files copied.

    Numba loads a cached kernel only when the index's source stamp and the entry's key
    (bytecode hash, signature, CPU) match, else it compiles; so the install's kernels are
    the checkout's compiled code for the same source, and a module left uncopied (or a
    checkout never warmed by ``make``) compiles cold into the install as for a user."""
    from mttbench.trackers.compiled import STAMP_NAME

    if os.environ.get("NUMBA_CACHE_DIR"):
        return 0  # the cache lives outside both trees: nothing next to the sources
    roots = {REPO / "mttbench": package, **{REPO / layer: package / layer for layer in LAYERS}}
    copied = 0
    for src_root, dst_root in roots.items():
        for cache in sorted(src_root.rglob("__pycache__")):
            target = dst_root / cache.parent.relative_to(src_root)
            for file in sorted(cache.glob("*.nb[ic]")):
                source = file.name.split(".")[0] + ".py"
                if not ((target / source).is_file() and filecmp.cmp(
                        cache.parent / source, target / source, shallow=False)):
                    continue  # not installed (benchmarks/bench), or not the same source
                (target / "__pycache__").mkdir(exist_ok=True)
                shutil.copy2(file, target / "__pycache__" / file.name)
                copied += 1
            # the digest of the sources the cached kernels call: the install compares it
            # with its own sources' (else it would drop the copied cache and compile)
            if (cache / STAMP_NAME).is_file() and (target / "__pycache__").is_dir():
                shutil.copy2(cache / STAMP_NAME, target / "__pycache__")
    return copied


@pytest.fixture(scope="module")
def installed_site(tmp_path_factory) -> Path:
    """``<tmp>/site``: the project installed non-editably, built once per session (the
    xdist workers' temp folders share a parent, where the first one builds under a lock)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    shared = root / "mttbench-plain-install"
    shared.mkdir(exist_ok=True)
    site, done, failed = shared / "site", shared / "done", shared / "failed"
    with open(shared / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not done.exists() and not failed.exists():
                work = shared / "work"
                work.mkdir()
                try:
                    seconds = _build_and_install(site, work)
                except BaseException as exc:  # one failed build per session, not one per test
                    failed.write_text(str(exc))
                    raise
                finally:
                    shutil.rmtree(work, ignore_errors=True)
                done.write_text(f"{seconds:.1f}\n")
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    if failed.exists():
        pytest.fail("the plain install failed earlier in this session:\n" + failed.read_text(),
                    pytrace=False)
    return site


@pytest.fixture
def empty_cwd(tmp_path) -> Path:
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    return cwd


def test_installed_files_hold_only_the_mttbench_package(installed_site):
    top = {p.name for p in installed_site.iterdir()}
    assert "mttbench" in top
    assert not top & BARE_NAMES, f"generic top-level names installed: {sorted(top & BARE_NAMES)}"
    packages = {n for n in top if not n.endswith((".dist-info", ".egg-info"))
                and n not in ("bin", "__pycache__")}
    assert packages == {"mttbench"}, f"unexpected top-level entries installed: {sorted(top)}"
    # no layer folder anywhere but under mttbench/
    for name in BARE_NAMES:
        stray = [p for p in installed_site.rglob(name)
                 if p.is_dir() and p.parent != installed_site / "mttbench"]
        assert not stray, stray
    pkg = installed_site / "mttbench"
    for sub in (*LAYERS, "scenarios/presets", "reference"):
        assert (pkg / sub).is_dir(), f"mttbench/{sub} is missing from the install"
    # every source package of the checkout is installed (a new subpackage must be listed
    # in pyproject.toml's packages, or the plain install lacks it)
    for layer in LAYERS:
        for init in (REPO / layer).rglob("__init__.py"):
            rel = init.parent.relative_to(REPO / layer)
            if layer == "benchmarks" and rel.parts[:1] == ("bench",):
                continue  # the pytest-benchmark suites are not installed
            assert (pkg / layer / rel / "__init__.py").is_file(), (
                f"{layer}/{rel} is in the checkout but not in the plain install (add it to "
                "[tool.setuptools] packages in pyproject.toml)")
    assert list((pkg / "scenarios" / "presets").glob("*.toml"))
    assert list((pkg / "reference").glob("*.csv"))
    # the stored Bayes references (rows and provenance) ship, in pairs
    stored = sorted(p.name for p in (pkg / "reference" / "bayes").iterdir())
    assert stored and stored == sorted(p.name for p in (
        REPO / "reports" / "reference" / "bayes").iterdir())
    top_level = next(installed_site.glob("mttbench-*.dist-info")) / "top_level.txt"
    if top_level.exists():
        assert top_level.read_text().split() == ["mttbench"]


_WHERE = textwrap.dedent("""
    import importlib, importlib.resources, json, sys
    import mttbench
    out = {"mttbench": mttbench.__file__}
    for name in ("trackers", "scenarios", "benchmarks", "benchmarks.app.cli", "trackers.base"):
        out["mttbench." + name] = importlib.import_module("mttbench." + name).__file__
    out["reference"] = str(importlib.resources.files("mttbench.reference"))
    bare = {}
    for name in ("trackers", "scenarios", "benchmarks"):
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as exc:
            bare[name] = "ModuleNotFoundError:" + str(exc.name)
        except Exception as exc:
            bare[name] = type(exc).__name__
        else:
            bare[name] = "imported from " + str(sys.modules[name].__file__)
    out["bare"] = bare
    print(json.dumps(out))
""")


def test_installed_copy_wins_and_bare_layer_names_do_not_import(installed_site, empty_cwd):
    """From an empty folder with the install on PYTHONPATH, ``mttbench`` and its layers
    come from the install (not the .venv's editable finder, which maps the checkout)."""
    proc = ok(run_python(["-c", "import mttbench; print(mttbench.__file__)"], empty_cwd,
                         [installed_site]))
    assert Path(proc.stdout.strip()).resolve().is_relative_to(installed_site.resolve())
    where = json.loads(ok(run_python(["-c", _WHERE], empty_cwd, [installed_site])).stdout)
    bare = where.pop("bare")
    for name, file in where.items():
        path = Path(file).resolve()
        assert path.is_relative_to(installed_site.resolve()), f"{name} comes from {path}"
        assert not path.is_relative_to(REPO), f"{name} comes from the checkout: {path}"
    for name in BARE_NAMES:
        assert bare[name] == f"ModuleNotFoundError:{name}", f"import {name}: {bare[name]}"
    # nor does the development (editable) install expose the bare names
    where = json.loads(ok(run_python(["-c", _WHERE], empty_cwd, [])).stdout)
    for name in BARE_NAMES:
        assert where["bare"][name] == f"ModuleNotFoundError:{name}", (
            f"editable install, import {name}: {where['bare'][name]}")


def test_installed_compare_writes_report_and_results(installed_site, empty_cwd, tmp_path):
    out = tmp_path / "cmp"
    ok(run_python(["-m", "mttbench", "compare", "--scenarios", "default", "--trackers", "null",
                   "kfnn", "--seeds", "2", "--steps", "10", "--workers", "1", "--no-progress",
                   "--out", str(out)],
                  empty_cwd, [installed_site]))
    assert (out / "report.html").is_file()
    df = pd.read_parquet(out / "results.parquet")
    assert set(df["tracker"]) == {"null", "kfnn"}
    assert (df["status"] == "ok").all()
    assert not list(empty_cwd.iterdir()), "compare wrote into the working directory"


def test_installed_reproduce_reduced_check_passes(installed_site, empty_cwd, tmp_path):
    """The reference numbers ship as package data, so the check works from a plain install.

    Numba stays as the environment says (by default on). The install holds a copy of the
    checkout's numba disk cache (:func:`_copy_numba_cache`): kernels whose source matches
    the checkout's load from it, any other compiles cold into the install's __pycache__
    (the numbers are the same: the compiled and numpy forms agree bit for bit). One
    worker: with two, each would compile any cold kernel side by side
    (docs/suite_time.md)."""
    proc = ok(run_python(["-m", "mttbench", "reproduce", "paper", "--reduced", "--check",
                          "--workers", "1", "--no-progress", "--out", str(tmp_path / "repro"),
                          "--cache-dir", str(tmp_path / "cache")], empty_cwd, [installed_site]))
    assert "check passed" in proc.stdout, proc.stdout + proc.stderr
    assert not list(empty_cwd.iterdir()), "reproduce wrote into the working directory"


# ====================================================== 2. plugins by entry point
PLUGIN_SOURCE = '''\
"""An outside package with one tracker and one policy for mttbench."""

import numpy as np

from mttbench.benchmarks.engine.policies import Policy
from mttbench.trackers.base import Estimate, Tracker


class DemoTracker(Tracker):
    name = "demo-null"
    summary = "plugin demo: reports zero targets"

    def __init__(self) -> None:
        pass

    def reset(self, model, rng):
        self._n_cells = model.grid.n_cells

    def predict(self):
        pass

    def cell_count_distribution(self):
        P = np.zeros((self._n_cells, 2))
        P[:, 0] = 1.0
        return P

    def update(self, looks):
        pass

    def estimate(self):
        return Estimate.empty()


class DemoPolicy(Policy):
    name = "demo-first"
    summary = "plugin demo: looks at the first cells, every step"

    def select(self, k, counts=None, truth_cells=None):
        return np.arange(self._n_looks, dtype=np.int64) % self._n_cells
'''

# the broken entry points come first: they must not stop the ones after them
PLUGIN_ENTRY_POINTS = """\
[mttbench.trackers]
demo-broken = mttbench_plugin_missing:Nothing
demo-null = mttbench_plugin_demo:DemoTracker

[mttbench.policies]
demo-broken-policy = mttbench_plugin_missing:Nothing
demo-first = mttbench_plugin_demo:DemoPolicy
"""


@pytest.fixture(scope="module")
def plugin_dirs(tmp_path_factory) -> tuple[Path, Path]:
    """(with entry points, without): the same package, once with a ``.dist-info`` that
    importlib.metadata finds on PYTHONPATH, once bare (usable only by class path)."""
    root = tmp_path_factory.mktemp("plugin")
    registered, bare = root / "registered", root / "bare"
    for folder in (registered, bare):
        (folder / "mttbench_plugin_demo").mkdir(parents=True)
        (folder / "mttbench_plugin_demo" / "__init__.py").write_text(PLUGIN_SOURCE)
    info = registered / "mttbench_plugin_demo-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: mttbench-plugin-demo\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(PLUGIN_ENTRY_POINTS)
    (info / "top_level.txt").write_text("mttbench_plugin_demo\n")
    return registered, bare


def _tracker_lines(stdout: str) -> dict[str, str]:
    """``mttbench trackers`` output: entry name -> its line."""
    return {line.split()[0]: line for line in stdout.splitlines()
            if line.startswith("  ") and not line.startswith("   ") and line.split()}


def test_entry_points_are_listed_and_broken_ones_say_why(plugin_dirs, empty_cwd):
    registered, _ = plugin_dirs
    out = ok(run_python(["-m", "mttbench", "trackers"], empty_cwd, [registered])).stdout
    lines = _tracker_lines(out)
    assert "demo-null" in lines and "reports zero targets" in lines["demo-null"]
    assert "demo-first" in lines and "first cells" in lines["demo-first"]
    for name in ("demo-broken", "demo-broken-policy"):
        assert name in lines, out
        assert "NOT LOADED" in lines[name] and "mttbench_plugin_missing" in lines[name], out
    # the broken ones stop nothing: the shipped trackers and policies are all listed
    for name in ("null", "kfnn", "gpf", "raster"):
        assert name in lines and "NOT LOADED" not in lines[name], out
    trackers_part, policies_part = out.split("Cell-selection policies")
    assert "demo-null" in trackers_part and "demo-broken " in trackers_part
    assert "demo-first" in policies_part and "demo-broken-policy" in policies_part


def test_entry_point_tracker_and_policy_run(plugin_dirs, empty_cwd, tmp_path):
    registered, _ = plugin_dirs
    out = tmp_path / "run"
    ok(run_python(["-m", "mttbench", "run", "--scenarios", "default", "--trackers", "demo-null",
                   "null", "--policy", "demo-first", "raster", "--seeds", "1", "--steps", "3",
                   "--workers", "1", "--no-progress", "--out", str(out)],
                  empty_cwd, [registered]))
    df = pd.read_parquet(out / "results.parquet")
    demo = df[df["tracker"] == "demo-null"]
    assert len(demo) > 0 and (demo["status"] == "ok").all(), demo
    assert set(df["tracker"]) == {"demo-null", "null"}
    assert set(df["policy"]) == {"demo-first", "raster"}
    assert (df["status"] == "ok").all()


def test_broken_entry_point_fails_only_when_used(plugin_dirs, empty_cwd, tmp_path):
    registered, _ = plugin_dirs
    proc = run_python(["-m", "mttbench", "run", "--scenarios", "default", "--trackers",
                       "demo-broken", "--seeds", "1", "--steps", "3", "--workers", "1",
                       "--no-progress", "--out", str(tmp_path / "run")], empty_cwd, [registered])
    assert proc.returncode != 0
    assert "demo-broken" in proc.stderr and "mttbench_plugin_missing" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr


def test_tracker_by_class_path_needs_no_entry_point(plugin_dirs, empty_cwd, tmp_path):
    _, bare = plugin_dirs
    listed = ok(run_python(["-m", "mttbench", "trackers"], empty_cwd, [bare])).stdout
    assert "demo-null" not in listed  # no entry point here
    out = tmp_path / "run"
    ok(run_python(["-m", "mttbench", "run", "--scenarios", "default", "--trackers",
                   "mttbench_plugin_demo:DemoTracker", "--seeds", "1", "--steps", "3",
                   "--workers", "1", "--no-progress", "--out", str(out)], empty_cwd, [bare]))
    df = pd.read_parquet(out / "results.parquet")
    assert len(df) > 0 and (df["status"] == "ok").all(), df
    assert set(df["tracker"]) == {"mttbench_plugin_demo:DemoTracker"}


# ======================================================== 3. the import graph
def source_modules() -> dict[str, Path]:
    """Module name -> source file, for every module the package installs (read from the
    checkout: in editable mode pkgutil cannot see the mapped subpackages)."""
    roots = {"mttbench": REPO / "mttbench", **{f"mttbench.{n}": REPO / n for n in LAYERS}}
    modules: dict[str, Path] = {}
    for prefix, folder in roots.items():
        for path in sorted(folder.rglob("*.py")):
            rel = path.relative_to(folder)
            if "__pycache__" in rel.parts:
                continue
            if prefix == "mttbench.benchmarks" and rel.parts[0] == "bench":
                continue  # not installed
            if prefix == "mttbench" and len(rel.parts) > 1:
                continue  # mttbench/ holds modules only; a subfolder would be a new layer
            parts = list(rel.with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join([prefix, *parts])] = path
    return modules


def _is_type_checking(test: ast.expr) -> bool:
    return ((isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
            or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"))


def _imports(tree: ast.AST, type_checking: bool = True):
    """Every Import/ImportFrom node, in functions and under ``if TYPE_CHECKING:`` too (a
    reader follows those edges as well); ``type_checking=False`` skips the latter."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if not type_checking and isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)
            continue
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        stack.extend(ast.iter_child_nodes(node))


def _deepest_known(name: str, known: set[str]) -> str | None:
    parts = name.split(".")
    while parts:
        candidate = ".".join(parts)
        if candidate in known:
            return candidate
        parts.pop()
    return None


def import_edges(module: str, path: Path, known: set[str], type_checking: bool = True
                 ) -> set[str]:
    """The mttbench modules ``module`` imports (relative imports resolved; those under
    ``if TYPE_CHECKING:`` only with ``type_checking``)."""
    is_package = path.name == "__init__.py"
    package = module if is_package else module.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    targets: set[str] = set()
    for node in _imports(tree, type_checking):
        if isinstance(node, ast.Import):
            bases = [alias.name for alias in node.names]
            names: list[str] = []
        else:
            if node.level:
                anchor = package.split(".")
                if node.level - 1 > len(anchor) - 1:
                    raise AssertionError(f"{path}:{node.lineno}: relative import beyond the "
                                         "top-level package")
                anchor = anchor[:len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            bases = [base]
            names = [alias.name for alias in node.names if alias.name != "*"]
        for base in bases:
            if base != "mttbench" and not base.startswith("mttbench."):
                continue
            if names:  # from base import name: the submodule base.name if there is one
                for name in names:
                    sub = f"{base}.{name}"
                    target = sub if sub in known else _deepest_known(base, known)
                    if target:
                        targets.add(target)
            else:
                target = _deepest_known(base, known)
                if target:
                    targets.add(target)
    targets.discard(module)
    return targets


def import_graph() -> dict[str, set[str]]:
    modules = source_modules()
    known = set(modules)
    return {m: import_edges(m, p, known) for m, p in modules.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as ``[a, b, ..., a]``, or None. Iterative three-colour DFS,
    nodes and edges visited in sorted order so the answer is reproducible."""
    WHITE, GREY, BLACK = 0, 1, 2
    colour = dict.fromkeys(graph, WHITE)
    for start in sorted(graph):
        if colour[start] != WHITE:
            continue
        path = [start]
        colour[start] = GREY
        stack = [iter(sorted(graph[start]))]
        while stack:
            nxt = next(stack[-1], None)
            if nxt is None:
                stack.pop()
                colour[path.pop()] = BLACK
                continue
            state = colour.get(nxt, BLACK)  # edges out of the graph lead nowhere
            if state == GREY:
                return path[path.index(nxt):] + [nxt]
            if state == WHITE:
                colour[nxt] = GREY
                path.append(nxt)
                stack.append(iter(sorted(graph.get(nxt, ()))))
    return None


@pytest.mark.parametrize("graph, cyclic", [
    ({}, False),
    ({"a": set()}, False),
    ({"a": {"a"}}, True),
    ({"a": {"b"}, "b": {"c"}, "c": set()}, False),
    ({"a": {"b", "c"}, "b": {"d"}, "c": {"d"}, "d": set()}, False),  # a diamond is no cycle
    ({"a": {"b"}, "b": {"c"}, "c": {"a"}}, True),
    ({"a": {"x"}, "x": {"y"}, "y": {"z"}, "z": {"x"}}, True),  # reached from outside
    ({"a": {"b"}, "b": set(), "c": {"d"}, "d": {"e"}, "e": {"c", "f"}, "f": set()}, True),
    ({"a": {"outside"}}, False),
])
def test_find_cycle_on_hand_made_graphs(graph, cyclic):
    cycle = find_cycle(graph)
    assert (cycle is not None) == cyclic, cycle
    if cycle:
        assert cycle[0] == cycle[-1] and len(cycle) >= 2
        for a, b in zip(cycle, cycle[1:], strict=False):
            assert b in graph[a], (a, b, cycle)


def test_import_edges_resolve_relative_and_absolute_imports(tmp_path):
    known = {"mttbench", "mttbench.trackers", "mttbench.trackers.base", "mttbench.trackers.gpf",
             "mttbench.scenarios", "mttbench.scenarios.model", "mttbench.benchmarks",
             "mttbench.benchmarks.app.cli", "mttbench.benchmarks.engine.specs"}
    src = tmp_path / "mod.py"
    src.write_text(textwrap.dedent("""
        from __future__ import annotations
        from typing import TYPE_CHECKING
        import numpy
        from . import base, nothing_here
        from ..scenarios.model import Looks
        from .. import benchmarks
        import mttbench.benchmarks.engine.specs
        if TYPE_CHECKING:
            from ..benchmarks.app.cli import main
        else:
            from mttbench import scenarios

        def lazy():
            from mttbench.benchmarks.app.cli import main  # a lazy import is still an import
    """))
    edges = import_edges("mttbench.trackers.gpf", src, known, type_checking=False)
    assert edges == {"mttbench.trackers.base", "mttbench.trackers", "mttbench.scenarios.model",
                     "mttbench.benchmarks", "mttbench.benchmarks.engine.specs",
                     "mttbench.scenarios", "mttbench.benchmarks.app.cli"}
    src.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                   "    from mttbench.benchmarks.app import cli\n")
    assert import_edges("mttbench.trackers.gpf", src, known) == {"mttbench.benchmarks.app.cli"}
    assert import_edges("mttbench.trackers.gpf", src, known, type_checking=False) == set()
    init = tmp_path / "__init__.py"
    init.write_text("from . import gpf\nfrom .base import Tracker\n")
    assert import_edges("mttbench.trackers", init, known) == {"mttbench.trackers.gpf",
                                                               "mttbench.trackers.base"}


def test_every_layer_and_module_is_found():
    modules = source_modules()
    for name in ("mttbench", "mttbench.__main__", "mttbench.trackers", "mttbench.trackers.base",
                 "mttbench.scenarios", "mttbench.scenarios.model", "mttbench.benchmarks",
                 "mttbench.benchmarks.app.cli"):
        assert name in modules, name
    assert not any(m.startswith("mttbench.benchmarks.bench") for m in modules)


def test_no_import_cycle():
    graph = import_graph()
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def _layer_violations(graph: dict[str, set[str]]) -> list[str]:
    def within(name: str, package: str) -> bool:
        return name == package or name.startswith(package + ".")

    bad = []
    for module, targets in sorted(graph.items()):
        for target in sorted(targets):
            edge = f"{module} imports {target}"
            if within(module, "mttbench.scenarios") and (
                    within(target, "mttbench.trackers") or within(target, "mttbench.benchmarks")):
                bad.append(f"{edge} (scenarios is the bottom layer)")
            if within(module, "mttbench.trackers") and not (
                    within(target, "mttbench.trackers") or target == "mttbench.scenarios.model"):
                bad.append(f"{edge} (trackers may import only mttbench.scenarios.model)")
            if target == "mttbench.benchmarks.app.cli" and not module.endswith(".__main__"):
                bad.append(f"{edge} (only __main__ may import the command line)")
            if within(module, "mttbench.benchmarks.engine") and within(
                    target, "mttbench.benchmarks.app"):
                bad.append(f"{edge} (the engine imports nothing of the application)")
            if (module == "mttbench.testing" or within(module, "mttbench.trackers")
                    or within(module, "mttbench.scenarios")) and within(
                    target, "mttbench.benchmarks.app"):
                bad.append(f"{edge} (only the command line and __main__ build on the "
                           "application)")
    return bad


def test_layering():
    bad = _layer_violations(import_graph())
    assert not bad, "layering violations:\n  " + "\n  ".join(bad)


def test_layering_check_catches_violations():
    graph = {"mttbench.scenarios.spec": {"mttbench.trackers.base"},
             "mttbench.trackers.gpf": {"mttbench.scenarios.simulator", "mttbench.trackers.base",
                                       "mttbench.scenarios.model"},
             "mttbench.benchmarks.app.report": {"mttbench.benchmarks.app.cli"},
             "mttbench.benchmarks.engine.loop": {"mttbench.benchmarks.app.summary"},
             "mttbench.testing": {"mttbench.benchmarks.app.report"},
             "mttbench.benchmarks.app.tune": {"mttbench.benchmarks.engine.store"},
             "mttbench.__main__": {"mttbench.benchmarks.app.cli"}}
    bad = _layer_violations(graph)
    assert len(bad) == 5, bad


def test_the_public_names_load_no_application_module():
    """``from mttbench import play`` (and every other public name, and the conformance
    kit) imports nothing of the command line, compare, tune, reproduce or report."""
    code = ("import sys, mttbench, mttbench.testing\n"
            "for name in mttbench.__all__: getattr(mttbench, name)\n"
            "app = ('cli', 'compare', 'tune', 'tuned', 'reproduce', 'reproduce_kreucher', "
            "'report', 'figures', 'figures_kreucher', 'resources', 'executor_options', "
            "'frontier', 'figures_frontier')\n"
            "print(sorted(m for m in sys.modules\n"
            "             if m.startswith('mttbench.') and m.rpartition('.')[2] in app))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=REPO).stdout.strip()
    assert out == "[]", out


def test_the_command_line_starts_without_scipy_stats():
    """``mttbench``'s start (every command, every subprocess and Dask worker that imports
    the engine) leaves ``scipy.stats`` to the code that uses it: 0.8 s of a 2.7 s start;
    and so do runs of the trackers that need nothing of it (a sweep's worker process
    pays it otherwise, the KF-NN's gate for one)."""
    code = textwrap.dedent("""\
        import dataclasses, sys, mttbench.benchmarks.app.cli
        print(sorted(m for m in sys.modules if m.startswith('scipy.stats')))
        from mttbench.benchmarks.engine.loop import TrackerSpec, build_jobs, run_job
        from mttbench.scenarios import get
        short = dataclasses.replace(get("default"), n_steps=3)
        for name in ("null", "kfnn", "gpf", "pmb"):
            (job,) = build_jobs([short], [TrackerSpec(name)], None, None, [0])
            assert (run_job(job)["status"] == "ok").all(), name
        print(sorted(m for m in sys.modules if m.startswith('scipy.stats')))
        """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=REPO).stdout.split("\n")
    assert out[:2] == ["[]", "[]"], out


def _python_sources() -> list[Path]:
    """Every .py file of the checkout (tests and benchmarks/bench included)."""
    skip = {".git", ".venv", "build", "dist", ".cache", ".hypothesis", ".pytest_cache",
            ".ruff_cache", ".benchmarks", "__pycache__"}
    out = []
    for folder, dirs, files in os.walk(REPO):
        dirs[:] = sorted(d for d in dirs if d not in skip and not d.endswith(".egg-info"))
        out += [Path(folder, f) for f in sorted(files) if f.endswith(".py")]
    return out


#: calls whose first (string) argument names a module to import or patch
_IMPORTING_CALLS = {"import_module", "__import__", "find_spec", "patch", "setattr", "delattr"}


def bare_layer_imports(text: str, where: str = "<text>") -> list[str]:
    """``where:line`` of every absolute import of a bare layer name (``import trackers``,
    ``from scenarios.spec import x``, ``import_module("benchmarks.app.cli")``, ...)."""
    tree = ast.parse(text, filename=where)
    hits = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif isinstance(node, ast.Call) and node.args:
            func = node.func
            fname = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            arg = node.args[0]
            if (fname in _IMPORTING_CALLS and isinstance(arg, ast.Constant)
                    and isinstance(arg.value, str)):
                names = [arg.value]
        for name in names:
            if name.split(".")[0] in BARE_NAMES:
                hits.append(f"{where}:{node.lineno}: {name}")
    return hits


@pytest.mark.parametrize("line, bad", [
    ("import trackers.gpf", True),
    ("import numpy, scenarios", True),
    ("from scenarios import spec", True),
    ("from benchmarks.app.cli import main", True),
    ("importlib.import_module('benchmarks.app.cli')", True),
    ("monkeypatch.setattr('trackers.gpf.np', None)", True),
    ("from mttbench import trackers", False),
    ("import mttbench.trackers", False),
    ("from . import scenarios", False),
    ("from ..benchmarks import cli", False),
    ("x = 'import trackers'", False),
    ("monkeypatch.setattr(trackers, 'x', 1)", False),
])
def test_bare_layer_imports_are_detected(line, bad):
    assert bool(bare_layer_imports(line)) == bad


def test_no_absolute_import_of_bare_layer_names():
    hits = [hit for path in _python_sources()
            for hit in bare_layer_imports(path.read_text(encoding="utf-8"),
                                          str(path.relative_to(REPO)))]
    assert not hits, "absolute imports of a bare layer name:\n  " + "\n  ".join(hits)

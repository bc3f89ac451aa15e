"""``mttbench reproduce paper --reduced --check``: passes on the checked-in reference and
under restricted SIMD dispatch, fails naming a number altered well outside its band (in
a temporary copy); ``--check --exact`` is bit for bit; the run cache is keyed by
everything that can change a number and ``--no-cache`` neither reads nor writes it."""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import io
import json
import os
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from mttbench.benchmarks.app import reproduce
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec

REFERENCE = reproduce.REFERENCE_DIR / "paper_reduced.csv"
#: x86 dispatch targets at the AVX2 level or below, in numpy >= 2.4's grouped names
#: (X86_V2 = SSE4.2 + POPCNT, X86_V3 = AVX2 + FMA3 + F16C + BMI) and the older ones
AT_MOST_AVX2 = ("SSE", "SSE2", "SSE3", "SSSE3", "SSE41", "POPCNT", "SSE42", "AVX", "F16C",
                "FMA3", "AVX2", "X86_V2", "X86_V3")
#: a setting small enough to run in a second (cache semantics)
TINY = reproduce.Setting("tiny", ("default",), 2, (0,), ("null",), "raster", "null", 0, (1,))


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """The run cache of the reduced setting, filled once per session: the xdist workers'
    temporary folders share a parent, where the first worker computes the setting under
    a lock while the others wait, then read it."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    shared = root / "reproduce-cache"
    shared.mkdir(exist_ok=True)
    with open(root / "reproduce-cache.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not any(shared.glob("*/done.json")):
                with contextlib.redirect_stdout(io.StringIO()):
                    assert _run(shared, tmp_path_factory.mktemp("fill")) == 0
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return shared


def _run(cache, out, *extra):
    return main(["reproduce", "paper", "--reduced", "--out", str(out), "--cache-dir", str(cache),
                 "--workers", "1", "--no-progress", *extra])


# ------------------------------------------------------------------- the command
def test_reduced_check_passes_on_the_checked_in_reference(cache, tmp_path, capsys):
    assert REFERENCE.is_file(), "regenerate with: mttbench reproduce paper --reduced " \
                                "--update-reference"
    rc = _run(cache, tmp_path, "--check")
    io = capsys.readouterr()
    assert rc == 0, io.err
    assert "check passed" in io.out and "Monte Carlo bands" in io.out
    for sc in reproduce.SETTINGS["reduced"].scenarios:
        for name in (f"fig_error_{sc}.png", f"fig_snapshot_{sc}.png", f"error_{sc}.csv",
                     f"snapshot_{sc}.csv"):
            assert (tmp_path / name).is_file(), name
    assert "departs from the paper" in (tmp_path / "report.md").read_text()
    assert (tmp_path / "report.html").read_text().count("data:image/png;base64,") == 4


def _narrowest_state_error(ref: pd.DataFrame) -> tuple[tuple, float, float]:
    """``((scenario, tracker, step), value, band + floor)`` of the reference's state error
    with the narrowest band (both runs' interval taken as the reference's)."""
    err = ref[ref["figure"] == "error"]
    wide = err.set_index(["scenario", "tracker", "step", "quantity"])["value"].unstack()
    width = np.sqrt(2.0) * wide["state_error_ci95"].fillna(0.0) + reproduce.STATE_FLOOR
    at = width.idxmin()
    return at, float(wide.loc[at, "state_error"]), float(width[at])


def test_check_fails_naming_a_number_altered_well_outside_its_band(cache, tmp_path, capsys):
    """A state error moved by twice the step limit of bands: at its narrowest step that is
    a realistic change of at most half a cell (OSPA lies in [0, c = 2])."""
    ref = reproduce.read_numbers(REFERENCE)
    (sc, tracker, step), value, width = _narrowest_state_error(ref)
    delta = 2 * reproduce.STEP_LIMIT * width
    assert delta <= 0.5, f"the narrowest state-error band is {width:.3f} cells"
    new = value - delta if value > 1.0 else value + delta
    sel = ((ref["figure"] == "error") & (ref["scenario"] == sc) & (ref["tracker"] == tracker)
           & (ref["step"] == step) & (ref["quantity"] == "state_error"))
    assert sel.sum() == 1
    altered = ref.copy()
    altered.loc[sel, "value"] = new
    path = tmp_path / "altered.csv"
    altered.to_csv(path, index=False, float_format="%.17g")
    # a reference made with another numpy: the failure message says so
    path.with_suffix(".versions.json").write_text('{"numpy": "0.0"}')
    rc = _run(cache, tmp_path / "out", "--check", "--reference-csv", str(path))
    io = capsys.readouterr()
    assert rc == 1
    assert "runs from the cache" in io.out
    assert (f"figure=error scenario={sc} tracker={tracker} step={step} item=0 "
            f"quantity=state_error: reference {new!r}, now ") in io.err, io.err
    assert "band +-" in io.err and "floor" in io.err
    assert f"curve figure=error scenario={sc} tracker={tracker} quantity=state_error" in io.err
    assert "1 number(s) differ" in io.err
    assert "numpy 0.0 -> " in io.err


def test_update_reference_writes_both_and_exact_check_is_bit_for_bit(cache, tmp_path, capsys):
    """``--update-reference`` writes the CSV and its versions file; ``--check --exact``
    passes against it and fails on a snapshot estimate moved by 1e-6, which ``--check``
    does not compare (one run of one seed has no Monte Carlo band)."""
    ref = tmp_path / "ref" / "paper_reduced.csv"
    assert _run(cache, tmp_path / "out", "--update-reference", "--reference-csv", str(ref)) == 0
    assert "reference updated" in capsys.readouterr().out
    versions = json.loads(ref.with_suffix(".versions.json").read_text())
    assert versions == reproduce.reference_versions()
    assert {"numba", "numpy", "platform", "numpy_cpu_dispatch"} <= set(versions)
    assert _run(cache, tmp_path / "out", "--check", "--exact", "--reference-csv", str(ref)) == 0
    assert "check passed" in capsys.readouterr().out
    numbers = reproduce.read_numbers(ref)
    sel = (numbers["figure"] == "snapshot") & (numbers["quantity"] == "state.px")
    assert sel.any(), "the snapshot has no GPF estimate to alter"
    altered = numbers.copy()
    altered.loc[sel.idxmax(), "value"] += 1e-6
    assert reproduce.check_numbers(numbers, altered).passed
    altered.to_csv(ref, index=False, float_format="%.17g")
    assert _run(cache, tmp_path / "out", "--check", "--exact", "--reference-csv", str(ref)) == 1
    err = capsys.readouterr().err
    assert "1 number(s) differ" in err and "quantity=state.px" in err and "tolerance" in err


# ----------------------------------------------------- restricted SIMD dispatch
def _restricted_dispatch() -> tuple[str, list[str]]:
    """``NPY_ENABLE_CPU_FEATURES`` limited to AVX2 or lower, and the dispatch it leaves;
    skips when this numpy cannot be restricted that way or the restriction changes nothing."""
    cpu = reproduce.cpu_dispatch()
    if not set(cpu["baseline"] + cpu["built"]) & set(AT_MOST_AVX2):
        pytest.skip(f"not an x86 numpy build (baseline {cpu['baseline']}, dispatch "
                    f"{cpu['built']}): no AVX2-level dispatch to restrict to")
    keep = [t for t in cpu["dispatch"] if t in AT_MOST_AVX2]
    if keep == cpu["dispatch"]:
        pytest.skip(f"numpy dispatches nothing above AVX2 on this CPU ({cpu['dispatch']}): "
                    "restricting it changes nothing")
    if not keep:
        pytest.skip(f"numpy reports no AVX2-level target available ({cpu['dispatch']})")
    return " ".join(keep), keep


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "NPY_DISABLE_CPU_FEATURES"}
    env.update(extra)
    return env


def test_cpu_dispatch_and_cache_key_follow_npy_enable_cpu_features():
    features, keep = _restricted_dispatch()
    code = ("import json; from mttbench.benchmarks.app import reproduce as r; "
            "from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec; "
            "s = r.SETTINGS['reduced']; "
            "print(json.dumps([r.cpu_dispatch(), "
            "r.cache_key(s, [TrackerSpec('kfnn')], PolicySpec('renyi'))]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=_env(NPY_ENABLE_CPU_FEATURES=features), timeout=120, check=True)
    cpu, key = json.loads(out.stdout)
    assert cpu["dispatch"] == keep and cpu != reproduce.cpu_dispatch()
    s = reproduce.SETTINGS["reduced"]
    assert key != reproduce.cache_key(s, [TrackerSpec("kfnn")], PolicySpec("renyi"))


def test_reduced_check_passes_under_restricted_simd_dispatch(tmp_path):
    """The reviewer on another CPU: numpy limited to AVX2 (or lower) kernels. Measured on
    an AVX-512 machine (numpy 2.4.6): at commit 8ee53cb six jmpd-ip numbers of the reduced
    setting moved there (paper, step 11, est_count 1.333 -> 1.667) and ``--check --exact``
    failed, while ``--check`` passed with its largest curve mean at 0.01 (limit 1); with
    the seeds of f9ad50f the reduced numbers stay and 78 of the full setting's move
    (module docstring of :mod:`mttbench.benchmarks.app.reproduce`)."""
    features, _ = _restricted_dispatch()
    proc = subprocess.run(
        [sys.executable, "-m", "mttbench", "reproduce", "paper", "--reduced", "--check",
         "--workers", "1", "--no-progress", "--out", str(tmp_path / "out"), "--cache-dir",
         str(tmp_path / "cache")],
        capture_output=True, text=True, env=_env(NPY_ENABLE_CPU_FEATURES=features),
        timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "check passed" in proc.stdout


# ------------------------------------------------------------------ the checks
def _table(rows: list[tuple]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=[*reproduce.KEYS, "value"])


def _curve(scale: float = 0.0, n_steps: int = 10) -> pd.DataFrame:
    """A ``null`` curve on scenario ``s``: state error, its interval 0.2, count error with
    interval 0, true count 3 and 5 seeds per step; ``scale`` shifts the state error."""
    rows = []
    for k in range(n_steps):
        rows += [("error", "s", "null", k, 0, "state_error", 1.0 + 0.01 * k + scale),
                 ("error", "s", "null", k, 0, "state_error_ci95", 0.2),
                 ("error", "s", "null", k, 0, "count_error", 1.0),
                 ("error", "s", "null", k, 0, "count_error_ci95", 0.0),
                 ("error", "s", "null", k, 0, "rmse", 0.5),
                 ("error", "s", "null", k, 0, "true_count", 3.0),
                 ("error", "s", "null", k, 0, "n_seeds", 5.0)]
    rows += [("snapshot", "s", "gpf", 1, 0, "truth.px", 2.5),
             ("snapshot", "s", "gpf", 1, 0, "state.px", 2.4)]
    return _table(rows)


def _set(df: pd.DataFrame, quantity: str, step: int, value: float,
         figure: str = "error") -> pd.DataFrame:
    out = df.copy()
    sel = ((out["figure"] == figure) & (out["quantity"] == quantity) & (out["step"] == step))
    assert sel.sum() == 1
    out.loc[sel, "value"] = value
    return out


def test_exact_check_tolerance_and_missing_rows():
    base = _table([("error", "s", "null", k, 0, "q", v)
                   for k, v in enumerate([1.0, np.nan, 3.0])])
    within = base.assign(value=[1.0 + 1e-12, np.nan, 3.0])  # inside rtol 1e-9; NaN == NaN
    assert reproduce.check_numbers(within, base, exact=True).passed
    moved = base.assign(value=[1.0, np.nan, 3.0 * (1 + 1e-8)])
    check = reproduce.check_numbers(moved, base, exact=True)
    assert check.n_moved == 1 and len(check.lines) == 1
    assert "step=2" in check.lines[0] and "reference 3.0" in check.lines[0]
    assert reproduce.check_numbers(base.assign(value=[np.nan, np.nan, 3.0]), base,
                                   exact=True).n_moved == 1
    lines = reproduce.check_numbers(base.iloc[:2], base, exact=True).lines
    assert len(lines) == 1 and "missing" in lines[0] and "step=2" in lines[0]
    lines = reproduce.check_numbers(base, base.iloc[:2], exact=True).lines
    assert len(lines) == 1 and "new" in lines[0]


def test_monte_carlo_check_curve_rule():
    """The band of a step is sqrt(0.2^2 + 0.2^2) = 0.283, plus the floor 0.05 cells: a
    whole curve shifted by 0.8 of that passes, by 1.2 fails on its mean (every step
    named); one step moved by 4.5 band widths fails alone; one moved by 3.5 does not."""
    ref = _curve()
    width = np.hypot(0.2, 0.2) + reproduce.STATE_FLOOR
    assert reproduce.check_numbers(_curve(0.8 * width), ref).passed
    check = reproduce.check_numbers(_curve(-1.2 * width), ref)
    assert check.n_moved == 10
    assert check.lines[0].startswith("curve figure=error scenario=s tracker=null "
                                     "quantity=state_error: mean of |now - ref| / (band + "
                                     "floor) over 10 steps 1.20")
    assert all(f"step={k} item=0 quantity=state_error" in check.lines[k + 1]
               for k in range(10))
    assert "band +-0.283 + floor 0.05, ratio 1.20" in check.lines[1]
    assert reproduce.check_numbers(_set(ref, "state_error", 4, 1.04 + 3.5 * width), ref).passed
    check = reproduce.check_numbers(_set(ref, "state_error", 4, 1.04 + 4.5 * width), ref)
    assert check.n_moved == 1 and "largest 4.50 at step 4" in check.lines[0]
    assert len(check.lines) == 2
    assert "step=4 item=0 quantity=state_error: reference 1.04, now" in check.lines[1]


def test_monte_carlo_check_counts_floor_exact_quantities_and_skipped_ones():
    ref = _curve()
    # count error: both intervals 0, floor 1 / n_seeds = 0.2; 0.2 passes, 1.0 = 5 floors fails
    assert reproduce.check_numbers(_set(ref, "count_error", 3, 1.2), ref).passed
    check = reproduce.check_numbers(_set(ref, "count_error", 3, 2.0), ref)
    assert check.n_moved == 1 and "floor 0.2, ratio 5.00" in check.lines[1]
    # the world and the number of finished runs: exact
    for quantity, value in (("true_count", 4.0), ("n_seeds", 4.0)):
        check = reproduce.check_numbers(_set(ref, quantity, 7, value), ref)
        assert check.n_moved == 1 and f"step=7 item=0 quantity={quantity}" in check.lines[0]
        assert "tolerance" in check.lines[0]
    check = reproduce.check_numbers(_set(ref, "truth.px", 1, 2.5 + 1e-6, "snapshot"), ref)
    assert check.n_moved == 1 and "quantity=truth.px" in check.lines[0]
    # not compared by --check, compared by --exact: intervals, rmse, snapshot estimates
    for quantity, figure in (("state_error_ci95", "error"), ("rmse", "error"),
                             ("state.px", "snapshot")):
        step = 1 if figure == "snapshot" else 2
        now = _set(ref, quantity, step, 9.0, figure)
        assert reproduce.check_numbers(now, ref).passed, quantity
        assert reproduce.check_numbers(now, ref, exact=True).n_moved == 1, quantity
    # a mean on one side only, and a missing mean: fail
    check = reproduce.check_numbers(_set(ref, "state_error", 5, np.nan), ref)
    assert check.n_moved == 1 and "difference undefined" in check.lines[1]
    gone = ref[~((ref["quantity"] == "state_error") & (ref["step"] == 5))]
    check = reproduce.check_numbers(gone, ref)
    assert check.n_moved == 1 and "missing" in check.lines[0]


def test_reference_without_an_interval_uses_the_current_one():
    """A reference made before ``est_count_ci95`` existed: the current run's interval
    stands on both sides, and the interval rows it lacks are not 'new'."""
    now = _curve()
    for k in range(10):
        now = pd.concat([now, _table([("error", "s", "null", k, 0, "est_count", 2.0),
                                      ("error", "s", "null", k, 0, "est_count_ci95", 0.5)])])
    ref = now[now["quantity"] != "est_count_ci95"]
    width = np.hypot(0.5, 0.5) + 0.2
    assert reproduce.check_numbers(_set(now, "est_count", 0, 2.0 + 3.9 * width), ref).passed
    assert not reproduce.check_numbers(_set(now, "est_count", 0, 2.0 + 4.1 * width), ref).passed
    assert not reproduce.check_numbers(now, ref, exact=True).passed


# ------------------------------------------------------------------- the cache
def test_cache_key_follows_the_configuration_and_the_environment(monkeypatch):
    s = reproduce.SETTINGS["reduced"]
    specs, pol = [TrackerSpec("kfnn")], PolicySpec("renyi")
    k = reproduce.cache_key(s, specs, pol)
    assert k == reproduce.cache_key(s, specs, pol)
    assert k != reproduce.cache_key(dataclasses.replace(s, seeds=(0, 1)), specs, pol)
    assert k != reproduce.cache_key(s, [TrackerSpec("kfnn", {"lost_track_probability": 0.1})], pol)
    assert k != reproduce.cache_key(s, specs, PolicySpec("raster"))
    env = reproduce.environment()
    assert env["versions"] == reproduce.package_versions() and "numba" in env["versions"]
    assert k == reproduce.cache_key(s, specs, pol, env)
    for part, key, value in (("versions", "numpy", "0.0"), ("platform", "machine", "other"),
                             ("platform", "implementation", "PyPy"),
                             # values no machine reports (X86_V3 is this machine's own)
                             ("numpy_cpu", "dispatch", ["NOT_A_DISPATCH_TARGET"]),
                             ("numpy_cpu", "features", ["NOT_A_FEATURE"]),
                             ("env", "OMP_NUM_THREADS", "3")):
        other = json.loads(json.dumps(env))
        other[part][key] = value
        assert k != reproduce.cache_key(s, specs, pol, other), (part, key)
    for var, value in (("MTTBENCH_NO_NUMBA", "1"), ("NPY_DISABLE_CPU_FEATURES", "X86_V4")):
        with monkeypatch.context() as m:
            m.setenv(var, value)
            assert reproduce.environment()["env"][var] == value
            assert k != reproduce.cache_key(s, specs, pol)


def _files(folder) -> dict[str, tuple[int, bytes]]:
    return {str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.read_bytes())
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_no_cache_neither_reads_nor_writes_the_cache(tmp_path):
    specs = [TrackerSpec.parse("null")]
    fresh, _, cached = reproduce.run_or_load(TINY, specs, tmp_path / "none", progress=False,
                                             use_cache=False)
    assert not cached and not (tmp_path / "none").exists()
    again, _, _ = reproduce.run_or_load(TINY, specs, tmp_path / "none", progress=False,
                                        use_cache=False)
    cols = ["scenario", "seed", "step", "true_count", "est_count", "ospa"]
    pd.testing.assert_frame_equal(fresh[cols], again[cols])  # same machine: bit for bit
    cache = tmp_path / "cache"
    _, _, cached = reproduce.run_or_load(TINY, specs, cache, progress=False)
    assert not cached
    _, _, cached = reproduce.run_or_load(TINY, specs, cache, progress=False)
    assert cached
    # a cache entry with other numbers (another dispatch, say): read with the cache only
    (entry,) = [p for p in cache.iterdir()]
    poisoned = fresh.assign(true_count=fresh["true_count"] + 100)
    poisoned.to_parquet(entry / "results.parquet", index=False)
    before = _files(cache)
    read, _, cached = reproduce.run_or_load(TINY, specs, cache, progress=False)
    assert cached and (read["true_count"] >= 100).all()
    recomputed, _, cached = reproduce.run_or_load(TINY, specs, cache, progress=False,
                                                  use_cache=False)
    assert not cached
    pd.testing.assert_frame_equal(recomputed[cols], fresh[cols])
    assert _files(cache) == before


def test_exact_without_check_is_refused(capsys):
    assert main(["reproduce", "paper", "--reduced", "--exact"]) == 2
    assert "--exact only applies with --check" in capsys.readouterr().err


def test_a_failing_run_exits_1_with_one_line(tmp_path, capsys):
    """A tracker that raises at step 3 (tests/crashing_tracker.py) makes the reproduction
    exit 1 with the "k of n runs failed" line, after writing what it could, and the
    failed sweep is not cached as done."""
    cache = tmp_path / "cache"
    rc = main(["reproduce", "paper", "--reduced", "--no-progress", "--cache-dir", str(cache),
               "--workers", "1", "--trackers", "null", "crashing_tracker:Crash", "--out",
               str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 1
    lines = [line for line in err.splitlines() if "runs failed" in line]
    assert len(lines) == 1 and lines[0].startswith("6 of 12 runs failed; first error: "), err
    assert "crashing_tracker:Crash" in lines[0] and "Traceback" not in err
    assert (tmp_path / "out" / "report.md").is_file()
    # a sweep with failed runs is not marked done in the cache: the next call reruns them
    assert list(cache.rglob("results.parquet")) and not list(cache.rglob("done.json"))


def test_check_without_a_reference_is_refused_before_any_run(tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["reproduce", "paper", "--reduced", "--check", "--no-progress", "--no-cache",
               "--reference-csv", str(tmp_path / "missing.csv"), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and len([x for x in err.splitlines() if x.strip()]) == 1, err
    assert "no reference" in err and not out.exists()


def test_spelled_values_give_the_labels_of_the_checked_values():
    """`1e3` and `1000` are one configuration: one label, one cache key, one reference row."""
    (a,), _ = reproduce.available_trackers(("jmpd:n_particles=1e3",))
    (b,), _ = reproduce.available_trackers(("jmpd:n_particles=1000",))
    assert a.label == b.label == "jmpd(n_particles=1000)"
    setting = reproduce.SETTINGS["reduced"]
    policy = PolicySpec(setting.policy)
    assert reproduce.cache_key(setting, [a], policy) == reproduce.cache_key(setting, [b], policy)

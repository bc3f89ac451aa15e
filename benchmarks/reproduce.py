"""``mttbench reproduce paper``: the paper's two result figures, from pinned seeds, checked.

The paper (Section V) shows two figures:

* **Fig. "Snapshot of simulations"** -- the 12x12 grid with positive returns (magenta
  squares) and the true targets (blue dots). We draw it for the GPF at a few steps of
  one pinned run, adding the looked-at cells and the GPF's estimates with 95% ellipses.
* **Fig. "Simulation Result"** -- the target-state estimation error (black) and the
  target-number estimation error (red) against time. We draw the GPF's curves as in the
  paper and overlay the other trackers; each curve is the mean over the pinned seeds
  with a 95% t band.

Both are drawn for the ``paper`` preset (the paper's literal Q) and for ``default``
(the same grid, sensor and three targets with a physically sensible Q), with the
expected-Renyi-divergence cell selection (``renyi``, alpha = 0.5, the paper's
"information value function based alpha divergence") at 24 looks per step.

Pattern (STYLE.md 12): the expensive runs are cached under
``.cache/reproduce/<key>/`` where ``key`` hashes the setting (scenarios, trackers,
policy, seeds, steps, metric parameters) and a fingerprint of the source files that
determine the numbers (trackers, scenarios, harness, metrics, policies), so an edit
to a tracker invalidates the cache; the figure functions only read tables.

Outputs in ``reports/paper/`` (``--out``): ``fig_snapshot_<scenario>.png``,
``fig_error_<scenario>.png``, the numbers behind them (``snapshot_<scenario>.csv``,
``error_<scenario>.csv``), ``numbers_<setting>.csv`` (all numbers in one long table:
figure, scenario, tracker, step, item, quantity, value), ``report.md`` and a
self-contained ``report.html``.

``--check`` compares ``numbers_<setting>.csv`` with ``reports/reference/paper_<setting>.csv``
row by row: a number moved if ``|now - ref| > ATOL + RTOL * |ref|`` with ``RTOL = 1e-9``
and ``ATOL = 1e-12`` (same code and library versions give bit-identical numbers; the
tolerance only absorbs printing). NaN equals NaN. Missing or extra rows also count.
The command then exits 1 and names every number that moved (up to ``MAX_REPORTED``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import reference, scenarios, trackers
from ..scenarios.spec import dumps
from . import figures
from .compare import package_versions
from .harness import build_jobs, run_sweep
from .report import Document
from .snapshot import trace_run
from .specs import PolicySpec, TrackerSpec

RTOL = 1e-9
ATOL = 1e-12
MAX_REPORTED = 25
KEYS = ["figure", "scenario", "tracker", "step", "item", "quantity"]
#: the checked-in references: package data, so ``--check`` works from a plain install
REFERENCE_DIR = Path(reference.__file__).parent
#: source that determines the numbers (hashed into the cache key), per layer package
FINGERPRINT_GLOBS = {
    trackers: ("**/*.py",),
    scenarios: ("*.py", "presets/*.toml"),
    sys.modules[__package__]: ("harness.py", "metrics.py", "policies.py", "information.py",
                               "snapshot.py", "reproduce.py", "specs.py"),
}

#: where our reading of the paper departs from its text (shown in the report and README)
DEPARTURES = [
    "Two sensor models. Sections II and IV derive the GPF for a superposition sensor "
    "(z = mean of the targets' positions + Gaussian noise); Section V simulates Kreucher's "
    "Rayleigh grid sensor with binary returns. The figures come from Section V, so we run the "
    "grid sensor, where the GPF updates each Gaussian by the moment match of its truncation "
    "to the looked-at cells (DESIGN.md); the superposition sensor has its own preset.",
    "Q literal against sensible. The paper copies Q = diag(20, 0.2, 20, 0.2) from Kreucher "
    "et al.; on 1x1 cells that is a jump of about 4.5 cells per step, so no tracker can follow "
    "a target from step to step. The `paper` preset keeps it literally; `default` uses a "
    "white-noise-acceleration Q (q = 5e-4) on the same grid, sensor and three targets. Both "
    "are reproduced.",
    "Empty sensor. The superposition measurement (1/N_k) sum H x_i is undefined when "
    "N_k = 0; the simulator then reports pure noise, z = w, and the GPF's empty combination "
    "uses N(z; 0, R).",
    "Folding the groups G_c. The paper does not say how the per-combination posteriors of a "
    "group of interacting particles become one particle set again; the GPF takes each "
    "particle's exact marginal existence probability and moment-matches its Gaussian over the "
    "combinations in which it exists (dropping cross-particle correlation).",
    "Typos in the equations. The combination weight is printed with ||Sigma^-1|| and without "
    "the 1/2 in the exponent, and the covariance update has 1/n where 1/n^2 belongs; we use "
    "the Gaussian density and the derivation's result (trackers/gpf_linear.py).",
    "Cell selection. The paper's alpha-divergence information value is computed on the joint "
    "density; we score each cell by the expected Renyi gain (alpha = 0.5) of its predicted "
    "count distribution P_c(t) and add gains over cells (benchmarks/information.py), so every "
    "tracker can share the policy.",
    "Undefined error measures. The paper does not define its state error or how many runs it "
    "averages; we plot OSPA (c = 2 cells, p = 2) on positions as the state error and "
    "|N_est - N| as the number error, as means over pinned seeds with 95% t bands.",
]


@dataclass(frozen=True)
class Setting:
    """A pinned reproduction setting (everything that determines the numbers)."""

    name: str
    scenarios: tuple[str, ...]
    n_steps: int
    seeds: tuple[int, ...]
    trackers: tuple[str, ...]
    policy: str
    highlight: str
    snapshot_seed: int
    snapshot_steps: tuple[int, ...]
    c: float = 2.0
    p: float = 2.0


SETTINGS = {
    "full": Setting("full", ("paper", "default"), 50, tuple(range(20)),
                    ("gpf", "kfnn", "jmpd:n_particles=1000", "jmpd-ip:n_particles=1000",
                     "null"),
                    "renyi", "gpf", 0, (4, 24, 49)),
    "reduced": Setting("reduced", ("paper", "default"), 12, (0, 1, 2),
                       ("gpf", "kfnn", "jmpd:n_particles=200", "jmpd-ip:n_particles=200",
                        "null"),
                       "renyi", "gpf", 0, (3, 11)),
}


def available_trackers(texts: tuple[str, ...]) -> tuple[list[TrackerSpec], list[str]]:
    """The specs whose tracker is registered, and the names that are not."""
    specs, missing = [], []
    for text in texts:
        spec = TrackerSpec.parse(text)
        if spec.name in trackers.available():
            specs.append(spec)
        else:
            missing.append(spec.name)
    return specs, missing


def code_fingerprint() -> str:
    """SHA-256 over the sources that determine the numbers (:data:`FINGERPRINT_GLOBS`),
    read from the installed packages (a checkout or a plain install alike)."""
    h = hashlib.sha256()
    for package, patterns in FINGERPRINT_GLOBS.items():
        folder = Path(package.__file__).parent
        for pattern in patterns:
            for path in sorted(folder.glob(pattern)):
                h.update(f"{package.__name__}/{path.relative_to(folder).as_posix()}".encode())
                h.update(path.read_bytes())
    return h.hexdigest()


def cache_key(setting: Setting, specs: list[TrackerSpec], policy: PolicySpec) -> str:
    ident = {
        "setting": dataclasses.asdict(setting),
        "trackers": [[s.name, s.params] for s in specs],
        "policy": [policy.name, policy.params],
        "scenarios": [dumps(scenarios.get(n)) for n in setting.scenarios],
        "code": code_fingerprint(),
    }
    return hashlib.sha256(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()[:20]


# ------------------------------------------------------------------------ runs
def run_or_load(setting: Setting, specs: list[TrackerSpec], cache_dir: Path, *,
                workers: int = 1, progress: bool = True, use_cache: bool = True
                ) -> tuple[pd.DataFrame, dict[str, dict[str, pd.DataFrame]], bool]:
    """The results table and the snapshot trace frames (per scenario), from the cache
    when present. Returns ``(results, traces, cached)``."""
    policy = PolicySpec(setting.policy)
    folder = cache_dir / cache_key(setting, specs, policy)
    done = folder / "done.json"
    if use_cache and done.exists():
        results = pd.read_parquet(folder / "results.parquet")
        traces = {sc: {kind: pd.read_parquet(folder / f"trace_{sc}_{kind}.parquet")
                       for kind in ("looks", "truth", "estimates", "counts")}
                  for sc in json.loads(done.read_text())["traces"]}
        return results, traces, True
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    scs = [dataclasses.replace(scenarios.get(n), n_steps=setting.n_steps)
           for n in setting.scenarios]
    jobs = build_jobs(scs, specs, [policy], None, list(setting.seeds))
    results = run_sweep(jobs, folder, workers=workers, progress=progress, resume=False,
                        c=setting.c, p=setting.p)
    shutil.rmtree(folder / "parts", ignore_errors=True)
    traces: dict[str, dict[str, pd.DataFrame]] = {}
    hl = [s for s in specs if s.name == setting.highlight]
    if hl:
        for sc in scs:
            try:
                frames = trace_run(sc, hl[0], setting.snapshot_seed, policy).frames()
            except Exception as exc:  # noqa: BLE001 - the tables already show the failure
                print(f"snapshot of {hl[0].label} on {sc.name} failed: {exc}", file=sys.stderr)
                continue
            traces[sc.name] = frames
            for kind, df in frames.items():
                df.to_parquet(folder / f"trace_{sc.name}_{kind}.parquet", index=False)
    done.write_text(json.dumps({"traces": sorted(traces), "setting": setting.name}))
    return results, traces, False


# --------------------------------------------------------------------- numbers
def error_curves(results: pd.DataFrame) -> pd.DataFrame:
    """Per scenario x tracker x step: state error (OSPA) and count error, mean and 95% t
    half-width over the ok seeds, and the mean RMSE, estimated and true counts."""
    parts = []
    for col, name in (("ospa", "state_error"), ("count_error", "count_error"),
                      ("rmse", "rmse"), ("est_count", "est_count"),
                      ("true_count", "true_count")):
        st = figures.step_stats(results, col)
        st = st.rename(columns={"mean": name, "ci95": f"{name}_ci95", "n": f"{name}_n"})
        parts.append(st.set_index(["scenario", "tracker_label", "step"]))
    out = pd.concat(parts, axis=1).reset_index()
    keep = ["scenario", "tracker_label", "step", "state_error", "state_error_ci95",
            "count_error", "count_error_ci95", "rmse", "est_count", "true_count",
            "state_error_n"]
    return out[keep].rename(columns={"state_error_n": "n_seeds"})


def snapshot_numbers(frames: dict[str, pd.DataFrame], steps: tuple[int, ...]) -> pd.DataFrame:
    """The snapshot's numbers at ``steps``: looked-at cells and returns, true positions,
    estimates with position covariances (one row per item)."""
    rows = []
    for k in steps:
        cnt = frames["counts"].loc[frames["counts"]["step"] == k, "count"]
        rows.append({"step": k, "item": 0, "kind": "estimate", "count": float(cnt.iloc[0])})
        lk = frames["looks"][frames["looks"]["step"] == k]
        for r in lk.itertuples():
            rows.append({"step": k, "item": int(r.look), "kind": "look", "cell": int(r.cell),
                         "positive": int(r.positive)})
        for i, r in enumerate(frames["truth"][frames["truth"]["step"] == k].itertuples()):
            rows.append({"step": k, "item": i, "kind": "truth", "px": r.px, "py": r.py,
                         "id": int(r.id)})
        for r in frames["estimates"][frames["estimates"]["step"] == k].itertuples():
            rows.append({"step": k, "item": int(r.index), "kind": "state", "px": r.px,
                         "py": r.py, "cov_xx": r.cov_xx, "cov_xy": r.cov_xy,
                         "cov_yy": r.cov_yy})
    return pd.DataFrame(rows)


def long_numbers(curves: pd.DataFrame, snaps: dict[str, pd.DataFrame],
                 highlight: str) -> pd.DataFrame:
    """All numbers behind the figures as one long table with :data:`KEYS` + ``value``."""
    parts = []
    value_cols = ["state_error", "state_error_ci95", "count_error", "count_error_ci95",
                  "rmse", "est_count", "true_count", "n_seeds"]
    m = curves.melt(id_vars=["scenario", "tracker_label", "step"], value_vars=value_cols,
                    var_name="quantity", value_name="value")
    m = m.rename(columns={"tracker_label": "tracker"})
    m["figure"], m["item"] = "error", 0
    parts.append(m)
    for sc, snap in snaps.items():
        if snap.empty:
            continue
        cols = [c for c in ("cell", "positive", "id", "px", "py", "cov_xx", "cov_xy", "cov_yy",
                            "count") if c in snap.columns]
        s = snap.melt(id_vars=["step", "item", "kind"], value_vars=cols, var_name="q",
                      value_name="value").dropna(subset=["value"])
        s["quantity"] = s["kind"] + "." + s["q"]
        s["figure"], s["scenario"], s["tracker"] = "snapshot", sc, highlight
        parts.append(s)
    out = pd.concat(parts, ignore_index=True)[KEYS + ["value"]]
    out["value"] = out["value"].astype(float)
    out[["step", "item"]] = out[["step", "item"]].astype("int64")
    return out.sort_values(KEYS, kind="stable").reset_index(drop=True)


def read_numbers(path: str | Path) -> pd.DataFrame:
    """A numbers CSV as written by :func:`reproduce_paper` (floats parsed round-trip exact)."""
    # read text: names such as "null" (a tracker) must stay strings, and Python's float()
    # parses the 17 significant digits exactly whatever the pandas version; "" is NaN
    df = pd.read_csv(path, dtype=str, keep_default_na=False)
    df[["step", "item"]] = df[["step", "item"]].astype("int64")
    df["value"] = [float(v) if v != "" else math.nan for v in df["value"]]
    return df


def check_numbers(now: pd.DataFrame, reference: pd.DataFrame, rtol: float = RTOL,
                  atol: float = ATOL) -> list[str]:
    """Lines naming every number that moved (empty list: all match). See module docstring."""
    ref = reference.copy()
    for df in (now, ref):
        df[["step", "item"]] = df[["step", "item"]].astype("int64")
        df[["figure", "scenario", "tracker", "quantity"]] = df[
            ["figure", "scenario", "tracker", "quantity"]].astype(str)
    merged = now.merge(ref, on=KEYS, how="outer", suffixes=("_now", "_ref"), indicator=True)
    lines = []

    def name(r) -> str:
        return (f"figure={r.figure} scenario={r.scenario} tracker={r.tracker} step={r.step} "
                f"item={r.item} quantity={r.quantity}")

    for r in merged[merged["_merge"] == "left_only"].itertuples():
        lines.append(f"{name(r)}: new (not in the reference), value {r.value_now!r}")
    for r in merged[merged["_merge"] == "right_only"].itertuples():
        lines.append(f"{name(r)}: missing (reference value {r.value_ref!r})")
    both = merged[merged["_merge"] == "both"]
    a, b = both["value_now"].to_numpy(float), both["value_ref"].to_numpy(float)
    same_nan = np.isnan(a) & np.isnan(b)
    with np.errstate(invalid="ignore"):
        moved = ~same_nan & ~(np.abs(a - b) <= atol + rtol * np.abs(b))
    for r in both[moved].itertuples():
        lines.append(f"{name(r)}: reference {r.value_ref!r}, now {r.value_now!r} "
                     f"(difference {r.value_now - r.value_ref:+.3e})")
    return lines


# ---------------------------------------------------------------------- report
def _write_report(out: Path, setting: Setting, specs: list[TrackerSpec], missing: list[str],
                  figs: list[tuple[Path, str]], failures: list[str], cached: bool) -> None:
    """``report.md`` and a self-contained ``report.html`` (figures embedded)."""
    doc = Document()
    doc.add("h1", f"Reproduction of the paper's result figures ({setting.name} setting)")
    doc.add("p", "Command: `mttbench reproduce paper"
            + (" --reduced" if setting.name == "reduced" else "") + "`.")
    doc.add("list", [
        f"scenarios: {', '.join(setting.scenarios)} ({setting.n_steps} steps)",
        f"trackers: {', '.join(s.label for s in specs)}"
        + (f" (not registered, left out: {', '.join(missing)})" if missing else ""),
        f"seeds: {', '.join(map(str, setting.seeds))}; snapshot: seed "
        f"{setting.snapshot_seed}, steps {', '.join(map(str, setting.snapshot_steps))}",
        f"cell selection: {setting.policy} (each scenario's 24 looks per step); OSPA "
        f"c = {setting.c:g}, p = {setting.p:g}",
        f"runs {'loaded from the cache' if cached else 'computed'}",
    ])
    if failures:
        doc.add("h2", "Runs that failed (excluded from the means)")
        doc.add("list", failures)
    doc.add("h2", "Figures")
    for path, caption in figs:
        doc.add("figure", path, caption)
    doc.add("h2", "Where our reading departs from the paper's text")
    doc.add("list", DEPARTURES)
    (out / "report.md").write_text(doc.markdown(out), encoding="utf-8")
    (out / "report.html").write_text(doc.html("mttbench paper reproduction"), encoding="utf-8")


# ------------------------------------------------------------------------ main
@dataclass(frozen=True)
class Reproduction:
    out_dir: Path
    numbers: pd.DataFrame
    numbers_csv: Path
    cached: bool


def reproduce_paper(setting: Setting, out_dir: str | Path, cache_dir: str | Path, *,
                    tracker_texts: tuple[str, ...] | None = None, workers: int = 1,
                    progress: bool = True, use_cache: bool = True) -> Reproduction:
    """Run (or load) the setting, write the figures, CSVs and report into ``out_dir``."""
    if tracker_texts:
        setting = dataclasses.replace(setting, trackers=tuple(tracker_texts))
    specs, missing = available_trackers(setting.trackers)
    if not specs:
        raise ValueError(f"none of the trackers {setting.trackers} is registered")
    for name in missing:
        print(f"tracker {name!r} is not registered: left out", file=sys.stderr)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results, traces, cached = run_or_load(setting, specs, Path(cache_dir), workers=workers,
                                          progress=progress, use_cache=use_cache)
    curves = error_curves(results)
    hl = next((s.label for s in specs if s.name == setting.highlight), specs[0].label)
    figs: list[tuple[Path, str]] = []
    snaps: dict[str, pd.DataFrame] = {}
    for sc_name in setting.scenarios:
        sc = scenarios.get(sc_name)
        cv = curves[curves["scenario"] == sc_name]
        cv.to_csv(out / f"error_{sc_name}.csv", index=False)
        figs.append((figures.paper_error_curves(cv, out / f"fig_error_{sc_name}.png",
                                                highlight=setting.highlight),
                     f"Estimation error over time on `{sc_name}`: state error (OSPA) and "
                     f"number error, {hl} bold (black / red as in the paper), others overlaid; "
                     f"mean over {len(setting.seeds)} seeds with 95% bands."))
        if sc_name in traces:
            snap = snapshot_numbers(traces[sc_name], setting.snapshot_steps)
            snaps[sc_name] = snap
            snap.to_csv(out / f"snapshot_{sc_name}.csv", index=False)
            figs.append((figures.snapshot(
                traces[sc_name], out / f"fig_snapshot_{sc_name}.png",
                list(setting.snapshot_steps), sc.grid.nx, sc.grid.ny, sc.grid.cell_size,
                title=f"{hl} on {sc_name}, seed {setting.snapshot_seed}: positive returns "
                      "(magenta), true targets (blue)"),
                f"Snapshot on `{sc_name}` (12x12 grid): looked-at cells, positive returns, "
                f"true targets, {hl} estimates with 95% ellipses."))
    numbers = long_numbers(curves, snaps, hl)
    csv = out / f"numbers_{setting.name}.csv"
    numbers.to_csv(csv, index=False, float_format="%.17g")
    bad = results[results["status"] != "ok"]
    failures = sorted({f"{r.scenario} / {r.tracker_label} seed {r.seed}: {r.error}"
                       for r in bad.itertuples()})
    _write_report(out, setting, specs, missing, figs, failures, cached)
    return Reproduction(out, numbers, csv, cached)


def changed_versions(then: dict[str, str]) -> list[str]:
    """``"pkg old -> new"`` for every package whose version differs from ``then``."""
    now = package_versions()
    return [f"{k} {then.get(k)} -> {now.get(k)}" for k in sorted(set(then) | set(now))
            if then.get(k) != now.get(k)]

"""``mttbench score``: score a tracker that ran elsewhere on exported worlds.

An outside tracker reads a world of :mod:`~mttbench.benchmarks.app.export` (its truth
hidden from it by its author's honesty: the world folder holds the truth too) and writes
its estimates, one row per estimated target and step (CSV or Parquet)::

    step   int >= 0, < the world's n_steps       (required)
    x, y   float, workspace units               (required; both empty on a count-only row)
    label  int, the track's identity            (optional; unique within a step)
    count  float >= 0, the tracker's own count  (optional; the same on every row of a step)

A step without rows is an empty estimate (count 0). A tracker whose own count is not its
number of states (a weight sum) gives the count on every row of the step; a step where it
reports no state but a count takes one **count-only row**: ``step`` and ``count`` given,
``x`` and ``y`` empty. Any other empty, non-numeric or infinite value, a negative step, a
step beyond the world, an unknown or missing column is refused in one line (exit 2).

Scoring builds exactly the rows :func:`~mttbench.benchmarks.engine.loop.run_job` writes for an
in-process tracker: every registered per-step metric
(:func:`~mttbench.benchmarks.engine.metrics.step_metrics`) on the step's true positions
``(n, 2)`` and estimated positions ``(m, 2)`` with the estimate's count, and, when every
state has a label, every run-level (track) metric
(:func:`~mttbench.benchmarks.engine.metrics.run_level_metrics`, and the per-step series of
:mod:`~mttbench.benchmarks.engine.track_series`) on the whole run; without
labels the track scores are NaN, as for an in-process tracker that gives none. The metrics
read positions only, so velocities are not asked for. The tracker is
``outside:NAME`` (name and label); its times and memory are unknown (NaN); it is marked as
not using the truth, which mttbench cannot check. The rows go to ``--out``'s
``results.parquet`` with ``summary.csv``/``summary.md``; ``--beside DIR`` joins them with the
results of a ``run`` or ``compare`` folder on the same worlds (left unchanged) and writes
the summary and the report (``report.md``, ``report.html``, figures) of both side by side.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..engine.loop import COLUMNS, TIMING_COLUMNS, _frame
from ..engine.metrics import (
    RunData,
    cutoff,
    metric_columns,
    run_level_metrics,
    run_metric_columns,
    step_metrics,
)
from ..engine.store import write_text_atomic
from ..engine.track_series import series_values
from .export import (
    CARD,
    FORMAT,
    FORMAT_VERSION,
    LOOKS_COLUMNS,
    MAX_WORLD_STEPS,
    TRUTH_COLUMNS,
    WORLDS_INDEX,
    replace_file,
    sha256_of,
)
from .usage import UsageError

#: columns of an estimates file: required, then optional
REQUIRED = ("step", "x", "y")
OPTIONAL = ("label", "count")
#: the largest magnitude of a position or count: beyond it a squared distance loses
#: every digit (1e160 squared overflows), so the metrics would be meaningless
MAX_ABS = 1e12
#: the largest magnitude of a label: every integer up to it is exact as a float
MAX_LABEL = float(2**53)
#: the tracker name of an outside tracker's rows: ``outside:NAME``
OUTSIDE_PREFIX = "outside:"
_NAME = re.compile(r"[A-Za-z0-9._+-]{1,64}")


# ----------------------------------------------------------------------- worlds
@dataclass(frozen=True)
class WorldFiles:
    """A world read back and checked: its folder, model card, truth and looks tables."""

    folder: Path
    card: dict[str, Any]
    truth: pd.DataFrame
    looks: pd.DataFrame

    @property
    def n_steps(self) -> int:
        return int(self.card["scenario"]["n_steps"])


def _read_table(folder: Path, stem: str, columns: list[str]) -> pd.DataFrame:
    """``<stem>.parquet`` if present, else ``<stem>.csv``, with ``columns`` in order."""
    path = folder / f"{stem}.parquet"
    try:
        df = pd.read_parquet(path) if path.exists() else pd.read_csv(folder / f"{stem}.csv")
    except Exception as exc:  # noqa: BLE001 - pyarrow and pandas raise many types
        raise UsageError(f"world {folder}: cannot read {stem} ({type(exc).__name__})") from None
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise UsageError(f"world {folder}: {stem} has no column {missing[0]!r}")
    return df[columns]


def read_world(folder: str | Path) -> WorldFiles:
    """Read an exported world (``model_card.json``, truth, looks) and check it: format and
    version, and the SHA-256 of every file the card lists that is present (a file changed
    since the export is refused). :class:`UsageError` in one line otherwise."""
    folder = Path(folder)
    try:
        card = json.loads((folder / CARD).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UsageError(f"{folder} is not an exported world (no {CARD}; `mttbench export` "
                         "writes one per world)") from None
    except (OSError, ValueError) as exc:
        raise UsageError(f"{folder / CARD}: cannot read it ({type(exc).__name__})") from None
    if not isinstance(card, dict) or card.get("format") != FORMAT:
        raise UsageError(f"{folder / CARD} is not a {FORMAT} model card")
    if card.get("format_version") != FORMAT_VERSION:
        raise UsageError(f"{folder / CARD}: format version {card.get('format_version')!r}; "
                         f"this mttbench reads version {FORMAT_VERSION}")
    _check_card(folder, card)
    for name, meta in sorted(card["files"].items()):
        path = folder / name
        if path.exists() and sha256_of(path) != meta.get("sha256"):
            raise UsageError(f"world {folder}: {name} does not match its sha256 in {CARD} "
                             "(changed since the export)")
    world = WorldFiles(folder, card, _read_table(folder, "truth", TRUTH_COLUMNS),
                       _read_table(folder, "looks", LOOKS_COLUMNS))
    _check_steps(world)
    return world


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _check_card(folder: Path, card: dict[str, Any]) -> None:
    """Every field scoring reads, its type and range; the tables it reads listed with
    their sha256 (so they are checked against it). :class:`UsageError` in one line."""
    where = folder / CARD

    def bad(text: str) -> UsageError:
        return UsageError(f"{where}: {text}")

    sc, pol, files = card.get("scenario"), card.get("policy"), card.get("files")
    if not isinstance(sc, dict) or not isinstance(pol, dict) or not isinstance(files, dict):
        missing = [k for k, v in (("scenario", sc), ("policy", pol), ("files", files))
                   if not isinstance(v, dict)]
        raise bad(f"no {missing[0]} table (not an exported world's card)")
    checks = [("scenario.name", sc.get("name"), lambda v: isinstance(v, str) and v != ""),
              ("scenario.n_steps", sc.get("n_steps"),
               lambda v: _is_int(v) and 1 <= v <= MAX_WORLD_STEPS),
              ("seed", card.get("seed"), lambda v: _is_int(v) and 0 <= v < 2**63),
              ("policy.name", pol.get("name"), lambda v: isinstance(v, str) and v != ""),
              ("policy.label", pol.get("label"), lambda v: isinstance(v, str) and v != ""),
              ("policy.params", pol.get("params"), lambda v: isinstance(v, dict)),
              ("policy.looks_per_step", pol.get("looks_per_step"),
               lambda v: _is_int(v) and v >= 0)]
    for field, value, ok in checks:
        if not ok(value):
            raise bad(f"{field} = {value!r} is not allowed" if value is not None
                      else f"no {field}")
    for stem in ("truth", "looks"):
        name = f"{stem}.parquet" if (folder / f"{stem}.parquet").exists() else f"{stem}.csv"
        if not isinstance(files.get(name), dict) or not isinstance(
                files[name].get("sha256"), str):
            raise bad(f"lists no sha256 of {name} (not the card of this world)")


def _check_steps(world: WorldFiles) -> None:
    """The card's ``n_steps`` against the tables (whose sha256 were checked): every step
    of the truth and the looks within ``0..n_steps-1``, and with a look budget a look at
    every step."""
    n = world.n_steps
    for stem, df in (("truth", world.truth), ("looks", world.looks)):
        steps = pd.to_numeric(df["step"], errors="coerce")
        if len(steps) and not (steps.notna().all() and steps.min() >= 0 and steps.max() < n):
            raise UsageError(f"world {world.folder}: {stem} has steps outside 0..{n - 1} "
                             f"(its {CARD} says n_steps = {n})")
    if int(world.card["policy"]["looks_per_step"]) > 0 and (
            world.looks["step"].nunique() != n):
        raise UsageError(f"world {world.folder}: its looks cover "
                         f"{world.looks['step'].nunique()} steps, its {CARD} says n_steps = {n}")


def world_folders(path: str | Path) -> list[Path]:
    """The worlds under ``path``: ``path`` itself if it holds a model card, else the
    folders its ``worlds.csv`` lists (an export folder)."""
    path = Path(path)
    if (path / CARD).is_file():
        return [path]
    index = path / WORLDS_INDEX
    if not index.is_file():
        raise UsageError(f"{path} is neither an exported world ({CARD}) nor an export folder "
                         f"({WORLDS_INDEX})")
    try:
        names = pd.read_csv(index, dtype=str, keep_default_na=False)["world"].tolist()
    except Exception as exc:  # noqa: BLE001
        raise UsageError(f"{index}: cannot read it ({type(exc).__name__})") from None
    if not names:
        raise UsageError(f"{index} lists no world")
    for name in names:
        if name in ("", ".", "..") or Path(name).name != name:
            raise UsageError(f"{index}: {name!r} is not a world folder's name")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise UsageError(f"{index} lists the world {twice[0]} twice")
    return [path / n for n in names]


# -------------------------------------------------------------------- estimates
@dataclass(frozen=True)
class StepEstimate:
    """One step of an outside tracker: positions ``(m, 2)``, labels ``(m,)`` int64 or
    None, and its count."""

    positions: np.ndarray
    labels: np.ndarray | None
    count: float


def _float(text: str) -> float | None:
    """``float(text)`` (correctly rounded: a float written in its shortest round-trip form
    reads back bit for bit), None if it is not a number; ``""`` and ``nan`` give NaN."""
    if text == "":
        return math.nan
    try:
        return float(text)
    except ValueError:
        return None


def _bad(path: Path, text: str) -> UsageError:
    return UsageError(f"estimates {path}: {text}")


def _where(df: pd.DataFrame, mask: np.ndarray, csv: bool) -> str:
    """``line N`` (CSV, the header is line 1) or ``row N`` (Parquet, 0-based) of the first
    row where ``mask`` holds."""
    i = int(np.flatnonzero(mask)[0])
    return f"line {i + 2}" if csv else f"row {i}"


def read_estimates(path: str | Path, n_steps: int) -> list[StepEstimate]:
    """An estimates file (see the module docstring) as one :class:`StepEstimate` per step
    ``0..n_steps-1``, the rows of a step in the file's order. :class:`UsageError` (one line
    naming the file, the column and the line) for anything the format refuses."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".parquet"):
        raise _bad(path, "expected a .csv or .parquet file")
    if not path.is_file():
        raise _bad(path, f"no such file ({path.absolute()})")
    csv = suffix == ".csv"
    try:
        df = pd.read_csv(path, dtype=str, keep_default_na=False) if csv \
            else pd.read_parquet(path)
    except Exception as exc:  # noqa: BLE001 - pandas and pyarrow raise many types
        first = (str(exc).strip().splitlines() or [""])[0]
        raise _bad(path, f"cannot read it ({type(exc).__name__}: {first})") from None
    df.columns = [str(c).strip() for c in df.columns]
    missing = [c for c in REQUIRED if c not in df.columns]
    if missing:
        raise _bad(path, f"missing column(s) {', '.join(missing)} (required: step, x, y; "
                         "optional: label, count)")
    unknown = [c for c in df.columns if c not in (*REQUIRED, *OPTIONAL)]
    if unknown:
        raise _bad(path, f"unknown column {unknown[0]!r} (allowed: step, x, y, label, count)")
    values: dict[str, np.ndarray] = {}
    empty: dict[str, np.ndarray] = {}
    for col in df.columns:
        raw = df[col]
        if csv:
            text = raw.astype(str).str.strip().tolist()
            parsed = [_float(t) for t in text]
            bad = np.array([v is None and t != "" for v, t in zip(parsed, text, strict=True)],
                           bool)
            num = pd.Series([math.nan if v is None else v for v in parsed], dtype=float)
        else:
            if not (pd.api.types.is_numeric_dtype(raw) or raw.isna().all()):
                raise _bad(path, f"column {col!r} is not numeric ({raw.dtype})")
            num = pd.to_numeric(raw, errors="coerce").astype(float)
            bad = np.zeros(len(raw), bool)
        empty[col] = num.isna().to_numpy()
        if bad.any():
            raise _bad(path, f"{col} {df[col].iloc[int(np.flatnonzero(bad)[0])]!r} on "
                             f"{_where(df, bad, csv)} is not a number")
        values[col] = num.to_numpy(dtype=float)
        if np.isinf(values[col]).any():
            raise _bad(path, f"{col} is infinite on {_where(df, np.isinf(values[col]), csv)}")
        limit = MAX_LABEL if col == "label" else MAX_ABS
        huge = np.abs(np.nan_to_num(values[col])) > limit
        if huge.any():
            raise _bad(path, f"{col} {values[col][huge][0]:g} on {_where(df, huge, csv)} is "
                             f"beyond +-{limit:g}")
    if empty["step"].any():
        raise _bad(path, f"step is empty or NaN on {_where(df, empty['step'], csv)}")
    step = values["step"]
    if (step != np.round(step)).any():
        raise _bad(path, f"step {step[step != np.round(step)][0]!r} on "
                         f"{_where(df, step != np.round(step), csv)} is not an integer")
    if (step < 0).any():
        raise _bad(path, f"negative step {int(step[step < 0][0])} on "
                         f"{_where(df, step < 0, csv)}")
    if (step >= n_steps).any():
        raise _bad(path, f"step {int(step[step >= n_steps][0])} on "
                         f"{_where(df, step >= n_steps, csv)} is beyond the world (steps 0.."
                         f"{n_steps - 1})")
    has_count = "count" in df.columns
    # a count-only row: x and y both empty (or NaN), a count given
    count_only = empty["x"] & empty["y"]
    count_only &= ~empty["count"] if has_count else np.zeros(len(df), bool)
    for col in ("x", "y"):
        hole = empty[col] & ~count_only
        if hole.any():
            raise _bad(path, f"{col} is empty or NaN on {_where(df, hole, csv)} (only a "
                             "count-only row, with a count, leaves both x and y empty)")
    if has_count:
        count = values["count"]
        if empty["count"].any():
            raise _bad(path, f"count is empty or NaN on {_where(df, empty['count'], csv)} "
                             "(give it on every row, or drop the column)")
        if (count < 0).any():
            raise _bad(path, f"negative count on {_where(df, count < 0, csv)}")
    labels = None
    if "label" in df.columns:
        hole = empty["label"] & ~count_only
        if hole.any():
            raise _bad(path, f"label is empty or NaN on {_where(df, hole, csv)} (give one "
                             "on every state row, or drop the column)")
        lab = values["label"]
        frac = ~empty["label"] & (lab != np.round(lab))
        if frac.any():
            raise _bad(path, f"label on {_where(df, frac, csv)} is not an integer")
        labels = np.where(empty["label"], 0, lab).astype(np.int64)
    steps = step.astype(np.int64)
    out = [StepEstimate(np.zeros((0, 2)), None if labels is None else np.zeros(0, np.int64), 0.0)
           for _ in range(n_steps)]
    order = np.argsort(steps, kind="stable")
    bounds = np.searchsorted(steps[order], np.arange(n_steps + 1))
    for k in np.unique(steps):
        rows = order[bounds[k]:bounds[k + 1]]
        states = rows[~count_only[rows]]
        pos = np.stack([values["x"][states], values["y"][states]], axis=1)
        lab_k = None if labels is None else labels[states]
        if lab_k is not None and len(np.unique(lab_k)) != len(lab_k):
            raise _bad(path, f"labels repeat within step {k}")
        if has_count:
            counts = values["count"][rows]
            if (counts != counts[0]).any():
                raise _bad(path, f"step {k} gives different counts on its rows")
            n = float(counts[0])
        else:
            n = float(len(states))
        out[k] = StepEstimate(pos, lab_k, n)
    return out


# ----------------------------------------------------------------------- rows
def check_name(name: str) -> str:
    """An outside tracker's name: 1-64 letters, digits, ``.``, ``_``, ``+``, ``-``."""
    if not _NAME.fullmatch(name or ""):
        raise UsageError(f"--name {name!r} is not allowed: expected 1 to 64 letters, digits, "
                         "'.', '_', '+' or '-'")
    return name


def score_world(world: WorldFiles, estimates: Sequence[StepEstimate], name: str,
                c: float | None = None, p: float = 2.0) -> pd.DataFrame:
    """The results rows of an outside tracker ``outside:NAME`` on ``world``: one per step,
    with the columns and metric values :func:`~mttbench.benchmarks.engine.loop.run_job`
    writes (timings and memory NaN), and the run-level scores when labelled."""
    card = world.card
    c = cutoff(c, float(card["grid"]["cell_size"]))  # None: 2 cells
    pol = card["policy"]
    label = OUTSIDE_PREFIX + name
    base = {"scenario": card["scenario"]["name"], "tracker": label, "tracker_label": label,
            "tracker_params": "{}", "policy": pol["name"], "policy_label": pol["label"],
            "policy_params": json.dumps(pol["params"], sort_keys=True, default=str),
            "tracker_uses_truth": False, "policy_uses_truth": False,
            "looks_per_step": int(pol["looks_per_step"]), "seed": int(card["seed"]),
            "ospa_c": float(c), "ospa_p": float(p), "peak_rss_mb": math.nan}
    n = world.n_steps
    truth, looks = world.truth, world.looks
    t_steps = truth["step"].to_numpy(np.int64)
    t_bounds = np.searchsorted(t_steps, np.arange(n + 1))
    pos = truth[["px", "py"]].to_numpy(float)
    ids = truth["target_id"].to_numpy(np.int64)
    n_looks = np.bincount(looks["step"].to_numpy(np.int64), minlength=n)
    n_pos = np.bincount(looks["step"].to_numpy(np.int64),
                        weights=looks["return"].to_numpy(float), minlength=n)
    rows, run = [], [[], [], [], []]
    labelled = True
    for k in range(n):
        est = estimates[k]
        x = pos[t_bounds[k]:t_bounds[k + 1]]
        m = step_metrics(x, est.positions, est.count, c=c, p=p)
        labelled = labelled and est.labels is not None
        for acc, v in zip(run, (x, ids[t_bounds[k]:t_bounds[k + 1]], est.positions,
                                est.labels), strict=True):
            acc.append(v)
        rows.append({**base, "step": k, "true_count": float(len(x)), "est_count": est.count,
                     **{col: float(m[col]) for col in metric_columns()},
                     "n_looks": int(n_looks[k]), "n_positive": int(n_pos[k]),
                     **dict.fromkeys(TIMING_COLUMNS, math.nan), "status": "ok", "error": ""})
    values = dict.fromkeys(run_metric_columns(), math.nan)
    series: dict[str, np.ndarray] = {}
    if values:  # as run_job: the run's scores on every row, a series' value k on row k
        t, i, e, lab = run
        whole = RunData(t, i, e, lab if labelled else None, c=c, p=p)
        values.update(run_level_metrics(whole))
        series = series_values(whole)
    for k, r in enumerate(rows):
        r.update(values)
        r.update((col, float(v[k])) for col, v in series.items())
    return _frame(rows)


# ----------------------------------------------------------------------- command
@dataclass(frozen=True)
class ScoreOutput:
    """What :func:`run_score` wrote: the outside rows, the table summarised (with the
    ``--beside`` rows when given) and the files."""

    rows: pd.DataFrame
    table: pd.DataFrame
    files: list[str]


def load_beside(folder: str | Path, rows: pd.DataFrame, c: float | None, p: float
                ) -> pd.DataFrame:
    """The ``results.parquet`` of a ``run``/``compare`` folder, checked against the outside
    ``rows``: the same ``c`` and ``p``, and at least one run on each of their worlds
    ``(scenario, policy_label, looks_per_step, seed)``."""
    path = Path(folder) / "results.parquet"
    if not path.is_file():
        raise UsageError(f"--beside {folder}: no results.parquet (a folder written by "
                         "`mttbench run` or `mttbench compare`)")
    try:
        other = pd.read_parquet(path)
    except Exception as exc:  # noqa: BLE001
        raise UsageError(f"--beside {path}: cannot read it ({type(exc).__name__})") from None
    missing = [col for col in COLUMNS if col not in other.columns]
    if missing:
        raise UsageError(f"--beside {path}: not a results table (no column {missing[0]!r})")
    cp = other[["ospa_c", "ospa_p"]].dropna().drop_duplicates()
    mine = set(map(tuple, rows[["ospa_c", "ospa_p"]].dropna().to_numpy().tolist()))
    if len(cp) and not all(tuple(x) in mine for x in cp.to_numpy().tolist()):
        raise UsageError(f"--beside {path}: its runs were scored with c = "
                         f"{cp['ospa_c'].iloc[0]:g}, p = {cp['ospa_p'].iloc[0]:g}; give the "
                         "same --c and --p")
    world = ["scenario", "policy_label", "looks_per_step", "seed"]
    have = set(map(tuple, other[world].astype(str).to_numpy()))
    for key in map(tuple, rows[world].drop_duplicates().astype(str).to_numpy()):
        if key not in have:
            raise UsageError(f"--beside {path}: no run on the world scenario {key[0]}, policy "
                             f"{key[1]}, {key[2]} looks, seed {key[3]}")
    # the steps of their finished rows on each world (a run that failed early is shorter)
    mine = rows.astype({c: str for c in world}).groupby(world)["step"].max()
    ok = other[other["status"] == "ok"].astype({c: str for c in world})
    theirs = ok.groupby(world)["step"].max().reindex(mine.index)
    differ = np.flatnonzero((theirs.notna() & (theirs != mine)).to_numpy())
    if len(differ):
        i = int(differ[0])
        key = mine.index[i]
        raise UsageError(f"--beside {path}: its runs on the world scenario {key[0]}, policy "
                         f"{key[1]}, {key[2]} looks, seed {key[3]} have {int(theirs.iloc[i]) + 1} "
                         f"steps, the world {int(mine.iloc[i]) + 1}; run them with the "
                         "world's --steps")
    clash = set(other["tracker_label"].astype(str)) & set(rows["tracker_label"].astype(str))
    if clash:
        raise UsageError(f"--beside {path}: it already holds {sorted(clash)[0]!r}; choose "
                         "another --name")
    return other


def _reference(table: pd.DataFrame) -> str | None:
    """``kfnn`` when it ran, else the first tracker that neither uses the truth nor is
    outside, else None."""
    labels = table.loc[~table["tracker_uses_truth"].astype(bool), "tracker_label"].astype(str)
    inside = sorted({lab for lab in labels if not lab.startswith(OUTSIDE_PREFIX)})
    return "kfnn" if "kfnn" in inside else (inside[0] if inside else None)


def run_score(world_dir: str | Path, estimates: str, name: str | None, out_dir: str | Path,
              c: float | None = None, p: float = 2.0, beside: str | Path | None = None,
              draw: bool = True) -> ScoreOutput:
    """Score ``estimates`` on the worlds of ``world_dir`` (one world, or an export folder:
    then ``estimates`` is a path relative to each world's folder) and write ``out_dir``:
    ``results.parquet`` (the outside rows; with ``beside``, those of the other folder too),
    ``summary.csv``, ``summary.md``, and with ``beside`` ``report.md``, ``report.html``
    and ``figures/``. Every input is read and checked before anything is written."""
    from ..engine.store import prepare_out_dir, sort_results
    from .summary import write_summary

    folders = world_folders(world_dir)
    single = len(folders) == 1 and (Path(world_dir) / CARD).is_file()
    name = check_name(name if name is not None else Path(estimates).stem)
    if not single and Path(estimates).is_absolute():
        raise UsageError(f"--estimates {estimates} is an absolute path: with an export folder "
                         "it is each world's own file, relative to the world's folder")
    frames = []
    for folder in folders:
        world = read_world(folder)
        est_path = Path(estimates) if single else folder / estimates
        frames.append(score_world(world, read_estimates(est_path, world.n_steps), name, c, p))
    rows = sort_results(pd.concat(frames, ignore_index=True))
    table = rows
    if beside is not None:
        other = load_beside(beside, rows, c, p)
        table = sort_results(pd.concat([other, rows], ignore_index=True))
    out = prepare_out_dir(out_dir, parts=False)
    replace_file(out / "results.parquet", lambda tmp: table.to_parquet(tmp, index=False))
    title = f"mttbench score: outside:{name}" + (f" beside {beside}" if beside else "")
    write_summary(table, out, title)
    files = ["results.parquet", "summary.csv", "summary.md"]
    if beside is not None:
        from .report import build_report

        build_report(table, out, reference=_reference(table), title=title, draw=draw,
                     intro=[f"Rows of `outside:{name}` scored by `mttbench score` from its "
                            f"estimates on exported worlds, beside the runs of {beside}. An "
                            "outside tracker's times and memory are unknown (blank)."])
        files += ["report.md", "report.html", "figures/"]
    write_text_atomic(out / "score.json", json.dumps(
        {"name": name, "tracker": OUTSIDE_PREFIX + name, "worlds": [str(f) for f in folders],
         "estimates": str(estimates), "c": c, "p": p,
         "beside": None if beside is None else str(beside)}, indent=1) + "\n")
    return ScoreOutput(rows, table, [*files, "score.json"])

"""Tuned parameter files (``tuned/<tracker>.toml``): their format, where they live, and
how ``mttbench compare`` runs them.

``mttbench tune`` (:mod:`~mttbench.benchmarks.app.tune`) writes one file per tracker with the
best parameters it found and their provenance; ``compare`` runs every tracker that has a
file with those parameters (``--untuned``: the defaults) and says so in every table: the
tracker's label reads ``kfnn(tuned)`` (``jmpd-ap(tuned,n_particles=250)`` with parameters
given on the command line, which win over the file's), and the summary and the report
list, per tracker, the parameters that ran, where they came from and what tuning gained
on the tuning seeds. ``compare --tuning-effect`` also runs each tuned tracker's defaults
(label ``kfnn``) on the same evaluation seeds and adds a table "Effect of tuning":
tuned minus default, paired by seed, with 95% t intervals. The tuning seeds are disjoint
from the evaluation seeds (tuning starts at :data:`TUNING_SEED_BASE`; ``--seeds N``
gives ``0..N-1`` with ``N <= 1,000,000``); ``compare`` refuses evaluation seeds that a
tuned file was tuned on.

Where the files live (:func:`default_tuned_dir`): the folder ``tuned/`` next to the
package's layer folders. In a checkout (or an editable install) that is the repository's
``tuned/``, checked in; a built package ships it as ``mttbench/tuned/`` (package data),
so an installed ``mttbench compare`` runs the parameters that were checked in when it was
built. ``--tuned-dir DIR`` reads (``compare``) or writes (``tune``) another folder; from
an installed package ``tune`` writes ``./tuned`` unless told otherwise (it never writes
into the installed package).

File format (TOML; ``None`` values are left out)::

    format = 1
    tracker = "kfnn"
    source = "trial 17"        # or "defaults": no trial beat the defaults
    [params]                   # the searched parameters compare applies ({}: defaults)
    [fixed]                    # parameters given to tune and held fixed
    [objective]                # metric, c, p, value, default_value, per-scenario values
    [budget]                   # trials, tuning_seeds, scenarios, steps, policy, looks, runs
    [search]                   # the search space, one line per parameter
    [sampler]                  # TPE settings, seed, batch size
    [provenance]               # date, command, git commit, versions, study folder
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from ..engine.errors import first_line
from ..engine.specs import TrackerSpec
from ..engine.store import write_text_atomic
from .summary import mean_ci95, paired_difference, per_run
from .usage import UsageError

#: first seed of the tuning seeds; evaluation seeds (``--seeds N``: ``0..N-1``, at most
#: 1,000,000 of them) never reach it
TUNING_SEED_BASE = 1_000_000
#: version of the file format
FORMAT = 1
#: the mark in the label of a tracker run with tuned parameters
TUNED_MARK = "tuned"
_PACKAGE_ROOT = Path(__file__).resolve().parents[2]


def default_tuned_dir() -> Path:
    """The tuned parameters the package runs: ``tuned/`` beside the layer folders (the
    checkout's ``tuned/``, or ``mttbench/tuned/`` of an installed package)."""
    return _PACKAGE_ROOT / "tuned"


def is_checkout() -> bool:
    """True when the package runs from a source checkout (an editable install)."""
    return (_PACKAGE_ROOT / "pyproject.toml").is_file()


def default_write_dir() -> Path:
    """Where ``tune`` writes without ``--tuned-dir``: the checkout's ``tuned/``, or
    ``./tuned`` from an installed package."""
    return default_tuned_dir() if is_checkout() else Path("tuned")


def has_search(cls: type) -> bool:
    """True if a parameter of tracker class ``cls`` declares a search range."""
    declared = getattr(cls, "declared_parameters", lambda: None)() or {}
    return any(p.search is not None for p in declared.values())


def tuned_path(tuned_dir: str | Path, name: str) -> Path:
    return Path(tuned_dir) / f"{name}.toml"


# ----------------------------------------------------------------------- the file
def _drop_none(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _drop_none(v) for k, v in value.items() if v is not None}
    if isinstance(value, list | tuple):
        return [_drop_none(v) for v in value if v is not None]
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)
    return value


def dumps(record: Mapping[str, Any]) -> str:
    """The TOML text of a tuned-file record (``None`` values left out)."""
    import tomli_w

    head = "# written by `mttbench tune`; `mttbench compare` runs [params] (see tuned.py)\n"
    return head + tomli_w.dumps(_drop_none(record))


def write_tuned(path: str | Path, record: Mapping[str, Any]) -> Path:
    """Write ``record`` as TOML to ``path``, all or nothing (the folder is created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, dumps(record))
    return path


@dataclass(frozen=True)
class TunedFile:
    """A tuned file as read: ``params`` (what ``compare`` applies), ``fixed``, the
    objective on the tuning seeds (``value``, ``default_value``: None when the defaults
    failed), ``seeds`` (the tuning seeds) and the whole ``record``."""

    path: Path
    tracker: str
    params: dict[str, Any]
    fixed: dict[str, Any]
    metric: str
    value: float
    default_value: float | None
    seeds: tuple[int, ...]
    record: dict[str, Any] = field(repr=False)

    def budget_text(self) -> str:
        """``24 trials x 3 tuning seeds x 4 scenarios (100 steps)``."""
        b = self.record.get("budget", {})
        steps = sorted(set((b.get("steps") or {}).values()))
        step_text = "/".join(map(str, steps)) + " steps" if steps else "scenario lengths"
        return (f"{b.get('trials', '?')} trials x {len(self.seeds)} tuning seeds x "
                f"{len(b.get('scenarios', []))} scenarios ({step_text})")


def read_tuned(path: str | Path) -> TunedFile:
    """Read and check a tuned file: the tracker must be registered (or importable) and
    every parameter one it accepts; ``UsageError`` (one line naming the file) if not."""
    path = Path(path)
    try:
        record = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise UsageError(f"tuned file {path}: {first_line(exc)}") from None
    try:
        name = record["tracker"]
        params = dict(record.get("params", {}))
        fixed = dict(record.get("fixed", {}))
        obj = record["objective"]
        seeds = tuple(int(s) for s in record["budget"]["tuning_seeds"])
        metric, value = str(obj["metric"]), float(obj["value"])
        default = obj.get("default_value")
    except (KeyError, TypeError, ValueError) as exc:
        raise UsageError(f"tuned file {path}: missing or bad field {first_line(exc)}") from None
    try:
        params = TrackerSpec(name, params).target().validate_params(params, name=name)
    except Exception as exc:  # noqa: BLE001 - unknown tracker, parameter or value
        raise UsageError(f"tuned file {path}: {first_line(exc)} (tune again, or run "
                         "compare --untuned)") from None
    return TunedFile(path, name, params, fixed, metric, value,
                     None if default is None else float(default), seeds, record)


def find_tuned(tuned_dir: str | Path, name: str) -> TunedFile | None:
    """The tuned file of tracker ``name`` in ``tuned_dir``, or None if there is none."""
    path = tuned_path(tuned_dir, name)
    return read_tuned(path) if path.is_file() else None


# ------------------------------------------------------------------ compare's side
@dataclass(frozen=True, eq=False)
class TunedTrackerSpec(TrackerSpec):
    """A tracker with tuned parameters: ``params`` are the tuned file's with the ``given``
    ones (from the command line) over them; the label is ``name(tuned[,given k=v])``."""

    given: dict[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str:
        extra = [f"{k}={self.given[k]}" for k in sorted(self.given)]
        return f"{self.name}(" + ",".join([TUNED_MARK, *extra]) + ")"


@dataclass(frozen=True)
class ParamSource:
    """Where one setting's parameters came from: ``tuned`` is the file applied (None: the
    defaults), ``why`` a few words, ``params`` every parameter as it ran."""

    label: str
    name: str
    tuned: TunedFile | None
    why: str
    params: dict[str, Any]
    given: dict[str, Any]
    #: the label of the default setting run beside a tuned one (``--tuning-effect``)
    default_of: str | None = None


@dataclass(frozen=True)
class TuningPlan:
    """``specs`` to run (tuned ones replacing their defaults, plus the defaults again with
    ``--tuning-effect``), ``main`` (the settings the comparison is about: without the
    extra defaults) and one :class:`ParamSource` per label of ``specs``."""

    specs: list[TrackerSpec]
    main: list[TrackerSpec]
    sources: dict[str, ParamSource]
    tuned_dir: Path
    untuned: bool

    @property
    def pairs(self) -> list[tuple[str, str]]:
        """``(default label, tuned label)`` of each tracker run both ways."""
        return [(s.default_of, s.label) for s in self.sources.values() if s.default_of]


def tuned_scenarios(plan: TuningPlan) -> dict[str, frozenset[str]]:
    """Label -> the scenarios its tuned file was tuned on, for every setting that runs a
    tuned file (the report marks the rows out of sample for it)."""
    return {label: frozenset(str(sc) for sc in
                             src.tuned.record.get("budget", {}).get("scenarios", []))
            for label, src in plan.sources.items() if src.tuned is not None}


def plan_tuning(specs: Sequence[TrackerSpec], tuned_dir: str | Path | None = None,
                seeds: Sequence[int] = (), untuned: bool = False,
                tuning_effect: bool = False) -> TuningPlan:
    """Apply the tuned files of ``tuned_dir`` (None: :func:`default_tuned_dir`) to the
    resolved ``specs``: a tracker with a file runs its tuned parameters under the label
    ``name(tuned...)``, parameters given in the spec over the file's; ``untuned`` applies
    none. With ``tuning_effect`` each tuned tracker also runs its defaults (its original
    spec), first (unless the tuned parameters are the defaults). ``UsageError`` if an
    evaluation seed is one a file was tuned on, or a tuned file is bad."""
    tuned_dir = Path(tuned_dir) if tuned_dir is not None else default_tuned_dir()
    main: list[TrackerSpec] = []
    extra: list[TrackerSpec] = []
    sources: dict[str, ParamSource] = {}
    where = show_path(tuned_dir)
    for spec in specs:
        cls = spec.target()
        resolved = cls.resolved_params(spec.params, name=spec.name)
        tf = None if untuned else find_tuned(tuned_dir, spec.name)
        if tf is None:
            why = ("defaults (nothing to tune: no parameter declares a search range)"
                   if not has_search(cls) else "defaults (--untuned)" if untuned
                   else f"defaults (no {where}/{spec.name}.toml)")
            main.append(spec)
            sources[spec.label] = ParamSource(spec.label, spec.name, None, why, resolved,
                                              dict(spec.params))
            continue
        overlap = sorted(set(seeds) & set(tf.seeds))
        if overlap:
            raise UsageError(f"evaluation seed(s) {overlap[:5]} were used to tune {spec.name} "
                             f"({tf.path}); evaluate on other seeds, or run --untuned")
        merged = {**tf.params, **spec.params}
        try:
            merged = cls.validate_params(merged, name=spec.name)
            full = cls.resolved_params(merged, name=spec.name)
        except Exception as exc:  # noqa: BLE001 - a conflict of given and tuned values
            raise UsageError(f"{first_line(exc)} (with the tuned parameters of {tf.path}; "
                             "--untuned runs the defaults)") from None
        tuned_spec = TunedTrackerSpec(spec.name, merged, given=dict(spec.params))
        main.append(tuned_spec)
        default_of = None
        if tuning_effect and full != resolved:
            extra.append(spec)
            default_of = spec.label
            sources[spec.label] = ParamSource(
                spec.label, spec.name, None, f"defaults, beside {tuned_spec.label} (the "
                "effect of tuning)", resolved, dict(spec.params))
        sources[tuned_spec.label] = ParamSource(
            tuned_spec.label, spec.name, tf, f"tuned ({show_path(tf.path)})", full,
            dict(spec.params), default_of)
    labels = [s.label for s in [*extra, *main]]
    if len(set(labels)) != len(labels):
        raise UsageError(f"a tracker is given more than once: {labels}")
    return TuningPlan([*extra, *main], main, sources, tuned_dir, untuned)


def show_path(path: Path) -> str:
    """A path relative to the working directory when it is below it."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def _value_text(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _params_text(params: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={_value_text(v)}" for k, v in sorted(params.items())) or "–"


def _seed_text(seeds: Sequence[int]) -> str:
    s = list(seeds)
    if s and s == list(range(s[0], s[0] + len(s))):
        return f"{s[0]}..{s[-1]}" if len(s) > 1 else str(s[0])
    return ", ".join(map(str, s))


def tuning_seed_text(tf: TunedFile) -> str:
    """``mean OSPA 1.234 against 1.300 with the defaults on tuning seeds ...``."""
    name = tf.metric.upper()
    default = ("the defaults failed" if tf.default_value is None
               else f"against {tf.default_value:.3f} with the defaults")
    return (f"mean {name} {tf.value:.3f} {default} on tuning seeds {_seed_text(tf.seeds)} "
            f"({tf.budget_text()})")


def parameter_notes(plan: TuningPlan) -> list[str]:
    """One line per setting: the parameters that ran and whether they were tuned (for
    ``summary.md``)."""
    out = []
    for s in plan.sources.values():
        if s.tuned is None:
            given = f": {_params_text(s.given)}" if s.given else ""
            out.append(f"`{s.label}`: {s.why}{given}.")
        else:
            src = s.tuned.record.get("source", "")
            out.append(f"`{s.label}`: tuned parameters from {show_path(s.tuned.path)} "
                       f"({_params_text(s.tuned.params) if s.tuned.params else 'the defaults'}"
                       f"{'; ' + src if src else ''}"
                       f"{'; given: ' + _params_text(s.given) if s.given else ''}): "
                       f"{tuning_seed_text(s.tuned)}.")
    return out


def parameters_table(plan: TuningPlan) -> pd.DataFrame:
    """One row per setting: tracker label, tuned or not, the tuned and given parameters,
    and the tuning objective on the tuning seeds."""
    rows = []
    for s in plan.sources.values():
        tf = s.tuned
        rows.append({
            "tracker": s.label,
            "parameters": s.why,
            "tuned values": _params_text(tf.params) if tf is not None else "–",
            "given": _params_text(s.given),
            "on the tuning seeds": tuning_seed_text(tf) if tf is not None else "–",
        })
    return pd.DataFrame(rows)


def tuning_effect_table(results: pd.DataFrame, plan: TuningPlan,
                        metric: str = "ospa") -> pd.DataFrame:
    """Per scenario and tuned tracker run both ways: the default's and the tuned
    setting's mean ``metric`` over the evaluation seeds (± 95% t half-width), and the
    paired difference tuned minus default (negative: tuning helped)."""
    pairs = plan.pairs
    if not pairs or results.empty:
        return pd.DataFrame()
    runs = per_run(results)
    ok = runs[runs["status"] == "ok"]
    rows = []
    for default_label, tuned_label in pairs:
        sub = runs[runs["tracker_label"].isin([default_label, tuned_label])]
        try:
            diff = paired_difference(sub, default_label, metric)
        except ValueError:
            continue
        for r in diff[diff["tracker_label"] == tuned_label].itertuples(index=False):
            cells = {}
            for lab, head in ((default_label, "default"), (tuned_label, "tuned")):
                v = ok[(ok["tracker_label"] == lab) & (ok["scenario"] == r.scenario)
                       & (ok["policy_label"] == r.policy_label)
                       & (ok["looks_per_step"] == r.looks_per_step)][metric]
                m, h = mean_ci95(v.to_numpy(dtype=float))
                cells[head] = _pm(m, h)
            rows.append({"scenario": r.scenario, "tracker": tuned_label.split("(")[0],
                         f"default {metric.upper()}": cells["default"],
                         f"tuned {metric.upper()}": cells["tuned"],
                         "tuned - default (paired)": _pm(r.diff_mean, r.diff_ci95),
                         "pairs": int(r.n_seeds)})
    return pd.DataFrame(rows)


def _pm(mean: float, half: float) -> str:
    if mean is None or math.isnan(mean):
        return "–"
    return f"{mean:.3f} ± {'n/a' if math.isnan(half) else f'{half:.3f}'}"


def report_sections(plan: TuningPlan, results: pd.DataFrame) -> list[tuple[Any, ...]]:
    """Report blocks (:class:`~mttbench.benchmarks.app.report.Document`): "Parameters" (which
    ran, tuned or not) and "Effect of tuning" (on the tuning seeds from the files; on the
    evaluation seeds when the defaults ran beside the tuned settings)."""
    blocks: list[tuple[Any, ...]] = [
        ("h2", "Parameters"),
        ("p", "Which parameters each tracker ran. A label `name(tuned)` runs the parameters "
              "of its tuned file (written by `mttbench tune` on tuning seeds >= "
              f"{TUNING_SEED_BASE:,}, disjoint from the evaluation seeds; parameters given "
              "on the command line win over the file's); a bare name runs its defaults. "
              f"Tuned files: {show_path(plan.tuned_dir)}"
              + (" (not used: --untuned)." if plan.untuned else ".")),
        ("table", parameters_table(plan)),
    ]
    tuned = [s for s in plan.sources.values() if s.tuned is not None]
    if not tuned:
        return blocks
    blocks.append(("h2", "Effect of tuning"))
    blocks.append(("p", "On the tuning seeds (in-sample, so optimistic): "
                        + "; ".join(f"`{s.name}` {tuning_seed_text(s.tuned)}" for s in tuned)
                        + "."))
    table = tuning_effect_table(results, plan)
    if table.empty:
        blocks.append(("p", "Not measured on the evaluation seeds: run `mttbench compare "
                            "--tuning-effect` to run each tuned tracker's defaults beside it "
                            "on the same worlds."))
    else:
        blocks.append(("p", "On the evaluation seeds: each tuned tracker and its defaults on "
                            "the same worlds; tuned minus default per seed, mean ± 95% t "
                            "half-width over the pairs (negative: tuning helped)."))
        blocks.append(("table", table))
    return blocks

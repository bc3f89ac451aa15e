"""``mttbench tune``: the same tuning budget for every tracker, on seeds held apart.

**Search space.** A tracker's searched parameters are those whose :class:`Param` declares
``search=Search(...)`` (:mod:`mttbench.trackers.params`; a range outside what the
parameter accepts is refused when the class is defined), minus the parameters given in
the tracker spec (``jmpd-ap:n_particles=250`` holds ``n_particles`` fixed). Each maps to
optuna's ``suggest_*`` (:func:`suggest`): numbers to ``suggest_float(low, high, log,
step)`` or, for an ``int`` parameter, ``suggest_int``; choices to ``suggest_categorical``.

**Objective** (minimised): for a parameter setting, every scenario x tuning seed is one
harness run (:func:`~mttbench.benchmarks.engine.loop.run_job`: the raster policy at each
scenario's look budget unless ``policy``/``looks`` say otherwise); each run's per-step
value of the objective metric (``objective``: OSPA by default; any metric registered with
``objective=True``, :func:`~mttbench.benchmarks.engine.metrics.objective_names`) is
averaged over its steps, then over the seeds, then over the scenarios
(:func:`objective_value`, the convention of :mod:`~mttbench.benchmarks.app.summary`). A
run that fails (an ``error`` or ``unsupported`` row) fails the trial (optuna state FAIL,
its message kept in the trial's ``message`` attribute and in ``trials.csv``); a setting
that breaks a rule between parameters (``param_conflict``) fails without runs. The study
goes on either way.

**Seeds.** The tuning seeds are ``TUNING_SEED_BASE, TUNING_SEED_BASE + 1, ...``
(1,000,000 up); evaluation seeds are ``0..N-1`` with ``N <= 1,000,000`` (``--seeds``), so
the two never meet, and ``compare`` refuses a ``--seed-list`` that reaches a tuned file's
tuning seeds.

**Budget**, the same for every tracker and stated in the output: ``trials`` settings x
``tuning seeds`` x ``scenarios`` runs of the stated length, plus one more setting's runs
for the defaults (their objective on the same seeds, so the tuned file shows what tuning
gained). Trials in a failed or repeated setting count against the budget.

**Search and parallelism.** A seeded TPE sampler (optuna's; the first
``startup_trials`` trials are random, multivariate with the constant liar for trials
asked together). Trials go in batches of ``batch_size`` (default: the workers): the
batch's trials are asked, all their runs (trials x scenarios x seeds, and the defaults'
with the first batch) go to one :func:`~mttbench.benchmarks.engine.sweep.run_sweep` call on
its executor, then each trial is told its value. The sampler of trial ``n`` is seeded
from ``(seed, n)`` (:func:`trial_seed`) rather than drawn from one stream, so the trials
depend only on the seed, the batch size and the values of the earlier trials: the same
settings give the same trials on any number of workers, and a study interrupted at any
point and resumed gives the trials of an uninterrupted one: a trial is drawn on an
in-memory copy of the study and reaches the journal whole, in one write (:func:`_draw`),
so an interrupt or a kill leaves either no trial or a whole one; trials left ``RUNNING``
are run again with their stored parameters; finished runs are read back from
``parts/``. The journal's lock is an ``flock`` (:class:`_JournalLock`), which no
interrupt or kill can leave behind.

**Files.** ``out/`` (default ``reports/tune-<UTC timestamp>``) holds ``manifest.json``,
``parts/`` (one file per run: job-level resume), ``results.parquet`` (every run of the
study once it is finished) and per tracker ``<tracker>/study.journal`` (optuna's journal
storage: ``--resume`` continues it), ``<tracker>/trials.csv`` (every trial) and
``<tracker>/tuned.toml``; the best parameters go to ``<tuned_dir>/<tracker>.toml``
(:mod:`~mttbench.benchmarks.app.tuned`: format, location, how ``compare`` uses them). When no
trial beats the defaults on the tuning seeds, the file says so and holds no parameters
(``compare`` then runs the defaults, labelled tuned).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import math
import os
import platform
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...scenarios.spec import Scenario
from ...trackers.params import Param, Search
from ..engine.errors import first_line
from ..engine.loop import Job, build_jobs
from ..engine.metrics import objective_names
from ..engine.specs import PolicySpec, TrackerSpec
from ..engine.store import check_sweep, prepare_out_dir, write_text_atomic
from .compare import git_commit, package_versions, read_manifest
from .progress import run_sweep
from .summary import per_run
from .tuned import FORMAT, TUNING_SEED_BASE, default_write_dir, tuned_path, write_tuned
from .usage import UsageError

#: defaults of ``mttbench tune`` (the budget is the same for every tracker): about 20
#: minutes for kfnn, gpf, jmpd-ap (N = 250), ss-gnn and ss-gmphd on a quiet 2-core
#: machine, about 55 on a busy one (docs/tune.md)
TUNE_SCENARIOS = ("default", "crossing", "births", "large")
TUNE_TRIALS = 30
TUNE_SEEDS = 4
#: random trials before TPE models the results (optuna's default)
STARTUP_TRIALS = 10
#: files a finished tune leaves in its folder (per tracker: study.journal, trials.csv,
#: tuned.toml)
OUTPUT_FILES = ("manifest.json", "parts/", "results.parquet")


# -------------------------------------------------------------------- search space
def search_space(cls: type, fixed: Mapping[str, Any] = ()) -> dict[str, tuple[Param, Search]]:
    """``{parameter: (Param, Search)}`` of the declared parameters of ``cls`` with a
    ``search``, in declaration order, without those in ``fixed``."""
    declared = cls.declared_parameters() or {}
    fixed = dict(fixed)
    return {n: (p, p.search) for n, p in declared.items()
            if p.search is not None and n not in fixed}


def suggest(trial: Any, space: Mapping[str, tuple[Param, Search]]) -> dict[str, Any]:
    """Draw one value per parameter of ``space`` from an optuna trial: choices by
    ``suggest_categorical``, an ``int`` parameter by ``suggest_int(low, high, step, log)``,
    a ``float`` one by ``suggest_float(low, high, step, log)``. Returns the values in the
    parameters' canonical types."""
    out: dict[str, Any] = {}
    for name, (param, s) in space.items():
        if s.choices:
            value = trial.suggest_categorical(name, list(s.choices))
        elif param.kind is int:
            value = trial.suggest_int(name, int(s.low), int(s.high),
                                      step=int(s.step) if s.step else 1, log=s.log)
        else:
            value = trial.suggest_float(name, float(s.low), float(s.high), step=s.step,
                                        log=s.log)
        out[name] = param.parse(value)
    return out


def describe_search(space: Mapping[str, tuple[Param, Search]]) -> dict[str, str]:
    """One line per searched parameter: ``"float in [0.001, 0.1], log"``."""
    out = {}
    for name, (param, s) in space.items():
        if s.choices:
            out[name] = "one of " + ", ".join(map(str, s.choices))
        else:
            kind = "int" if param.kind is int else "float"
            out[name] = (f"{kind} in [{s.low:g}, {s.high:g}]" + (", log" if s.log else "")
                         + (f", step {s.step:g}" if s.step else ""))
    return out


def trial_seed(seed: int, number: int) -> int:
    """The sampler seed of trial ``number`` of a study seeded ``seed`` (32 bits, from
    ``SeedSequence([seed, number])``)."""
    return int(np.random.SeedSequence([int(seed), int(number)]).generate_state(1)[0])


# ----------------------------------------------------------------------- settings
@dataclass(frozen=True)
class TuneSettings:
    """One tracker's study: what runs, how it is scored, how it is searched."""

    tracker: TrackerSpec
    scenarios: tuple[Scenario, ...]
    seeds: tuple[int, ...]
    trials: int = TUNE_TRIALS
    objective: str = "ospa"
    policy: PolicySpec = field(default_factory=lambda: PolicySpec("raster"))
    looks: int | None = None
    c: float | None = None  # None: 2 cells of each scenario's grid
    p: float = 2.0
    seed: int = 0
    batch_size: int = 1
    startup_trials: int = STARTUP_TRIALS

    def __post_init__(self) -> None:
        if self.objective not in objective_names():
            raise UsageError(f"objective {self.objective!r} is not one of {objective_names()}")
        for what, v, lo in (("trials", self.trials, 1), ("batch size", self.batch_size, 1),
                            ("startup trials", self.startup_trials, 0)):
            if v < lo:
                raise UsageError(f"{what} {v} is not allowed: expected an integer >= {lo}")
        if not self.seeds or min(self.seeds) < TUNING_SEED_BASE:
            raise UsageError(f"tuning seeds must be >= {TUNING_SEED_BASE} (disjoint from the "
                             f"evaluation seeds), got {list(self.seeds)[:3]}...")
        if not self.scenarios:
            raise UsageError("no scenario to tune on")

    @property
    def name(self) -> str:
        return self.tracker.name

    @property
    def fixed(self) -> dict[str, Any]:
        return dict(self.tracker.params)

    def space(self) -> dict[str, tuple[Param, Search]]:
        return search_space(self.tracker.target(), self.fixed)

    def problem(self) -> str | None:
        """None if the study can start, else why not (one line): no search space, or a
        scenario the tracker cannot run with its fixed parameters."""
        if not self.space():
            return (f"tracker {self.tracker.label!r} has no search space: none of its "
                    "parameters declares search=Search(...)"
                    + (" (or every searched one is given)" if self.fixed else ""))
        for sc in self.scenarios:
            try:
                reason = self.spec({}).make().unsupported_reason(sc.model)
            except Exception as exc:  # noqa: BLE001 - a tracker that cannot be built
                reason = first_line(exc)
            if reason:
                return (f"tracker {self.tracker.label!r} cannot run scenario {sc.name!r} "
                        f"({reason}): tune it on other --scenarios")
        return None

    def spec(self, params: Mapping[str, Any]) -> TrackerSpec:
        """The tracker spec of a trial: the fixed parameters and the trial's."""
        return TrackerSpec(self.name, {**self.fixed, **params})

    def jobs(self, spec: TrackerSpec) -> list[Job]:
        looks = [self.looks] if self.looks is not None else None
        return build_jobs(list(self.scenarios), [spec], [self.policy], looks, list(self.seeds))

    def identity(self) -> dict[str, Any]:
        """What a resumed study must share with the one it continues (not ``trials``:
        raising it continues the study)."""
        return {"tracker": self.name, "fixed": _jsonable(self.fixed),
                "scenarios": [{"name": sc.name, "n_steps": sc.n_steps} for sc in self.scenarios],
                "seeds": list(self.seeds), "objective": self.objective,
                "policy": self.policy.label, "looks": self.looks, "c": self.c, "p": self.p,
                "seed": self.seed, "batch_size": self.batch_size,
                "startup_trials": self.startup_trials}

    def budget(self) -> dict[str, Any]:
        n = len(self.seeds) * len(self.scenarios)
        return {"trials": self.trials, "tuning_seeds": list(self.seeds),
                "scenarios": [sc.name for sc in self.scenarios],
                "steps": {sc.name: sc.n_steps for sc in self.scenarios},
                "policy": self.policy.label,
                "looks": self.looks if self.looks is not None else "each scenario's "
                                                                   "looks_per_step",
                "runs": self.trials * n, "default_runs": n}

    def budget_text(self) -> str:
        steps = sorted({sc.n_steps for sc in self.scenarios})
        looks = "each scenario's look budget" if self.looks is None else f"{self.looks} looks"
        n = len(self.seeds) * len(self.scenarios)
        return (f"{self.trials} trials x {len(self.seeds)} tuning seeds x "
                f"{len(self.scenarios)} scenarios ({', '.join(sc.name for sc in self.scenarios)}"
                f"; {'/'.join(map(str, steps))} steps; {self.policy.label} at {looks}) = "
                f"{self.trials * n} runs, + {n} runs of the defaults")


def _jsonable(d: Mapping[str, Any]) -> dict[str, Any]:
    return json.loads(json.dumps(dict(d), sort_keys=True, default=str))


# ---------------------------------------------------------------------- objective
def objective_value(results: pd.DataFrame, label: str, settings: TuneSettings
                    ) -> tuple[float | None, dict[str, float], str]:
    """``(value, per-scenario values, message)`` of the setting ``label`` in ``results``:
    the mean over scenarios of the mean over seeds of each run's mean over its steps of
    the objective metric. ``value`` None and ``message`` the first failure (``scenario /
    seed S: error``) when a run is missing or did not finish ``ok``."""
    runs = per_run(results[results["tracker_label"] == label]) if len(results) else None
    metric = settings.objective
    if runs is not None and metric not in runs.columns:
        return None, {}, (f"the results have no {metric!r} column: register the metric in "
                          "the worker processes too (at import of a module they import)")
    per_scenario: dict[str, float] = {}
    for sc in settings.scenarios:
        rows = (runs[runs["scenario"] == sc.name].set_index("seed")
                if runs is not None else pd.DataFrame())
        values = []
        for seed in settings.seeds:
            if seed not in rows.index:
                return None, per_scenario, f"{sc.name} / seed {seed}: no run"
            r = rows.loc[seed]
            if r["status"] != "ok":
                return None, per_scenario, f"{sc.name} / seed {seed}: {r['status']}: {r['error']}"
            values.append(float(r[metric]))
        per_scenario[sc.name] = float(np.mean(values))
    return float(np.mean(list(per_scenario.values()))), per_scenario, ""


# -------------------------------------------------------------------------- study
@dataclass(frozen=True)
class TuneResult:
    """One tracker's tuning: the record written to its tuned file (None when no trial
    finished), the file's path, the study folder and the trials table."""

    name: str
    record: dict[str, Any] | None
    tuned_file: Path | None
    study_dir: Path
    trials: pd.DataFrame
    message: str = ""


def _quiet_optuna() -> None:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)


class _JournalLock:
    """The journal's writer lock as an ``fcntl.flock`` on the journal file itself (the
    interface of optuna's ``BaseJournalFileLock``: ``acquire``, ``release``).

    The kernel drops it with its holder, so neither Ctrl-C nor a kill can leave it held.
    optuna's default lock is a symlink beside the journal, renamed away on release: a
    Ctrl-C landing in its acquire or release raised an ``OSError`` of its own instead of
    the interrupt, and a kill left the symlink behind for the next session to wait on."""

    def __init__(self, path: str) -> None:
        self._path = path
        self._fd: int | None = None

    def acquire(self) -> bool:
        fd = os.open(self._path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        return True

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)  # closing the descriptor drops its flock


def _storage(study_dir: Path):
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    path = str(study_dir / "study.journal")
    return JournalStorage(JournalFileBackend(path, lock_obj=_JournalLock(path)))


def _sampler(settings: TuneSettings, number: int):
    import optuna

    return optuna.samplers.TPESampler(seed=trial_seed(settings.seed, number),
                                      n_startup_trials=settings.startup_trials,
                                      multivariate=True, constant_liar=True)


def _open_study(settings: TuneSettings, study_dir: Path, resume: bool):
    """The study of ``study_dir``: created, or with ``resume`` loaded (its settings must be
    those given: ``UsageError`` naming the first that differs)."""
    import optuna

    storage = _storage(study_dir)
    exists = any(s.study_name == settings.name for s in storage.get_all_studies())
    if exists and not resume:
        raise UsageError(f"{study_dir} already holds a study of {settings.name}: --resume to "
                         "continue it, or another --out")
    study = optuna.create_study(study_name=settings.name, storage=storage,
                                direction="minimize", load_if_exists=True,
                                sampler=_sampler(settings, 0))
    identity = settings.identity()
    stored = study.user_attrs.get("settings")
    if stored is None:
        study.set_user_attr("settings", identity)
    else:
        for key, value in identity.items():
            if stored.get(key) != value:
                raise UsageError(f"{study_dir}: the study was made with {key} = "
                                 f"{stored.get(key)!r}, not {value!r}; resume it with the "
                                 "same settings (only --trials may change), or use another "
                                 "--out")
    return study, storage


def _study_for_trial(settings: TuneSettings, storage: Any, number: int):
    import optuna

    return optuna.load_study(study_name=settings.name, storage=storage,
                             sampler=_sampler(settings, number))


def _draw(settings: TuneSettings, storage: Any, study_id: int, number: int,
          space: Mapping[str, tuple[Param, Search]]) -> dict[str, Any]:
    """Draw trial ``number`` and add it, ``RUNNING`` with all its parameters, to the study
    in one journal write; returns its parameters.

    The draw runs on an in-memory copy of the study's trials ``0..number-1`` (states,
    values, parameters and the sampler's attributes, all the sampler reads) with the
    sampler of :func:`trial_seed`, so it is the draw optuna would make on the study
    itself; only the finished trial reaches the journal. An interrupt or a kill at any
    moment thus leaves either no trial ``number`` (the next session draws it again, the
    same) or the whole trial (run again with its parameters), never a half-drawn one."""
    import optuna
    from optuna.storages import InMemoryStorage

    earlier = [t for t in storage.get_all_trials(study_id, deepcopy=False) if t.number < number]
    if len(earlier) != number:
        raise RuntimeError(f"trial {number} asked with {len(earlier)} trials before it")
    scratch = optuna.create_study(storage=InMemoryStorage(), direction="minimize",
                                  sampler=_sampler(settings, number))
    scratch.add_trials(earlier)
    trial = scratch.ask()
    if trial.number != number:
        raise RuntimeError(f"trial {number} drawn as number {trial.number}")
    trial.set_user_attr("sampler_seed", trial_seed(settings.seed, number))
    params = suggest(trial, space)
    storage.create_new_trial(study_id, template_trial=scratch.trials[number])
    return params


def _check_params(settings: TuneSettings, params: Mapping[str, Any]) -> str:
    """``""`` if the trial's parameters go together, else the reason (one line)."""
    try:
        settings.tracker.target().validate_params({**settings.fixed, **params},
                                                  name=settings.name)
    except (ValueError, TypeError) as exc:
        return first_line(exc)
    return ""


def tune_tracker(settings: TuneSettings, out_dir: str | Path, *,
                 tuned_dir: str | Path | None = None, workers: int = 1, resume: bool = False,
                 progress: bool = True, executor_options: Mapping[str, Any] | None = None,
                 argv: Sequence[str] | None = None,
                 sweep: Callable[..., pd.DataFrame] | None = None) -> TuneResult:
    """Tune one tracker (module docstring); write ``<tuned_dir>/<tracker>.toml`` (None:
    :func:`~mttbench.benchmarks.app.tuned.default_write_dir`) and the study's files under
    ``out_dir``. ``executor_options`` go to :func:`~mttbench.benchmarks.engine.sweep.run_sweep`
    with ``workers``; ``sweep`` replaces ``run_sweep`` (tests). ``UsageError`` for a
    tracker without search space or a resumed study with other settings."""
    _quiet_optuna()
    from optuna.trial import TrialState

    problem = settings.problem()
    if problem:
        raise UsageError(problem)
    space = settings.space()
    out_dir = Path(out_dir)
    study_dir = out_dir / settings.name
    study_dir.mkdir(parents=True, exist_ok=True)
    study, storage = _open_study(settings, study_dir, resume)
    run = sweep or run_sweep
    options = dict(executor_options or {})
    default_spec = settings.spec({})
    B = settings.batch_size

    study_id = storage.get_study_id_from_name(settings.name)

    def set_attr(number: int, key: str, value: Any) -> None:
        """A user attribute of the (running) trial ``number``."""
        storage.set_trial_user_attr(
            storage.get_trial_id_from_study_id_trial_number(study_id, number), key, value)

    def say(text: str) -> None:
        if progress:
            print(text, file=sys.stderr, flush=True)

    print(f"tune {settings.tracker.label}: {settings.budget_text()}; batches of {B} "
          f"trial(s) on {workers} worker(s) -> {study_dir}", file=sys.stderr, flush=True)
    while True:
        trials = study.get_trials(deepcopy=False)
        running = [t for t in trials if t.state == TrialState.RUNNING]
        n = len(trials)
        need_default = "default_value" not in study.user_attrs
        if not running and n >= settings.trials and not need_default:
            break
        batch: list[tuple[int, dict[str, Any]]] = []

        def admit(batch: list, number: int, params: dict[str, Any]) -> None:
            """Into the batch, or failed at once if its parameters do not go together
            (told before the next draw, which must see it failed)."""
            problem = _check_params(settings, params)
            if problem:
                set_attr(number, "message", f"parameters refused: {problem}")
                study.tell(number, state=TrialState.FAIL)
                say(f"  {settings.name} trial {number}: failed: parameters refused: {problem}")
            else:
                batch.append((number, params))

        for t in running:  # left by an interrupt: run again with their parameters
            if set(t.params) == set(space):
                admit(batch, t.number, {k: space[k][0].parse(v) for k, v in t.params.items()})
            else:  # only a journal written before draws were atomic (_draw) holds these
                set_attr(t.number, "message", "interrupted while its parameters were drawn")
                study.tell(t.number, state=TrialState.FAIL)
        if running:
            end = min((running[0].number // B + 1) * B, settings.trials)
        else:
            end = min((n // B + 1) * B, settings.trials) if n < settings.trials else n
        for number in range(n, end):
            admit(batch, number, _draw(settings, storage, study_id, number, space))
        specs = {number: settings.spec(params) for number, params in batch}
        jobs: dict[str, Job] = {}
        for spec in [*specs.values(), *([default_spec] if need_default else [])]:
            for job in settings.jobs(spec):
                jobs.setdefault(job.key(settings.c, settings.p), job)
        if not jobs:
            continue
        results = run(list(jobs.values()), out_dir, workers=workers, progress=progress,
                      resume=True, c=settings.c, p=settings.p, extend=True, **options)
        if need_default:
            value, per_sc, msg = objective_value(results, default_spec.label, settings)
            study.set_user_attr("default_per_scenario", per_sc)
            study.set_user_attr("default_message", msg)
            study.set_user_attr("default_value", value)  # last: it marks the three written
            say(f"  {settings.name} defaults: "
                + (f"{settings.objective} {value:.4f}" if value is not None else f"failed: {msg}"))
        for number, _ in batch:
            value, per_sc, msg = objective_value(results, specs[number].label, settings)
            set_attr(number, "per_scenario", per_sc)
            if value is None:
                set_attr(number, "message", msg)
                study.tell(number, state=TrialState.FAIL)
            else:
                study.tell(number, value)
            say(_trial_line(settings, study, number, value, msg))
        write_text_atomic(study_dir / "trials.csv", trials_table(study, settings)
                          .to_csv(index=False))

    table = trials_table(study, settings)
    write_text_atomic(study_dir / "trials.csv", table.to_csv(index=False))
    record = tuned_record(study, settings, space, study_dir, argv)
    if record is None:
        return TuneResult(settings.name, None, None, study_dir, table,
                          f"no trial of {settings.name} finished; see {study_dir / 'trials.csv'}")
    target = tuned_path(tuned_dir if tuned_dir is not None else default_write_dir(),
                        settings.name)
    write_tuned(study_dir / "tuned.toml", record)
    write_tuned(target, record)
    return TuneResult(settings.name, record, target, study_dir, table)


def _trial_line(settings: TuneSettings, study: Any, number: int, value: float | None,
                msg: str) -> str:
    done = sum(1 for t in study.get_trials(deepcopy=False) if t.state.is_finished())
    head = f"  {settings.name} trial {number} ({done}/{settings.trials}): "
    if value is None:
        head += f"failed: {msg}"
    else:
        head += f"{settings.objective} {value:.4f}"
    try:
        best = study.best_trial
        head += f"; best {best.value:.4f} (trial {best.number})"
    except ValueError:
        pass
    return head


def trials_table(study: Any, settings: TuneSettings) -> pd.DataFrame:
    """Every trial: ``number, state, value``, the value per scenario, the parameters
    (``param_<name>``), the sampler seed and the failure message."""
    rows = []
    for t in study.get_trials(deepcopy=False):
        row: dict[str, Any] = {"number": t.number, "state": t.state.name, "value": t.value}
        per_sc = t.user_attrs.get("per_scenario", {})
        for sc in settings.scenarios:
            row[f"{settings.objective}_{sc.name}"] = per_sc.get(sc.name, math.nan)
        for name in settings.space():
            row[f"param_{name}"] = t.params.get(name)
        row["sampler_seed"] = t.user_attrs.get("sampler_seed")
        row["message"] = t.user_attrs.get("message", "")
        rows.append(row)
    return pd.DataFrame(rows)


def versions() -> dict[str, str]:
    """:func:`~mttbench.benchmarks.app.compare.package_versions` and optuna's."""
    out = package_versions()
    try:
        out["optuna"] = metadata.version("optuna")
    except metadata.PackageNotFoundError:
        out["optuna"] = "not installed"
    return out


def tuned_record(study: Any, settings: TuneSettings, space: Mapping[str, tuple[Param, Search]],
                 study_dir: Path, argv: Sequence[str] | None) -> dict[str, Any] | None:
    """The tuned file's content (:mod:`~mttbench.benchmarks.app.tuned`), or None when no trial
    finished."""
    from optuna.trial import TrialState

    trials = study.get_trials(deepcopy=False)
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    if not complete:
        return None
    best = min(complete, key=lambda t: (t.value, t.number))
    default = study.user_attrs.get("default_value")
    defaults_win = default is not None and default <= best.value
    params = {} if defaults_win else {k: space[k][0].parse(v) for k, v in best.params.items()}
    git = git_commit()
    return {
        "format": FORMAT,
        "tracker": settings.name,
        "source": ("defaults: no trial beat them on the tuning seeds" if defaults_win
                   else f"trial {best.number}"),
        "params": params,
        "fixed": settings.fixed,
        "objective": {
            "metric": settings.objective, "c": settings.c, "p": settings.p,
            "definition": "mean over scenarios of the mean over tuning seeds of each run's "
                          "mean over its steps",
            "value": default if defaults_win else best.value,
            "default_value": default,
            "best_trial": best.number, "best_trial_value": best.value,
            "per_scenario": (study.user_attrs.get("default_per_scenario") if defaults_win
                             else best.user_attrs.get("per_scenario")),
            "default_per_scenario": study.user_attrs.get("default_per_scenario"),
            "default_message": study.user_attrs.get("default_message") or None,
        },
        "budget": {**settings.budget(), "completed": len(complete),
                   "failed": sum(1 for t in trials if t.state == TrialState.FAIL)},
        "search": describe_search(space),
        "sampler": {"name": "optuna TPESampler", "seed": settings.seed,
                    "trial_seeds": "SeedSequence([seed, trial number])",
                    "startup_trials": settings.startup_trials, "multivariate": True,
                    "constant_liar": True, "batch_size": settings.batch_size},
        "provenance": {
            "date_utc": datetime.now(UTC).isoformat(timespec="seconds"),
            "command": " ".join(argv) if argv else None,
            "git_commit": git.get("commit"), "git_dirty": git.get("dirty"),
            "study": str(study_dir), "platform": platform.platform(),
            "versions": versions(),
        },
    }


# ----------------------------------------------------------------- several trackers
def is_finished(folder: str | Path) -> bool:
    """True if ``folder`` holds a finished tune (manifest status ``"finished"``)."""
    man = read_manifest(folder)
    return man is not None and man.get("status") == "finished"


def stored_batch_size(folder: str | Path, name: str) -> int | None:
    """The batch size of tracker ``name``'s study in ``folder`` (its manifest), or None."""
    man = read_manifest(folder) or {}
    try:
        return int(man["trackers"][name]["settings"]["batch_size"])
    except (KeyError, TypeError, ValueError):
        return None


@dataclass(frozen=True)
class TuneOutput:
    out_dir: Path
    results: list[TuneResult]
    manifest: dict[str, Any]


def run_tune(settings: Sequence[TuneSettings], out_dir: str | Path, *,
             tuned_dir: str | Path | None = None, workers: int | None = None,
             resume: bool = False, progress: bool = True,
             executor_options: Mapping[str, Any] | None = None,
             argv: Sequence[str] | None = None,
             run_timeout: float | None = None) -> TuneOutput:
    """Tune each tracker in turn (:func:`tune_tracker`) into ``out_dir``, with a
    ``manifest.json`` (status ``running``, then ``finished``/``interrupted``/``failed``)
    and, at the end, ``results.parquet`` holding every run of every study. A run past
    ``run_timeout`` seconds (None: the app's default) is ended: its trial fails."""
    t0 = time.perf_counter()
    started = datetime.now(UTC)
    workers = workers or os.cpu_count() or 1
    for s in settings:  # bad input: refused before the folder is touched
        problem = s.problem()
        if problem:
            raise UsageError(problem)
    out = prepare_out_dir(out_dir)
    for s in settings:  # a folder of another kind of sweep (run, compare) or other c, p
        check_sweep(out, None, s.c, s.p, resume=True, extend=True)
    if not resume:
        taken = [s.name for s in settings if (out / s.name / "study.journal").exists()]
        if taken:
            raise UsageError(f"{out} already holds a study of {taken[0]}: --resume to "
                             "continue it, or another --out")
    command = list(argv) if argv is not None else list(sys.argv)
    previous = read_manifest(out) if resume else None
    manifest: dict[str, Any] = {
        "status": "running", "command": command, "started_utc": started.isoformat(),
        "sessions": [*(previous or {}).get("sessions", []),
                     {"started_utc": started.isoformat(), "command": command}],
        "workers": workers, "cpu_count": os.cpu_count(), "platform": platform.platform(),
        "versions": versions(), "git": git_commit(),
        "trackers": {s.name: {"settings": s.identity(), "budget": s.budget_text()}
                     for s in settings},
        "tuned_dir": str(tuned_dir if tuned_dir is not None else default_write_dir()),
    }

    def save(status: str) -> None:
        manifest["status"] = status
        manifest["sessions"][-1]["wall_time_s"] = round(time.perf_counter() - t0, 3)
        write_text_atomic(out / "manifest.json", json.dumps(manifest, indent=2) + "\n")

    save("running")
    done: list[TuneResult] = []
    try:
        for s in settings:
            options = {**(executor_options or {}),
                       **({"run_timeout": run_timeout} if run_timeout is not None else {})}
            res = tune_tracker(s, out, tuned_dir=tuned_dir, workers=workers, resume=resume,
                               progress=progress, executor_options=options, argv=command)
            done.append(res)
            manifest["trackers"][s.name]["tuned_file"] = (str(res.tuned_file)
                                                          if res.tuned_file else None)
            manifest["trackers"][s.name]["message"] = res.message
            save("running")
        # every saved run of the studies in one table (reads the parts; runs nothing: a
        # run without a part, lost with its worker, is left out)
        all_jobs: dict[str, Job] = {}
        for s in settings:
            for t in _finished_specs(s, out):
                for job in s.jobs(t):
                    key = job.key(s.c, s.p)
                    if (out / "parts" / f"{key}.parquet").is_file():
                        all_jobs.setdefault(key, job)
        if all_jobs:
            c, p = settings[0].c, settings[0].p
            run_sweep(list(all_jobs.values()), out, workers=1, progress=False,
                      resume=True, c=c, p=p, extend=True)
    except BaseException as exc:
        status = "interrupted" if isinstance(exc, KeyboardInterrupt) else "failed"
        with contextlib.suppress(OSError):
            save(status)
        raise
    save("finished")
    return TuneOutput(out, done, manifest)


def _finished_specs(settings: TuneSettings, out: Path) -> list[TrackerSpec]:
    """The specs of the defaults and of every trial that ran (for the final results)."""
    from optuna.trial import TrialState

    study = _study_for_trial(settings, _storage(out / settings.name), 0)
    space = settings.space()
    specs = [settings.spec({})]
    for t in study.get_trials(deepcopy=False):
        if t.state in (TrialState.COMPLETE, TrialState.FAIL) and set(t.params) == set(space) \
                and not t.user_attrs.get("message", "").startswith("parameters refused"):
            specs.append(settings.spec({k: space[k][0].parse(v) for k, v in t.params.items()}))
    return specs

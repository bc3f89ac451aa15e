"""The public conformance kit: checks that every tracker must pass.

In the spirit of scikit-learn's ``check_estimator``: the checks ship inside the
package, so the author of a tracker written elsewhere runs them in their own
tests. Each check takes the tracker *class* (registered or not), builds instances
with ``cls()`` and ``cls(**params)``, and drives them only through the harness's
step loop (:func:`mttbench.benchmarks.engine.loop.play`). A failing check raises
``AssertionError`` naming the check and what went wrong.

An outside author's test file::

    from mttbench.testing import check_tracker, parametrize_with_checks
    from my_package import MyTracker          # a subclass of mttbench.Tracker

    def test_my_tracker_conforms():           # everything in one test...
        check_tracker(MyTracker)

    @parametrize_with_checks([MyTracker])     # ...or one test item per check,
    def test_conformance(tracker_class, check):   # ids like "my-tracker-check_params"
        check(tracker_class)

``checks_for(MyTracker)`` gives the same checks as ``(name, callable)`` pairs for
other test runners. A tracker that legitimately cannot pass a check declares it
with the reason, ``conformance_exceptions = {"check_tracks_two_targets": "why"}``,
and the check is skipped, visibly. A baseline that does not track by design
declares ``baseline = True`` (the ``null`` tracker does): the tracking checks are
skipped for it.

Two kinds of checks (:data:`INTERFACE_CHECKS`, :data:`TRACKING_CHECKS`):

* **interface** -- class declarations; parameters stored unchanged, JSON-able, an
  equal rebuild, unknown keywords refused; estimates of the right shape, dtype and
  finite; the predicted per-cell count distribution ``P_c(t)`` valid at *every*
  step; same seed, same outputs; no state carried across ``reset``; no targets ->
  the count settles below 1; steps without looks; the 2500-cell ``large`` preset;
  the superposition sensor supported or refused with a reason.
* **tracking** -- it finds and holds one target, and two separated targets, on easy
  scenarios, within stated tolerances on mean OSPA (``c = 2``, ``p = 2``) and mean
  count error after a burn-in. The ``null`` tracker (reports nothing) scores OSPA
  = ``c`` = 2 and count error = the true count exactly, and fails both; each bound
  and the measurements it was chosen from are in the check's docstring.

The checks run the kit's own scenarios (presets changed with
``dataclasses.replace``, named ``check-*`` so their worlds are their own) and fixed
seeds, so a deterministic tracker gets the same verdict on every run. Runtime of
the whole kit, measured on a busy 2-core machine: kfnn 1.2 s, gpf 2 s, jmpd 5 s
(numba compilation included), jmpd-ip 8 s (2000 particles; the slowest).
"""

from __future__ import annotations

import dataclasses
import inspect
import json
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from mttbench.benchmarks.engine.loop import StepRecord, play
from mttbench.benchmarks.engine.metrics import step_metrics
from mttbench.benchmarks.engine.policies import AllCells, Raster
from mttbench.scenarios.spec import Scenario
from mttbench.scenarios.spec import get as get_scenario
from mttbench.trackers.base import Estimate, Tracker, available, get_class, make
from mttbench.trackers.cells import CellCounts

__all__ = [
    "CHECKS", "INTERFACE_CHECKS", "TRACKING_CHECKS", "check_tracker", "checks_for",
    "parametrize_with_checks", "skipped_checks",
    "check_declarations", "check_params", "check_runs_200_steps", "check_deterministic",
    "check_reset_no_state_leak", "check_zero_targets", "check_step_without_looks",
    "check_count_distribution_on_large", "check_superposition_or_reason",
    "check_tracks_one_target", "check_tracks_two_targets",
]

#: rows of ``P_c(t)`` must sum to 1 within this (float64 sums over a few columns)
ROW_SUM_TOL = 1e-9
#: the OSPA / GOSPA cut-off and order of the tracking checks (the suite's defaults)
OSPA_C, OSPA_P = 2.0, 2.0


# ------------------------------------------------------------------ the kit's policies
class _RasterWithPrediction(Raster):
    """The raster sweep that also asks for ``P_c(t)``, so every step's prediction is
    recorded (``StepRecord.counts``) and checked; ``blind_steps`` get no looks."""

    name = "check-raster"
    uses_prediction = True

    def __init__(self, blind_steps: Iterable[int] = ()) -> None:
        self.blind_steps = frozenset(int(k) for k in blind_steps)

    def select(self, k, counts=None, truth_cells=None):
        if k in self.blind_steps:
            return np.zeros(0, dtype=np.int64)
        return super().select(k)


class _AllCellsWithPrediction(AllCells):
    """Every cell once per step, asking for ``P_c(t)`` too (recorded and checked)."""

    name = "check-all"
    uses_prediction = True


# ------------------------------------------------------------------ helpers
def _label(cls: type[Tracker]) -> str:
    """The tracker's name, or its class name when it has none (test ids, seeds)."""
    name = getattr(cls, "name", "")
    return name if isinstance(name, str) and name else cls.__name__


def _scenario(preset: str, name: str, *, n_steps: int | None = None,
              initial_states: tuple | None = None) -> Scenario:
    """A shipped preset changed for a check; ``initial_states`` given -> exactly those
    targets, no random ones, survival 1 and no births. Named ``name`` (its own world)."""
    sc = get_scenario(preset)
    model = sc.model
    if initial_states is not None:
        bd = dataclasses.replace(model.birth_death, initial_states=tuple(initial_states),
                                 n_random_initial=0, survival_probability=1.0,
                                 birth_rate=0.0)
        model = dataclasses.replace(model, birth_death=bd)
    return dataclasses.replace(sc, name=name, model=model,
                               n_steps=sc.n_steps if n_steps is None else n_steps)


#: targets of the 50x50 stand-in for trackers that declare ``large`` (25 targets)
#: unsupported, e.g. a JMPD whose ``t_max`` is below 25
LARGE_FEW_TARGETS = 3


def _large_scenario(cls: type[Tracker], n_steps: int | None = None) -> Scenario:
    """The 50x50 ``large`` preset, or, when ``cls`` declares it unsupported, the same
    grid, sensor and looks with :data:`LARGE_FEW_TARGETS` random targets (so state and
    ``P_c(t)`` sized by a large grid are still exercised)."""
    sc = _scenario("large", "check-large", n_steps=n_steps)
    if cls().unsupported_reason(sc.model) is None:
        return sc
    bd = dataclasses.replace(sc.model.birth_death, n_random_initial=LARGE_FEW_TARGETS)
    return dataclasses.replace(sc, name="check-large-few",
                               model=dataclasses.replace(sc.model, birth_death=bd))


def _run(tracker: Tracker, scenario: Scenario, seed: int, *, policy=None,
         n_steps: int | None = None) -> list[StepRecord]:
    """All steps of one run through the harness's step loop (:func:`play`)."""
    return list(play(scenario, tracker, seed, policy=policy, n_steps=n_steps,
                     tracker_label=_label(type(tracker))))


def _assert_estimate_valid(est: Any, k: int) -> None:
    where = f"step {k}: estimate()"
    assert isinstance(est, Estimate), f"{where} returned {type(est).__name__}, not Estimate"
    count = est.count
    assert isinstance(count, int | float | np.integer | np.floating) and not isinstance(
        count, bool), f"{where}.count is {count!r}, not a number"
    assert np.isfinite(count) and count >= 0, f"{where}.count = {count!r}: need finite, >= 0"
    s = est.states
    assert isinstance(s, np.ndarray), f"{where}.states is {type(s).__name__}, not ndarray"
    assert s.ndim == 2 and s.shape[1] == 4, f"{where}.states has shape {s.shape}, not (n, 4)"
    assert s.dtype == np.float64, f"{where}.states has dtype {s.dtype}, not float64"
    assert np.all(np.isfinite(s)), f"{where}.states has non-finite values"
    if est.covariances is not None:
        c = est.covariances
        assert isinstance(c, np.ndarray) and c.shape == (s.shape[0], 4, 4), (
            f"{where}.covariances has shape {getattr(c, 'shape', None)}, "
            f"not {(s.shape[0], 4, 4)}")
        assert np.all(np.isfinite(c)), f"{where}.covariances has non-finite values"
    labels = getattr(est, "labels", None)
    if labels is not None:  # persistent track labels: one per state, unique in the step
        assert isinstance(labels, np.ndarray) and labels.shape == (s.shape[0],), (
            f"{where}.labels has shape {getattr(labels, 'shape', None)}, not {(s.shape[0],)}")
        assert np.issubdtype(labels.dtype, np.integer), (
            f"{where}.labels has dtype {labels.dtype}, not an integer type")
        assert len(np.unique(labels)) == len(labels), f"{where}.labels repeat within the step"


def _assert_count_distribution_valid(P: Any, n_cells: int, k: int) -> None:
    """A dense ``(n_cells, n_counts)`` array, or a :class:`CellCounts` whose own rows and
    (when some cell uses it) default row are checked as they are, never made dense."""
    where = f"step {k}: cell_count_distribution()"
    if isinstance(P, CellCounts):
        assert P.n_cells == n_cells, (
            f"{where} is a CellCounts over {P.n_cells} cells, not n_cells = {n_cells}")
        cells = np.asarray(P.cells)
        assert P.rows.ndim == 2 and P.rows.shape == (len(cells), len(P.default)), (
            f"{where}: rows {P.rows.shape} do not match its {len(cells)} cells and "
            f"{len(P.default)} counts")
        assert len(P.default) >= 2, f"{where} has {len(P.default)} count columns: need >= 2"
        assert not len(cells) or (np.all(np.diff(cells) > 0) and cells[0] >= 0
                                  and cells[-1] < n_cells), (
            f"{where}: its cells are not sorted, unique and in [0, {n_cells})")
        rows = P.rows if P.n_default == 0 else np.vstack([P.rows, P.default[None]])
        what = "a row (own or default)"
    else:
        assert isinstance(P, np.ndarray), (
            f"{where} returned {type(P).__name__}, not ndarray or CellCounts")
        assert P.ndim == 2 and P.shape[0] == n_cells and P.shape[1] >= 2, (
            f"{where} has shape {P.shape}: need (n_cells = {n_cells}, n_counts >= 2)")
        rows, what = P, "a row"
    if not len(rows):
        return
    assert np.all(np.isfinite(rows)), f"{where} has non-finite values"
    assert np.all(rows >= 0), f"{where} has negative probabilities (min {rows.min():.3g})"
    worst = float(np.max(np.abs(rows.sum(axis=1) - 1.0)))
    assert worst <= ROW_SUM_TOL, (
        f"{where}: {what} sums to 1 {worst:+.3g} (tolerance {ROW_SUM_TOL})")


def _same_counts(a: Any, b: Any) -> bool:
    """Two recorded ``P_c(t)`` identical: the same type and the same numbers."""
    if isinstance(a, CellCounts) or isinstance(b, CellCounts):
        return (isinstance(a, CellCounts) and isinstance(b, CellCounts)
                and a.n_cells == b.n_cells and np.array_equal(a.cells, b.cells)
                and np.array_equal(a.rows, b.rows) and np.array_equal(a.default, b.default))
    return np.array_equal(a, b)


def _assert_records_valid(records: list[StepRecord], scenario: Scenario) -> None:
    """Every estimate valid; every recorded ``P_c(t)`` valid."""
    for rec in records:
        _assert_estimate_valid(rec.estimate, rec.k)
        if rec.counts is not None:
            _assert_count_distribution_valid(rec.counts, scenario.grid.n_cells, rec.k)


def _assert_same_outputs(a: list[StepRecord], b: list[StepRecord], what: str) -> None:
    """Counts, states, covariances and recorded ``P_c(t)`` identical at every step."""
    assert len(a) == len(b), f"{what}: {len(a)} steps against {len(b)}"
    for ra, rb in zip(a, b, strict=True):
        ea, eb = ra.estimate, rb.estimate
        where = f"{what}: step {ra.k}"
        assert ea.count == eb.count, f"{where}: count {ea.count!r} against {eb.count!r}"
        assert ea.states.shape == eb.states.shape and np.array_equal(ea.states, eb.states), (
            f"{where}: the estimated states differ")
        if ea.covariances is not None or eb.covariances is not None:
            assert (ea.covariances is not None and eb.covariances is not None
                    and np.array_equal(ea.covariances, eb.covariances)), (
                f"{where}: the covariances differ")
        if ra.counts is not None:
            assert _same_counts(ra.counts, rb.counts), f"{where}: P_c(t) differs"


# ======================================================================= interface
def check_declarations(cls: type[Tracker]) -> None:
    """Class declarations: a ``Tracker`` subclass with a non-empty one-word ``name``
    and a one-line ``summary``; ``baseline`` a bool; ``conformance_exceptions`` maps
    names of this kit's checks to non-empty reasons (a misspelt name would skip nothing)."""
    assert isinstance(cls, type) and issubclass(cls, Tracker), (
        f"{cls!r} is not a subclass of mttbench.trackers.base.Tracker")
    name = cls.name
    assert isinstance(name, str) and name and not any(ch.isspace() for ch in name), (
        f"name = {name!r}: need a non-empty string without spaces (it labels results)")
    summary = cls.summary
    assert isinstance(summary, str) and summary.strip() and "\n" not in summary, (
        f"summary = {summary!r}: need one non-empty line (`mttbench trackers` lists it)")
    assert isinstance(cls.baseline, bool), f"baseline = {cls.baseline!r}: need a bool"
    exc = cls.conformance_exceptions
    assert isinstance(exc, dict), f"conformance_exceptions = {exc!r}: need a dict"
    for check, reason in exc.items():
        assert check in CHECKS, (f"conformance_exceptions names {check!r}, which is not a "
                                 f"check of the kit: the checks are {sorted(CHECKS)}")
        assert isinstance(reason, str) and reason.strip(), (
            f"conformance_exceptions[{check!r}] = {reason!r}: need a reason")


def check_params(cls: type[Tracker]) -> None:
    """Constructors store parameters only (scikit-learn's rule): every parameter has a
    default; an unknown keyword is refused with ``TypeError`` (by the constructor, and
    by ``mttbench.trackers.make`` when the class is registered); ``cls()`` stores each
    parameter unchanged (equal value, same type) under its own name and sets no other
    public attribute; ``get_params()`` is JSON-able and rebuilds an equal tracker. A
    class that declares its parameters (``parameters = {name: Param(...)}``,
    :mod:`mttbench.trackers.params`) declares exactly its constructor's, and every
    default passes its own declaration unchanged."""
    names = cls.param_names()
    defaults = cls.param_defaults()
    missing = [n for n, v in defaults.items() if v is inspect.Parameter.empty]
    assert not missing, f"parameter(s) {missing} have no default: cls() must work"
    try:
        cls(definitely_not_a_parameter=1)
    except TypeError:
        pass
    else:
        raise AssertionError("cls(definitely_not_a_parameter=1) was accepted: unknown "
                             "keywords must raise TypeError")
    if cls.name in available() and get_class(cls.name) is cls:
        try:
            make(cls.name, definitely_not_a_parameter=1)
        except TypeError:
            pass
        else:
            raise AssertionError(f"make({cls.name!r}, definitely_not_a_parameter=1) was "
                                 "accepted")
    tracker = cls()
    params = tracker.get_params()
    assert list(params) == names, f"get_params() keys {list(params)} != parameters {names}"
    for n in names:
        got, want = params[n], defaults[n]
        assert type(got) is type(want) and got == want, (
            f"parameter {n!r}: default {want!r} is stored as {got!r}")
    public = {a for a in vars(tracker) if not a.startswith("_")}
    extra = sorted(public - set(names))
    assert not extra, (f"the constructor sets public attribute(s) {extra} that are not "
                       "parameters (keep run state private, built in reset)")
    try:
        json.dumps(params, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise AssertionError(f"get_params() is not JSON-able: {exc}") from None
    rebuilt = cls(**params).get_params()
    assert rebuilt == params, f"cls(**get_params()).get_params() = {rebuilt} != {params}"
    problem = cls.declaration_problem()
    assert problem is None, problem
    declared = cls.declared_parameters()
    if declared is not None:
        checked = cls.validate_params(defaults)
        for n, v in defaults.items():
            assert checked[n] == v and type(checked[n]) is type(v), (
                f"default {n}={v!r} is not allowed by its declaration ({declared[n].allowed()})")


def check_runs_200_steps(cls: type[Tracker]) -> None:
    """200 steps of the ``default`` preset (three targets, raster of 24 looks): every
    estimate valid (``count`` finite and >= 0; ``states (n, 4)`` float64, finite;
    ``covariances (n, 4, 4)`` or None) and ``P_c(t)`` valid at every step: a dense
    ``(n_cells, n_counts >= 2)`` array or a :class:`~mttbench.trackers.cells.CellCounts`
    over ``n_cells`` cells (its own rows and its default row checked, never made dense),
    finite, non-negative, rows summing to 1 within :data:`ROW_SUM_TOL`."""
    sc = _scenario("default", "check-default", n_steps=200)
    _assert_records_valid(_run(cls(), sc, 0, policy=_RasterWithPrediction()), sc)


def check_deterministic(cls: type[Tracker]) -> None:
    """All randomness from the generator ``reset`` gets: two fresh trackers on the same
    world and seed give identical counts, states, covariances and ``P_c(t)`` (40 steps
    of ``births``: targets appear and die)."""
    sc = _scenario("births", "check-births", n_steps=40)
    a = _run(cls(), sc, 3, policy=_RasterWithPrediction())
    b = _run(cls(), sc, 3, policy=_RasterWithPrediction())
    _assert_records_valid(a, sc)
    _assert_same_outputs(a, b, "two fresh trackers, same seed")


def check_reset_no_state_leak(cls: type[Tracker]) -> None:
    """``reset`` starts afresh: a tracker that has run the 50x50 ``large`` preset (3
    steps; see :func:`_large_scenario`) and then another world of ``births`` (20 steps)
    gives, after ``reset``, the same outputs as a fresh tracker (40 steps of ``births``,
    seed 3)."""
    sc = _scenario("births", "check-births", n_steps=40)
    used = cls()
    _run(used, _large_scenario(cls), 1, n_steps=3)
    _run(used, sc, 7, n_steps=20)
    again = _run(used, sc, 3, policy=_RasterWithPrediction())
    fresh = _run(cls(), sc, 3, policy=_RasterWithPrediction())
    _assert_same_outputs(again, fresh, "used tracker after reset against a fresh one")


def check_zero_targets(cls: type[Tracker]) -> None:
    """No target ever, every cell looked at every step (60 steps, prior count mean 0):
    valid outputs, and the mean estimated count of the last 20 steps is below 1 (with
    144 looks per step at ``p_f = 4.9e-4`` a false alarm comes every ~14 steps)."""
    sc = _scenario("default", "check-empty", n_steps=60, initial_states=())
    records = _run(cls(), sc, 1, policy=_AllCellsWithPrediction())
    _assert_records_valid(records, sc)
    late = float(np.mean([float(r.estimate.count) for r in records[-20:]]))
    assert late < 1.0, f"no targets: mean estimated count of the last 20 steps is {late:.3g}"


def check_step_without_looks(cls: type[Tracker]) -> None:
    """Steps with no looks at all (steps 0, 1 and 10-12 of 30 on ``default``): the
    tracker coasts; estimates and ``P_c(t)`` stay valid."""
    sc = _scenario("default", "check-default", n_steps=30)
    policy = _RasterWithPrediction(blind_steps=(0, 1, 10, 11, 12))
    records = _run(cls(), sc, 2, policy=policy)
    looked = [r.k for r in records if r.k in policy.blind_steps and len(r.looks)]
    assert not looked, f"the kit's policy looked at steps {looked} (a harness problem)"
    _assert_records_valid(records, sc)


def check_count_distribution_on_large(cls: type[Tracker]) -> None:
    """The ``large`` preset (50x50 cells, 25 targets, 250 looks; see
    :func:`_large_scenario`), 5 steps: valid estimates and ``P_c(t)`` over 2500 cells at
    every step."""
    sc = _large_scenario(cls, n_steps=5)
    _assert_records_valid(_run(cls(), sc, 0, policy=_RasterWithPrediction()), sc)


def check_superposition_or_reason(cls: type[Tracker]) -> None:
    """The superposition sensor (``superposition`` preset, 30 steps): either valid
    estimates at every step, or ``unsupported_reason(model)`` says why not in words
    (a string of more than 10 characters)."""
    sc = _scenario("superposition", "check-superposition", n_steps=30)
    tracker = cls()
    reason = tracker.unsupported_reason(sc.model)
    if reason is not None:
        assert isinstance(reason, str) and len(reason.strip()) > 10, (
            f"unsupported_reason returned {reason!r}: give the reason in words")
        return
    _assert_records_valid(_run(tracker, sc, 0), sc)


# ======================================================================== tracking
def _assert_tracks(cls: type[Tracker], what: str, scenario_name: str, initial_states: tuple, *,
                   seeds: tuple, n_steps: int, burn_in: int, max_ospa: float,
                   max_count_error: float) -> None:
    """Run ``cls`` on ``default`` with fixed ``initial_states`` (no births, ``p_s = 1``,
    every cell looked at every step; ``scenario_name`` seeds its worlds) and assert mean
    OSPA (``c = 2, p = 2``, positions) and mean count error over steps ``k >= burn_in``
    of ``seeds`` below the bounds."""
    sc = _scenario("default", scenario_name, n_steps=n_steps,
                   initial_states=initial_states)
    ospa, count_err = [], []
    for seed in seeds:
        records = _run(cls(), sc, seed, policy=_AllCellsWithPrediction())
        _assert_records_valid(records, sc)
        for rec in records[burn_in:]:
            est = rec.estimate
            m = step_metrics(rec.truth[:, [0, 2]], est.states[:, [0, 2]], float(est.count),
                             c=OSPA_C, p=OSPA_P)
            ospa.append(m["ospa"])
            count_err.append(m["count_error"])
    mean_ospa, mean_count = float(np.mean(ospa)), float(np.mean(count_err))
    assert mean_ospa < max_ospa and mean_count < max_count_error, (
        f"{what} (every cell looked at every step): mean OSPA {mean_ospa:.3f} (bound "
        f"{max_ospa}; reporting nothing scores {OSPA_C}) and mean count error "
        f"{mean_count:.3f} (bound {max_count_error}; nothing scores {len(initial_states)}) "
        f"over steps {burn_in}..{n_steps - 1} of seeds {seeds}")


#: one target in mid-grid, starting at ~0.06 cells/step (the ``default`` preset's speed)
ONE_TARGET = ((5.5, 0.05, 6.5, -0.03),)
ONE_TARGET_SEEDS, ONE_TARGET_STEPS, ONE_TARGET_BURN_IN = tuple(range(8)), 40, 10
ONE_TARGET_MAX_OSPA = 1.0
ONE_TARGET_MAX_COUNT_ERROR = 0.4


def check_tracks_one_target(cls: type[Tracker]) -> None:
    """Finds and holds one target: mean OSPA < 1.0 and mean count error < 0.4 after
    a burn-in of 10 steps.

    Scenario: the ``default`` preset (12x12 unit cells, ``p_d = 0.5``, ``snr = 10``
    so ``p_f = 4.9e-4``; white-noise acceleration ``q = 5e-4``) with exactly one
    target, no births and ``p_s = 1``; every cell is looked at every step (the
    ``all`` policy, 144 looks); 40 steps, seeds 0-7; the scores are means over steps
    10..39 of the eight runs (240 steps). The burn-in covers finding the target:
    with every cell looked at, its cell returns a detection with probability 0.5 per
    step; over 24 seeds the shipped trackers first report it at a median step of 1
    (gpf, jmpd) to 3 (kfnn, 2-of-3 confirmation), at the latest at step 12.

    Why these bounds: reporting nothing (``null``) scores OSPA = ``c`` = 2 and count
    error 1 at every step. A tracker that knows only which cell holds the target
    scores the distance to the cell centre, ``sqrt(2/12)`` = 0.41 RMS for a uniform
    position in the cell; one spurious extra estimate costs ``sqrt((d^2 + c^2)/2)``
    ~ 1.5, a missed step 2. OSPA < 1 (c/2) thus needs the target held, to about a
    cell, in well over half of the steps; count error < 0.4, the count right in
    about 60% of them. Measured on seeds 0-7, OSPA / count error: gpf 0.41 / 0.05,
    kfnn 0.55 / 0.09, jmpd 0.47 / 0.04, jmpd-ip 0.43 / 0.04 (means of 8 other seeds,
    twice: at most 0.56 / 0.11), so the bounds sit about 2x (OSPA) and 4x (count)
    above the worst shipped tracker, and 2x below ``null``.
    """
    _assert_tracks(cls, "one easy target", "check-one-target", ONE_TARGET,
                   seeds=ONE_TARGET_SEEDS, n_steps=ONE_TARGET_STEPS, burn_in=ONE_TARGET_BURN_IN,
                   max_ospa=ONE_TARGET_MAX_OSPA, max_count_error=ONE_TARGET_MAX_COUNT_ERROR)


#: two targets in opposite quarters of the grid, ~8 cells apart, moving slowly
TWO_TARGETS = ((3.5, 0.05, 3.5, 0.03), (8.5, -0.04, 9.5, -0.05))
TWO_TARGETS_SEEDS, TWO_TARGETS_STEPS, TWO_TARGETS_BURN_IN = tuple(range(8)), 40, 10
TWO_TARGETS_MAX_OSPA = 1.0
TWO_TARGETS_MAX_COUNT_ERROR = 0.6


def check_tracks_two_targets(cls: type[Tracker]) -> None:
    """Finds and holds two well separated targets: mean OSPA < 1.0 and mean count
    error < 0.6 after a burn-in of 10 steps.

    Scenario: as :func:`check_tracks_one_target` (every cell looked at every step,
    40 steps, seeds 0-7, means over steps 10..39) with two targets that start ~8
    cells apart, in opposite quarters of the grid, so there is little association
    ambiguity.

    Why these bounds: reporting nothing scores OSPA = 2 and count error 2. Holding
    both targets to about a cell scores OSPA ~ 0.41; holding only one of the two
    scores ``sqrt((d^2 + c^2)/2)`` ~ 1.5 and count error 1, so OSPA < 1 needs both
    targets most of the time, and count error < 0.6 the count right in well over
    half the steps. Measured on seeds 0-7, OSPA / count error: gpf 0.40 / 0.07,
    kfnn 0.43 / 0.05, jmpd-ip 0.52 / 0.13 (means of 8 other seeds, twice: at most
    0.78 / 0.34, jmpd-ip); margin about 2x (OSPA) and 4.5x (count). The bootstrap
    ``jmpd`` (2000 particles) scores 1.25 / 0.50 and fails: proposing from the prior
    in the joint two-target space leaves too few particles with both targets right
    (8-seed means 1.01-1.25 over seeds 0-23; 0.80 on seeds 0-5 with 20000
    particles); its partitioned-proposal
    variant ``jmpd-ip`` passes.
    """
    _assert_tracks(cls, "two separated targets", "check-two-targets", TWO_TARGETS,
                   seeds=TWO_TARGETS_SEEDS, n_steps=TWO_TARGETS_STEPS, burn_in=TWO_TARGETS_BURN_IN,
                   max_ospa=TWO_TARGETS_MAX_OSPA, max_count_error=TWO_TARGETS_MAX_COUNT_ERROR)


# ===================================================================== running them
CheckFunction = Callable[[type[Tracker]], None]

#: the interface checks, in running order (cheap first)
INTERFACE_CHECKS: tuple[CheckFunction, ...] = (
    check_declarations, check_params, check_runs_200_steps, check_deterministic,
    check_reset_no_state_leak, check_zero_targets, check_step_without_looks,
    check_count_distribution_on_large, check_superposition_or_reason,
)
#: the tracking checks (skipped for a ``baseline`` tracker)
TRACKING_CHECKS: tuple[CheckFunction, ...] = (check_tracks_one_target, check_tracks_two_targets)
#: every check by name
CHECKS: dict[str, CheckFunction] = {f.__name__: f for f in INTERFACE_CHECKS + TRACKING_CHECKS}


def skipped_checks(cls: type[Tracker]) -> dict[str, str]:
    """The checks skipped for ``cls``, each with the reason: its declared
    ``conformance_exceptions``, and the tracking checks when it is a ``baseline``."""
    skipped: dict[str, str] = {}
    if getattr(cls, "baseline", False) is True:
        for f in TRACKING_CHECKS:
            skipped[f.__name__] = f"{_label(cls)} is a baseline (does not track by design)"
    declared = getattr(cls, "conformance_exceptions", {})
    if isinstance(declared, dict):
        for name, reason in declared.items():
            skipped[name] = f"{_label(cls)} declares: {reason}"
    return skipped


class _Check:
    """One named check, callable on a tracker class; failures name the check."""

    def __init__(self, function: CheckFunction) -> None:
        self.function = function
        self.name = function.__name__

    def __call__(self, cls: type[Tracker]) -> None:
        try:
            self.function(cls)
        except AssertionError as exc:
            raise AssertionError(f"{_label(cls)}: {self.name} failed: {exc}") from exc
        except Exception as exc:  # noqa: BLE001 - any error of the tracker fails the check
            raise AssertionError(f"{_label(cls)}: {self.name} raised "
                                 f"{type(exc).__name__}: {exc}") from exc

    def __repr__(self) -> str:
        return self.name


def _select(checks: Iterable[str] | None) -> list[_Check]:
    if checks is None:
        return [_Check(f) for f in CHECKS.values()]
    names = [checks] if isinstance(checks, str) else list(checks)
    unknown = [n for n in names if n not in CHECKS]
    if unknown:
        raise ValueError(f"unknown check(s) {unknown}: the checks are {list(CHECKS)}")
    return [_Check(CHECKS[n]) for n in names]


def checks_for(cls: type[Tracker], *, checks: Iterable[str] | None = None,
               ) -> list[tuple[str, Callable[[], None]]]:
    """The checks to run on ``cls`` as ``(check name, callable())`` pairs, in order;
    skipped checks (:func:`skipped_checks`) are left out. ``checks`` picks names."""
    skipped = skipped_checks(cls)
    return [(c.name, lambda c=c: c(cls)) for c in _select(checks) if c.name not in skipped]


def check_tracker(cls: type[Tracker], *, checks: Iterable[str] | None = None) -> dict[str, str]:
    """Run every check (or the named ``checks``) on the tracker class ``cls``.

    Raises ``AssertionError`` at the first failure, with a message that names the
    tracker and the check. Returns the skipped checks with their reasons.
    """
    for _, run in checks_for(cls, checks=checks):
        run()
    selected = {c.name for c in _select(checks)}
    return {n: r for n, r in skipped_checks(cls).items() if n in selected}


def parametrize_with_checks(classes: Iterable[type[Tracker]], *,
                            checks: Iterable[str] | None = None) -> Any:
    """A ``pytest.mark.parametrize`` over ``(tracker_class, check)``: one test item per
    tracker and check, id ``<tracker name>-<check name>``; skipped checks are items
    marked skip with the reason. Use as::

        @parametrize_with_checks([MyTracker])
        def test_conformance(tracker_class, check):
            check(tracker_class)
    """
    import pytest

    params = []
    for cls in classes:
        skipped = skipped_checks(cls)
        for check in _select(checks):
            marks = [pytest.mark.skip(reason=skipped[check.name])] if check.name in skipped else []
            params.append(pytest.param(cls, check, marks=marks,
                                       id=f"{_label(cls)}-{check.name}"))
    return pytest.mark.parametrize(("tracker_class", "check"), params)

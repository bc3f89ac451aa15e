"""Conformance: the public kit (:mod:`mttbench.testing`) over every registered tracker.

One test item per tracker and check, id ``<tracker>-<check>`` (as scikit-learn's
``parametrize_with_checks``), so ``pytest -k "gpf-check_zero_targets"`` selects one. A
tracker that legitimately cannot pass a check declares ``conformance_exceptions =
{"check_name": "reason"}`` and the item is skipped with that reason; a ``baseline`` tracker
(``null``) skips the tracking checks. The kit drives trackers only through the harness's
step loop.

The second half tests the kit itself: the tracking checks fail the ``null`` tracker
when forced, and deliberately broken trackers are caught by the check that covers
their bug.
"""

from __future__ import annotations

import numpy as np
import pytest

from mttbench import testing, trackers
from mttbench.testing import (
    TRACKING_CHECKS,
    check_tracker,
    checks_for,
    parametrize_with_checks,
    skipped_checks,
)
from mttbench.trackers.base import Estimate
from mttbench.trackers.cells import CellCounts
from mttbench.trackers.kfnn import KFNNTracker
from mttbench.trackers.null import NullTracker

REGISTERED = [trackers.get_class(name) for name in trackers.available()]


@parametrize_with_checks(REGISTERED)
def test_conformance(tracker_class, check, kit):
    kit.run(tracker_class, check)  # check(tracker_class), once per session (tests/conftest.py)


def test_every_registered_tracker_gets_every_check():
    names = {cls.name for cls in REGISTERED}
    assert {"gpf", "jmpd", "jmpd-ip", "kfnn", "null"} <= names
    for cls in REGISTERED:
        run = [n for n, _ in checks_for(cls)]
        assert sorted(run + list(skipped_checks(cls))) == sorted(testing.CHECKS)


# ------------------------------------------------------------- the tracking checks bite
@pytest.mark.parametrize("check", TRACKING_CHECKS, ids=lambda f: f.__name__)
def test_null_fails_the_tracking_checks_when_forced(check):
    """``null`` reports nothing: OSPA = c = 2 and count error = true count, every step."""
    with pytest.raises(AssertionError, match=r"mean OSPA 2\.000 .* reporting nothing"):
        check(NullTracker)


def test_null_passes_the_kit_with_the_tracking_checks_skipped():
    skipped = check_tracker(NullTracker)
    assert set(skipped) == {f.__name__ for f in TRACKING_CHECKS}
    assert all("baseline" in reason for reason in skipped.values())


# ------------------------------------------------------------- broken trackers are caught
class ParamChangingKFNN(KFNNTracker):
    """Bug: ``get_params`` reports a parameter other than the one stored."""

    name = "broken-params"

    def get_params(self):
        params = super().get_params()
        params["lost_track_probability"] *= 2
        return params


class SwallowingKFNN(KFNNTracker):
    """Bug: unknown keywords are silently accepted."""

    name = "broken-swallows"

    def __init__(self, lost_track_probability: float = 0.1, **ignored) -> None:
        super().__init__(lost_track_probability=lost_track_probability)


class WrongShapeKFNN(KFNNTracker):
    """Bug: the states are positions ``(n, 2)`` instead of ``(n, 4)``."""

    name = "broken-shape"

    def estimate(self):
        est = super().estimate()
        return Estimate(est.count, est.states[:, [0, 2]])


class UnnormalisedKFNN(KFNNTracker):
    """Bug: ``P_c(t)`` (a CellCounts) drops its last column, so rows no longer sum to 1."""

    name = "broken-counts"

    def cell_count_distribution(self):
        cc = super().cell_count_distribution()
        return CellCounts(cc.n_cells, cc.cells, cc.rows[:, :-1], cc.default[:-1])


class UnnormalisedDenseKFNN(KFNNTracker):
    """Bug: the dense ``P_c(t)`` drops its last column, so rows no longer sum to 1."""

    name = "broken-dense-counts"

    def cell_count_distribution(self):
        return super().cell_count_distribution().dense()[:, :-1]


class NegativeDefaultKFNN(KFNNTracker):
    """Bug: the default row of ``P_c(t)`` (shared by the cells away from every track)
    has a negative entry; only that row is wrong."""

    name = "broken-default-row"

    def cell_count_distribution(self):
        cc = super().cell_count_distribution()
        default = np.r_[1.1, -0.1, np.zeros(cc.n_counts - 2)]  # sums to 1
        return CellCounts(cc.n_cells, cc.cells, cc.rows, default)


class WrongGridCountsKFNN(KFNNTracker):
    """Bug: ``P_c(t)`` claims a grid of another size."""

    name = "broken-counts-grid"

    def cell_count_distribution(self):
        cc = super().cell_count_distribution()
        return CellCounts(cc.n_cells + 1, cc.cells, cc.rows, cc.default)


class UnseededKFNN(KFNNTracker):
    """Bug: randomness that does not come from the generator ``reset`` gets."""

    name = "broken-unseeded"

    def estimate(self):
        est = super().estimate()
        jitter = np.random.default_rng().normal(scale=1e-3, size=est.states.shape)
        return Estimate(est.count, est.states + jitter, est.covariances)


_TRACK_ARRAYS = ("_m", "_P", "_id", "_score", "_prior_logodds", "_peak", "_tested",
                 "_confirmed", "_age", "_next_id")


class LeakyKFNN(KFNNTracker):
    """Bug: ``reset`` keeps the previous run's tracks on the same grid (a 'warm start')."""

    name = "broken-leaky"

    def reset(self, model, rng):
        old = {a: getattr(self, a) for a in _TRACK_ARRAYS} if hasattr(self, "_m") else None
        same_grid = getattr(self, "_grid", None) == model.grid
        super().reset(model, rng)
        if old is not None and same_grid:
            for attr, value in old.items():
                setattr(self, attr, value)


class BlindCrashKFNN(KFNNTracker):
    """Bug: a step without any look raises."""

    name = "broken-blind"

    def update(self, looks):
        if len(looks) == 0 and looks.z is None:
            raise IndexError("no looks")
        super().update(looks)


class ShiftedKFNN(KFNNTracker):
    """Bug: the reported positions are 3 cells off in x (beyond the cut-off c = 2): the
    outputs are valid, the count is right, only the tracking checks can see it."""

    name = "broken-shifted"

    def estimate(self):
        est = super().estimate()
        states = est.states.copy()
        states[:, 0] += 3.0
        return Estimate(est.count, states, est.covariances)


class MisspeltExceptionKFNN(KFNNTracker):
    """Bug: a declared exception names no check of the kit (it would skip nothing)."""

    name = "broken-exception"
    conformance_exceptions = {"check_tracks_two_target": "typo"}


BROKEN = [  # (tracker class, the check that must catch it, what its message says)
    (ParamChangingKFNN, "check_params", "default 0.1 is stored as 0.2"),
    (SwallowingKFNN, "check_params", "was accepted"),
    (WrongShapeKFNN, "check_runs_200_steps", r"shape \(\d+, 2\), not \(n, 4\)"),
    (UnnormalisedKFNN, "check_runs_200_steps", "sums to 1"),
    (UnnormalisedDenseKFNN, "check_runs_200_steps", "a row sums to 1"),
    (NegativeDefaultKFNN, "check_runs_200_steps", "negative probabilities"),
    (WrongGridCountsKFNN, "check_runs_200_steps", "not n_cells = 144"),
    (UnseededKFNN, "check_deterministic", "states differ"),
    (LeakyKFNN, "check_reset_no_state_leak", "after reset"),
    (BlindCrashKFNN, "check_step_without_looks", "raised IndexError"),
    (ShiftedKFNN, "check_tracks_one_target", "mean OSPA"),
    (MisspeltExceptionKFNN, "check_declarations", "not a check of the kit"),
]


@pytest.mark.parametrize(("cls", "check", "message"), BROKEN,
                         ids=[f"{cls.name}-{check}" for cls, check, _ in BROKEN])
def test_a_broken_tracker_is_caught_by_its_check(cls, check, message):
    with pytest.raises(AssertionError, match=rf"{cls.name}: {check} (failed|raised)") as info:
        check_tracker(cls, checks=[check])
    assert info.match(message)


def test_the_leak_is_not_a_determinism_failure():
    """The leaky tracker is deterministic from a fresh start: only the reset check sees it."""
    check_tracker(LeakyKFNN, checks=["check_deterministic"])


# ------------------------------------------------------------------ the kit's own rules
class DeclaredKFNN(KFNNTracker):
    name = "declared-kfnn"
    conformance_exceptions = {"check_tracks_two_targets": "tracks one target at most"}


def test_declared_exceptions_are_skipped_with_their_reason():
    names = [n for n, _ in checks_for(DeclaredKFNN)]
    assert "check_tracks_two_targets" not in names and "check_tracks_one_target" in names
    skipped = check_tracker(DeclaredKFNN, checks=["check_declarations",
                                                  "check_tracks_two_targets"])
    assert skipped == {"check_tracks_two_targets": "declared-kfnn declares: tracks one "
                                                   "target at most"}


def test_unknown_check_names_are_refused():
    with pytest.raises(ValueError, match="unknown check"):
        check_tracker(KFNNTracker, checks=["check_everything"])


def test_checks_run_in_the_documented_order():
    assert list(testing.CHECKS)[:2] == ["check_declarations", "check_params"]
    assert list(testing.CHECKS)[-2:] == [f.__name__ for f in TRACKING_CHECKS]


# ------------------------------------------------------------------ the session's shared kit
def test_the_shared_kit_runs_a_check_once_and_repeats_its_failure(kit, tmp_path):
    """``kit`` (tests/conftest.py): the first run of a (class, check) runs it, a later
    one reads its outcome: a failure fails again with the same message, a pass passes,
    and neither runs the check again; another class runs anew."""

    class Counted:
        def __init__(self, check):
            self.check, self.name, self.calls = check, check.name, 0

        def __call__(self, cls):
            self.calls += 1
            self.check(cls)

    shared = type(kit)(tmp_path)
    [(_, check)] = [p.values for p in parametrize_with_checks(
        [KFNNTracker], checks=["check_params"]).args[1]]
    counted = Counted(check)
    failed = "broken-params: check_params failed: .*default 0.1 is stored as 0.2"
    for _ in range(2):
        with pytest.raises(AssertionError, match=failed):
            shared.run(ParamChangingKFNN, counted)
    assert counted.calls == 1
    for _ in range(2):
        shared.run(KFNNTracker, counted)
    assert counted.calls == 2
    with pytest.raises(AssertionError, match=failed + r".*earlier run of the same check"):
        shared.check_tracker(ParamChangingKFNN)

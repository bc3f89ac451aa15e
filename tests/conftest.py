"""Fixtures shared by the test modules.

``kit``: the conformance kit (:mod:`mttbench.testing`) with each ``(tracker class, check)``
outcome computed once per session. ``tests/test_conformance.py`` runs the kit on every
registered tracker, and a tracker's own test file runs it again on the same class
(``ss-jpda``, ``pmb``, ``truth-aided``); the checks are deterministic (seeded from the
class and the check), so the second run repeats the first to the last digit. The outcome
(passed, or the failure's message) is kept in a folder that the xdist workers of one
session share, filled under a lock: the first test to need it runs the check, a later
one reads it and fails with the same message when the check failed.

``MTTBENCH_TEST_TIMES=PREFIX`` (off by default) writes each test's CPU time and wall
time, setup and teardown included, to ``PREFIX.<xdist worker>.json``: CPU is this
process's user + system time plus that of the children it waited for (a child killed
or left running is in no one's account), the measure of docs/suite_time.md.
"""

from __future__ import annotations

import fcntl
import json
import os
import time
from pathlib import Path

import pytest

from mttbench import testing


class SharedKit:
    """``run(cls, check)`` and ``check_tracker(cls)`` of the kit over a shared store of
    outcomes in ``folder``."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder

    def run(self, cls: type, check) -> None:
        """``check(cls)``, a check of :func:`mttbench.testing.parametrize_with_checks`
        (its failures name the tracker and the check), once per session."""
        self._once(cls, check.name, lambda: check(cls))

    def check_tracker(self, cls: type) -> dict[str, str]:
        """:func:`mttbench.testing.check_tracker` (every check, in order) through the
        store: raises at the first failure, returns the skipped checks with their reasons."""
        for name, call in testing.checks_for(cls):
            self._once(cls, name, call)
        return testing.skipped_checks(cls)

    def _once(self, cls: type, name: str, call) -> None:
        key = f"{cls.__module__}.{cls.__qualname__}.{name}"
        done = self.folder / f"{key}.json"
        with open(self.folder / f"{key}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                if not done.exists():
                    try:
                        call()
                    except AssertionError as exc:
                        done.write_text(json.dumps(str(exc)))
                        raise
                    done.write_text(json.dumps(None))
                    return
                failure = json.loads(done.read_text())
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)
        if failure is not None:
            raise AssertionError(f"{failure} (this session's earlier run of the same check)")


@pytest.fixture(scope="session")
def kit(tmp_path_factory) -> SharedKit:
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the session's folder, shared by its workers
    folder = root / "kit-outcomes"
    folder.mkdir(exist_ok=True)
    return SharedKit(folder)


# ------------------------------------------------------------------ MTTBENCH_TEST_TIMES
_TIMES: list[tuple[str, float, float]] = []  # (node id, CPU s, wall s)


def _cpu_s() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    if not os.environ.get("MTTBENCH_TEST_TIMES"):
        return (yield)
    cpu, wall = _cpu_s(), time.perf_counter()
    try:
        return (yield)
    finally:
        _TIMES.append((item.nodeid, _cpu_s() - cpu, time.perf_counter() - wall))


def pytest_sessionfinish(session):
    prefix = os.environ.get("MTTBENCH_TEST_TIMES")
    if prefix and _TIMES:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        Path(f"{prefix}.{worker}.json").write_text(json.dumps(
            {"tests": _TIMES, "process_cpu_s": _cpu_s()}))

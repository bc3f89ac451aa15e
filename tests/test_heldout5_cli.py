"""Two command-line guards: ``c ** p`` of the OSPA cut-off must stay a normal number on
both sides (a tiny ``--c`` with a large ``--p`` underflows to 0 and would make every
distance's cost 0), and a refused command removes the output folder only when it made
it (an empty folder the user gave stays).

References: ``c ** p`` evaluated in Python for each pair (overflow or a value below
1e-200 must be refused), and the folders' existence after each command."""

from __future__ import annotations

import argparse

import pytest

from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.app.cli_common import check_common, folder_lock
from mttbench.benchmarks.app.usage import UsageError
from mttbench.benchmarks.engine.store import LOCK_FILE


def _power(c: float, p: float) -> float:
    try:
        return c ** p
    except OverflowError:
        return float("inf")


@pytest.mark.parametrize(("c", "p"), [(1e-5, 50.0), (1e-5, 30.0), (0.5, 1000.0), (2.0, 1000.0),
                                      (1e5, 30.0), (1e5, 50.0), (1e-3, 2.0), (3.0, 2.0)])
def test_the_cut_off_to_the_power_p_stays_a_normal_number_on_either_side(c, p):
    args = argparse.Namespace(steps=None, workers=None, c=c, p=p)
    value = _power(c, p)
    if 1e-200 <= value <= 1e200:
        check_common(args)
    else:
        with pytest.raises(UsageError, match=r"c \*\* p"):
            check_common(args)


def test_a_tiny_cut_off_with_a_large_order_is_refused_before_any_work(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["run", "--scenarios", "default", "--trackers", "null", "--seeds", "1",
                 "--steps", "2", "--no-progress", "--c", "1e-5", "--p", "50",
                 "--out", str(out)])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "c ** p" in err[0]
    assert not out.exists()


def test_a_refused_command_removes_only_the_output_folder_it_created(tmp_path):
    given = tmp_path / "given"
    given.mkdir()
    fresh = tmp_path / "fresh"
    for folder in (given, fresh):
        with pytest.raises(RuntimeError):
            with folder_lock(folder):
                assert folder.is_dir()
                raise RuntimeError("a setting refused after the lock was taken")
    assert given.is_dir()  # with at most the lock file left in it
    assert {x.name for x in given.iterdir()} <= {LOCK_FILE}
    assert not fresh.exists()

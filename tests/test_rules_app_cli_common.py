"""Rules the commands share (``cli_common.py``, ``folders.py``, ``usage.py``) at their
documented edges: repeated and unsorted seeds, 2**63 - 1, ``MAX_SEEDS``, order p = 1, a
timeout of exactly a year, a path of exactly ``PATH_MAX`` bytes, the most recent
unfinished folder, a text of exactly 60 characters, a folder holding this command's
own mark or another's, the error class the command line turns into exit status 2."""

from __future__ import annotations

import argparse

import pytest

from mttbench.benchmarks.app import cli_common, folders
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.app.usage import UsageError
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.store import SWEEP_MANIFEST


def test_int_list_sorts_and_drops_repeats():
    assert cli_common.int_list(["5,3", "3", "9"], "seed", 0) == [3, 5, 9]


def test_int_list_allows_the_largest_int64():
    top = 2**63 - 1
    assert cli_common.int_list([str(top)], "seed", 0) == [top]
    with pytest.raises(UsageError):
        cli_common.int_list([str(top + 1)], "seed", 0)


def _ns(**kw) -> argparse.Namespace:
    base = {"seed_list": None, "seeds": None, "steps": None, "workers": None, "c": None,
            "p": 2.0, "run_timeout": None}
    base.update(kw)
    return argparse.Namespace(**base)


def test_max_seeds_is_allowed():
    assert len(cli_common.seeds_of(_ns(seeds=cli_common.MAX_SEEDS), 10)) == cli_common.MAX_SEEDS
    with pytest.raises(UsageError):
        cli_common.seeds_of(_ns(seeds=cli_common.MAX_SEEDS + 1), 10)


def test_order_one_and_a_years_timeout_are_allowed():
    cli_common.check_common(_ns(p=1.0))
    with pytest.raises(UsageError):
        cli_common.check_common(_ns(p=0.99))
    cli_common.check_common(_ns(run_timeout=cli_common.MAX_TIMEOUT_S))
    with pytest.raises(UsageError):
        cli_common.check_common(_ns(run_timeout=cli_common.MAX_TIMEOUT_S * 1.001))


def test_a_path_of_exactly_path_max_bytes_is_allowed(tmp_path):
    # 16 parts of 255 bytes with 15 separators = 4095 bytes, each part NAME_MAX long
    text = "/".join(["a" * 255] * 16)
    assert len(text) == cli_common.PATH_MAX
    cli_common.check_path("--out", text)
    with pytest.raises(UsageError, match="longer than the file system allows"):
        cli_common.check_path("--out", text + "a")


def test_resume_alone_takes_the_most_recent_unfinished_folder(tmp_path, monkeypatch):
    monkeypatch.setattr(cli_common, "REPORTS", tmp_path)
    for stamp in ("20250101T000000Z", "20260101T000000Z", "20260301T000000Z"):
        (tmp_path / f"compare-{stamp}").mkdir()
    done = {"compare-20260301T000000Z"}
    found = cli_common._latest_unfinished("compare-", lambda p: p.name in done)
    assert found == tmp_path / "compare-20260101T000000Z"


def test_a_text_of_60_characters_is_shown_whole():
    assert cli_common._shown("a" * 60) == repr("a" * 60)
    assert cli_common._shown("a" * 61) == repr("a" * 57 + "...")


def test_a_folder_is_refused_for_another_commands_mark_only(tmp_path):
    (tmp_path / SWEEP_MANIFEST).write_text("{}")
    folders.check_folder_kind(tmp_path, SWEEP_MANIFEST)  # its own mark: allowed
    with pytest.raises(UsageError, match="the runs of a sweep"):
        folders.check_folder_kind(tmp_path, folders.SCORE_MARK)
    with pytest.raises(UsageError, match="the runs of a sweep"):
        folders.check_folder_kind(tmp_path, folders.EXPORT_MARK)


def test_a_usage_error_is_the_engines_config_error_and_exits_2(capsys):
    assert issubclass(UsageError, ConfigError)
    assert main(["run", "--scenarios", "default", "--trackers", "null", "--seeds", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--seeds 0 is not allowed" in err[0]


def test_c_to_the_p_is_checked_on_the_small_side_too():
    """(1e-5) ** 50 = 1e-250 underflows below 1e-200; 1e5 ** 50 overflows above 1e200."""
    with pytest.raises(UsageError, match="c \\*\\* p must stay"):
        cli_common.check_common(_ns(c=1e-5, p=50.0))
    with pytest.raises(UsageError, match="c \\*\\* p must stay"):
        cli_common.check_common(_ns(c=1e5, p=50.0))
    cli_common.check_common(_ns(c=1e-3, p=2.0))

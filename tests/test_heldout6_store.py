"""All-or-nothing writes (``store.write_text_atomic``): a write that fails leaves the
earlier file as it was and no temporary file beside it; an ``OSError`` names the target.
Real failures, no patching: text that UTF-8 cannot encode, a target that is a folder."""

from __future__ import annotations

import errno

import pytest

from mttbench.benchmarks.engine.store import write_text_atomic


def test_a_failed_write_keeps_the_earlier_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "manifest.json"
    write_text_atomic(path, "earlier")
    with pytest.raises(UnicodeEncodeError):
        write_text_atomic(path, "half \ud800 written")  # a lone surrogate
    assert path.read_text(encoding="utf-8") == "earlier"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["manifest.json"]


def test_a_target_that_cannot_be_replaced_is_an_os_error_naming_it(tmp_path):
    target = tmp_path / "report.md"
    target.mkdir()
    (target / "inside").write_text("kept", encoding="utf-8")
    with pytest.raises(OSError) as err:
        write_text_atomic(target, "new")
    assert err.value.filename == str(target)
    assert err.value.errno in (errno.EISDIR, errno.ENOTEMPTY, errno.EEXIST)
    assert (target / "inside").read_text(encoding="utf-8") == "kept"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.md"]

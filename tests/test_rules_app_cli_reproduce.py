"""``mttbench reproduce paper --check``'s failure listing (``cli_reproduce.py``): at most
``MAX_REPORTED`` lines, then one line counting the rest, which is absent when exactly
``MAX_REPORTED`` lines moved. The runs and the check are replaced by stand-ins (a check
with a chosen number of lines); the command's own printing is what is tested."""

from __future__ import annotations

import pandas as pd
import pytest

from mttbench.benchmarks.app import reproduce
from mttbench.benchmarks.app.cli import main


@pytest.mark.parametrize("n_lines", [reproduce.MAX_REPORTED, reproduce.MAX_REPORTED + 2])
def test_the_check_lists_at_most_max_reported_lines_then_counts_the_rest(
        tmp_path, monkeypatch, capsys, n_lines):
    numbers = pd.DataFrame(columns=[*reproduce.KEYS, "value"])

    def fake_run(setting, out, cache, **kw):
        return reproduce.Reproduction(out, numbers, out / "numbers.csv", True,
                                      pd.DataFrame(columns=["status"]))

    lines = tuple(f"moved {i}" for i in range(n_lines))
    monkeypatch.setattr(reproduce, "reproduce_paper", fake_run)
    monkeypatch.setattr(reproduce, "check_numbers",
                        lambda *a, **k: reproduce.Check(False, 10, n_lines, lines))
    assert main(["reproduce", "paper", "--reduced", "--check", "--out",
                 str(tmp_path / "out"), "--cache-dir", str(tmp_path / "cache")]) == 1
    err = capsys.readouterr().err
    shown = [ln for ln in err.splitlines() if ln.startswith("  moved ")]
    assert len(shown) == reproduce.MAX_REPORTED
    more = [ln for ln in err.splitlines() if "more lines" in ln]
    if n_lines == reproduce.MAX_REPORTED:
        assert more == []
    else:
        assert more == ["  ... and 2 more lines"]

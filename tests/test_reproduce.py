"""``mttbench reproduce paper --reduced --check``: passes on the checked-in reference,
fails naming a number that was altered (in a temporary copy), uses its cache."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from mttbench.benchmarks import reproduce
from mttbench.benchmarks.cli import main
from mttbench.benchmarks.specs import PolicySpec, TrackerSpec

REFERENCE = reproduce.REFERENCE_DIR / "paper_reduced.csv"


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("reproduce-cache")


def _run(cache, out, *extra):
    return main(["reproduce", "paper", "--reduced", "--out", str(out), "--cache-dir", str(cache),
                 "--workers", "1", "--no-progress", *extra])


def test_reduced_check_passes_on_the_checked_in_reference(cache, tmp_path, capsys):
    assert REFERENCE.is_file(), "regenerate with: mttbench reproduce paper --reduced " \
                                "and copy numbers_reduced.csv to reports/reference/"
    rc = _run(cache, tmp_path, "--check")
    io = capsys.readouterr()
    assert rc == 0, io.err
    assert "check passed" in io.out
    for sc in reproduce.SETTINGS["reduced"].scenarios:
        for name in (f"fig_error_{sc}.png", f"fig_snapshot_{sc}.png", f"error_{sc}.csv",
                     f"snapshot_{sc}.csv"):
            assert (tmp_path / name).is_file(), name
    assert "departs from the paper" in (tmp_path / "report.md").read_text()
    assert (tmp_path / "report.html").read_text().count("data:image/png;base64,") == 4


def test_check_fails_naming_the_altered_number(cache, tmp_path, capsys):
    ref = reproduce.read_numbers(REFERENCE)
    sel = ((ref["figure"] == "error") & (ref["scenario"] == "default")
           & (ref["tracker"] == "gpf") & (ref["step"] == 5) & (ref["quantity"] == "state_error"))
    assert sel.sum() == 1
    altered = ref.copy()
    altered.loc[sel, "value"] *= 1 + 1e-6  # far beyond rtol 1e-9
    path = tmp_path / "altered.csv"
    altered.to_csv(path, index=False, float_format="%.17g")
    # a reference made with another numpy: the failure message says so
    path.with_suffix(".versions.json").write_text('{"numpy": "0.0"}')
    # fills the cache if this worker has not run the setting yet (pytest-xdist)
    assert _run(cache, tmp_path / "out") == 0
    capsys.readouterr()
    rc = _run(cache, tmp_path / "out", "--check", "--reference-csv", str(path))
    io = capsys.readouterr()
    assert rc == 1
    assert "runs from the cache" in io.out
    assert ("figure=error scenario=default tracker=gpf step=5 item=0 quantity=state_error"
            in io.err), io.err
    assert "1 number(s) differ" in io.err
    assert "numpy 0.0 -> " in io.err


def test_check_numbers_tolerance_and_missing_rows():
    base = pd.DataFrame({"figure": ["error"] * 3, "scenario": ["s"] * 3, "tracker": ["null"] * 3,
                         "step": [0, 1, 2], "item": [0, 0, 0], "quantity": ["q"] * 3,
                         "value": [1.0, np.nan, 3.0]})
    within = base.copy()
    within["value"] = [1.0 + 1e-12, np.nan, 3.0]  # inside rtol 1e-9; NaN equals NaN
    assert reproduce.check_numbers(within, base) == []
    moved = base.copy()
    moved.loc[2, "value"] = 3.0 * (1 + 1e-8)
    lines = reproduce.check_numbers(moved, base)
    assert len(lines) == 1 and "step=2" in lines[0] and "reference 3.0" in lines[0]
    nan_now = base.copy()
    nan_now.loc[0, "value"] = np.nan
    assert len(reproduce.check_numbers(nan_now, base)) == 1
    fewer = base.iloc[:2]
    lines = reproduce.check_numbers(fewer, base)
    assert len(lines) == 1 and "missing" in lines[0] and "step=2" in lines[0]
    lines = reproduce.check_numbers(base, fewer)
    assert len(lines) == 1 and "new" in lines[0]


def test_cache_key_follows_the_configuration():
    s = reproduce.SETTINGS["reduced"]
    specs, pol = [TrackerSpec("kfnn")], PolicySpec("renyi")
    k = reproduce.cache_key(s, specs, pol)
    assert k == reproduce.cache_key(s, specs, pol)
    assert k != reproduce.cache_key(dataclasses.replace(s, seeds=(0, 1)), specs, pol)
    assert k != reproduce.cache_key(s, [TrackerSpec("kfnn", {"max_misses": 4})], pol)
    assert k != reproduce.cache_key(s, specs, PolicySpec("raster"))

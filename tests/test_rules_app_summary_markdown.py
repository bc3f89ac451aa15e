"""The Markdown of ``summary.md`` (``summary.to_markdown`` and its helpers) on a summary
built by hand where a slip shows: a time in milliseconds with its half-width, the
``none`` policy beside ``all``, looks made half a look short of the budget, a label
holding a ``|``. The expected lines are written out cell by cell."""

from __future__ import annotations

import math

import pandas as pd

from mttbench.benchmarks.app import summary

METRICS = [("ospa", "OSPA", 1.0, ".3f"), ("tracker_wall_s", "ms/step", 1e3, ".3g")]


def _summ() -> pd.DataFrame:
    return pd.DataFrame({
        "scenario": ["s", "s", "s"], "tracker_label": ["a|b", "kfnn", "gpf"],
        "policy_label": ["none", "all", "raster"], "looks_per_step": [0, 200, 200],
        "n_seeds": [4, 4, 4], "looks_made": [math.nan, 144.0, 199.5],
        "ospa_mean": [1.0, 0.5, 0.25], "ospa_ci95": [0.125, 0.0625, 0.5],
        "tracker_wall_s_mean": [0.002, 0.004, 0.0125],
        "tracker_wall_s_ci95": [0.0005, 0.001, 0.0025]})


def test_the_table_lines_cell_by_cell():
    lines = summary.to_markdown(_summ(), METRICS).splitlines()
    assert lines[0] == "| scenario | tracker | policy | looks | seeds | OSPA | ms/step |"
    assert lines[1] == "|---|---|---|---|---:|---:|---:|"
    assert lines[2] == "| s | a\\|b | none | – | 4 | 1.000 ± 0.125 | 2 ± 0.5 |"
    assert lines[3] == "| s | kfnn | all | 200 (144 made) | 4 | 0.500 ± 0.062 | 4 ± 1 |"
    assert lines[4] == "| s | gpf | raster | 200 (199.5 made) | 4 | 0.250 ± 0.500 | 12.5 ± 2.5 |"


def test_looks_text_names_any_shortfall():
    assert summary.looks_text(200, 199.5) == "200 (199.5 made)"
    assert summary.looks_text(200, 200.0) == "200"
    assert summary.looks_text(200, math.nan) == "200"


def test_md_cell_escapes_the_pipe_and_joins_lines():
    assert summary.md_cell("a|b\nc\r") == "a\\|b c "


def test_group_text_without_looks_is_the_none_policy():
    assert summary.group_text("s", "none", 0) == "`s` (no looks)"
    assert summary.group_text("s", "all", 144) == "`s` (all, 144 looks)"

"""docs/examples/stonesoup_gnn.py: the Stone Soup GNN driven from exported world files.

As the GM-PHD example's test (tests/test_export_score.py): the example runs on a tiny export,
writes a well-formed estimate for every step and ``mttbench score`` scores it. Its cell masses
are checked against scipy's bivariate normal CDF.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.stats import multivariate_normal

from mttbench.benchmarks.app import export as ex
from mttbench.benchmarks.app.cli import main

GNN_EXAMPLE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "stonesoup_gnn.py"


def _load_example():
    pytest.importorskip("stonesoup")
    spec = importlib.util.spec_from_file_location("stonesoup_gnn_example", GNN_EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_cell_masses_equal_the_bivariate_normal_cdf():
    """The per-cell mass of a position Gaussian (x-y covariance zero) against scipy's CDF of
    the rectangle, on a 5x4 grid of cells of side 2 with the mean near a corner."""
    example = _load_example()
    mean = np.array([2.7, 0.3, 1.1, -0.2])
    covar = np.diag([0.8, 0.05, 0.5, 0.05])
    got = example.cell_masses(mean, covar, 2.0, 5, 4)
    assert got.shape == (4, 5)
    mvn = multivariate_normal([mean[0], mean[2]], np.diag([covar[0, 0], covar[2, 2]]))
    for iy in range(4):
        for ix in range(5):
            x0, x1, y0, y1 = 2.0 * ix, 2.0 * ix + 2, 2.0 * iy, 2.0 * iy + 2
            want = (mvn.cdf([x1, y1]) - mvn.cdf([x0, y1]) - mvn.cdf([x1, y0])
                    + mvn.cdf([x0, y0]))
            assert got[iy, ix] == pytest.approx(want, abs=1e-6)


def test_the_gnn_example_runs_every_step_and_is_scored(tmp_path):
    """On a 25-step export it writes one row or more per step ``0 .. 24`` (steps without a
    positive look included), labels unique within a step, one count per step; ``mttbench
    score`` scores it with the track metrics on, and it tracks (OSPA below the cutoff)."""
    pytest.importorskip("stonesoup")
    out = tmp_path / "worlds"
    assert main(["export", "births", "--seed-list", "2", "--policy", "raster", "--steps", "25",
                 "--out", str(out)]) == 0
    world = out / ex.world_name("births", 2, "raster", 24)
    steps = pd.read_csv(world / "steps.csv")
    assert (steps["n_positive"] == 0).any()  # some steps have no scan in Stone Soup's reader
    subprocess.run([sys.executable, str(GNN_EXAMPLE), str(world)], check=True,
                   capture_output=True)
    est = pd.read_csv(world / "stonesoup_gnn.csv")
    assert list(est.columns) == ["step", "x", "y", "label", "count"]
    assert sorted(est["step"].unique()) == list(range(25))
    states = est.dropna(subset=["x"])
    assert len(states) > 0 and states["label"].notna().all()
    assert not states.duplicated(["step", "label"]).any()
    assert (est.groupby("step")["count"].nunique() == 1).all() and (est["count"] >= 0).all()
    res = tmp_path / "scored"
    assert main(["score", str(world), "--estimates", str(world / "stonesoup_gnn.csv"),
                 "--name", "gnn", "--out", str(res)]) == 0
    rows = pd.read_parquet(res / "results.parquet")
    assert (res / "summary.md").is_file() and (res / "score.json").is_file()
    assert sorted(rows["step"]) == list(range(25)) and set(rows["status"]) == {"ok"}
    assert rows["ospa2"].notna().all()  # labels given: the track scores are on
    assert rows["ospa"].between(0, 2).all() and rows["ospa"].mean() < 2.0  # it tracks

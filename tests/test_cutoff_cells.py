"""The OSPA/GOSPA cut-off defaults to 2 cells: ``c = 2 * cell_size`` world units."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from mttbench.benchmarks.app import summary
from mttbench.benchmarks.engine.loop import Job, run_job
from mttbench.benchmarks.engine.metrics import ospa
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.scenarios import spec


def _scaled(size: float) -> spec.Scenario:
    """``default`` with cells of ``size`` world units (positions and velocities scaled)."""
    d = spec.to_dict(spec.get("default"))
    d["grid"]["cell_size"] = size
    d["targets"]["initial_states"] = [[v * size for v in s]
                                      for s in d["targets"]["initial_states"]]
    d["targets"]["birth_velocity_std"] *= size
    d["dynamics"]["wna_intensity"] *= size * size
    d["n_steps"] = 4
    d["name"] = f"default-{size:g}"
    return spec.from_dict(d)


@pytest.mark.parametrize("size", [1.0, 50.0])
def test_default_is_two_cells(size):
    """Without ``c`` a run is scored at ``2 * cell_size``: the rows record it, each step's
    OSPA equals the metric at that cut-off (the null tracker reports nothing, so every
    step is at the cut-off), and the job's key equals the key of the explicit value."""
    sc = _scaled(size)
    job = Job(sc, TrackerSpec("null"), seed=0)
    rows = run_job(job)
    rows = rows[rows["step"] >= 0]
    assert (rows["ospa_c"] == 2 * size).all()
    assert rows["ospa"].iloc[0] == pytest.approx(2 * size)
    x = np.array([[s[0], s[2]] for s in sc.model.birth_death.initial_states])
    assert ospa(x, np.zeros((0, 2)), c=2 * size).total == pytest.approx(2 * size)
    assert job.key(None, 2.0) == job.key(2 * size, 2.0)
    assert job.key(None, 2.0) != job.key(2.0 if size != 1.0 else 3.0, 2.0)
    explicit = run_job(job, c=1.5 * size)
    assert (explicit.loc[explicit["step"] >= 0, "ospa_c"] == 1.5 * size).all()


def test_summary_prints_c_with_units(monkeypatch):
    """The summary's line names c in world units and in cells of the scenario."""
    sc = _scaled(50.0)
    monkeypatch.setattr(spec, "get", lambda name: sc)
    rows = pd.DataFrame({"scenario": [sc.name], "ospa_c": [100.0], "ospa_p": [2.0]})
    assert summary.cutoff_text(rows) == "c = 100 (2 cells of 50), p = 2"
    monkeypatch.setattr(spec, "get", lambda name: (_ for _ in ()).throw(KeyError(name)))
    assert summary.cutoff_text(rows) == "c = 100 world units, p = 2"

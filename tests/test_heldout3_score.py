"""``score`` refuses a world whose truth holds a step past the card's last one, even when
that step is exactly ``n_steps`` and the table's checksum is the card's (a truth row the
scoring loop would silently skip): the card's ``n_steps`` is the reference."""

from __future__ import annotations

import json

import pandas as pd
from test_score_guards import _copy, _score, _world, exported, one_line  # noqa: F401

from mttbench.benchmarks.app import export as ex


def test_a_truth_row_at_step_n_steps_is_refused(exported, tmp_path, capsys):  # noqa: F811
    world = _world(_copy(exported, tmp_path))
    card = json.loads((world / ex.CARD).read_text())
    n = int(card["scenario"]["n_steps"])
    path = world / "truth.parquet"
    truth = pd.read_parquet(path)
    assert truth["step"].max() == n - 1
    extra = truth[truth["step"] == n - 1].assign(step=n)
    pd.concat([truth, extra], ignore_index=True).to_parquet(path, index=False)
    card["files"]["truth.parquet"]["sha256"] = ex.sha256_of(path)  # a consistent card
    (world / ex.CARD).write_text(json.dumps(card))
    out = tmp_path / "scored"
    assert _score(world, out) == 2
    assert f"truth has steps outside 0..{n - 1}" in one_line(capsys)
    assert not out.exists()


def test_steps_file_times_follow_tau_as_the_stone_soup_files_do():
    """With ``tau = 2.5`` the steps file's time is ``step * tau`` and agrees with the time
    the Stone Soup truth and look files give each step."""
    import dataclasses

    import numpy as np

    from mttbench import scenarios
    from mttbench.benchmarks.engine.specs import PolicySpec

    base = scenarios.get("default")
    model = dataclasses.replace(base.model,
                                dynamics=dataclasses.replace(base.model.dynamics, tau=2.5))
    sc = dataclasses.replace(base, model=model, n_steps=6)
    world = ex.draw_world(sc, PolicySpec("raster"), 0)
    steps = ex.steps_table(world)
    assert np.array_equal(steps["time"].to_numpy(), np.arange(6) * 2.5)
    soup = ex.stonesoup_tables(world)
    by_step = dict(zip(steps["step"], steps["time"], strict=True))
    for name in ("stonesoup_truth.csv", "stonesoup_detections.csv", "stonesoup_misses.csv"):
        table = soup[name]
        assert len(table) or name == "stonesoup_detections.csv"
        assert [by_step[k] for k in table["step"]] == table["time"].tolist(), name

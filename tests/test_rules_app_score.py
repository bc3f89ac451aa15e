"""Rules of ``mttbench score`` (``benchmarks/app/score.py``) where a slip shows: the line
number of a bad CSV row (the header is line 1), seed 0 and a zero look budget in a
model card, a table step equal to ``n_steps``, a world name with a folder part, the
default reference without ``kfnn``, other runs whose failed rows reach further than
their finished ones, the default cut-off on cells that are not 1, a 64-character name.
One exported world of 3 steps; the expected values are written from the format's rules."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from mttbench import scenarios
from mttbench.benchmarks.app import export as ex
from mttbench.benchmarks.app import score
from mttbench.benchmarks.app.usage import UsageError
from mttbench.benchmarks.engine.specs import PolicySpec


@pytest.fixture(scope="module")
def world_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("worlds")
    sc = dataclasses.replace(scenarios.get("default"), n_steps=3)
    ex.export_worlds([sc], [PolicySpec("raster")], [0], out)
    return out / ex.world_name("default", 0, "raster", 24)


def _nothing(n: int) -> list[score.StepEstimate]:
    return [score.StepEstimate(np.zeros((0, 2)), None, 0.0) for _ in range(n)]


def test_a_bad_csv_value_is_named_by_its_line_with_the_header_as_line_1(tmp_path):
    path = tmp_path / "e.csv"
    path.write_text("step,x,y\n0,1.0,2.0\n1,oops,2.0\n")
    with pytest.raises(UsageError, match=r"x 'oops' on line 3 is not a number"):
        score.read_estimates(path, 3)


def test_an_estimate_at_step_n_steps_is_beyond_the_world(tmp_path):
    path = tmp_path / "e.csv"
    path.write_text("step,x,y\n0,1.0,2.0\n3,1.0,2.0\n")
    with pytest.raises(UsageError, match=r"step 3 on line 3 is beyond the world"):
        score.read_estimates(path, 3)
    path.write_text("step,x,y\n0,1.0,2.0\n2,1.0,2.0\n")
    assert len(score.read_estimates(path, 3)) == 3


def _card(**policy) -> dict:
    pol = {"name": "raster", "label": "raster", "params": {}, "looks_per_step": 24}
    pol.update(policy)
    return {"scenario": {"name": "a", "n_steps": 3}, "seed": 0, "policy": pol,
            "files": {"truth.csv": {"sha256": "0" * 64}, "looks.csv": {"sha256": "0" * 64}}}


def test_a_card_with_seed_zero_and_no_look_budget_is_allowed(tmp_path):
    score._check_card(tmp_path, _card())
    score._check_card(tmp_path, _card(looks_per_step=0))
    with pytest.raises(UsageError, match="seed = -1"):
        score._check_card(tmp_path, {**_card(), "seed": -1})
    with pytest.raises(UsageError, match="policy.looks_per_step = -1"):
        score._check_card(tmp_path, _card(looks_per_step=-1))


def test_a_table_step_equal_to_n_steps_is_refused(world_dir):
    world = score.read_world(world_dir)
    truth = world.truth.copy()
    truth.loc[truth.index[-1], "step"] = world.n_steps
    with pytest.raises(UsageError, match="truth has steps outside 0..2"):
        score._check_steps(dataclasses.replace(world, truth=truth))


def test_a_world_name_with_a_folder_part_is_refused(tmp_path):
    (tmp_path / ex.WORLDS_INDEX).write_text("world\nsub/w1\n")
    with pytest.raises(UsageError, match="'sub/w1' is not a world folder's name"):
        score.world_folders(tmp_path)


def test_the_default_reference_is_kfnn_else_the_first_inside_tracker():
    table = pd.DataFrame({"tracker_label": ["outside:a", "pmb", "gpf", "truth-aided"],
                          "tracker_uses_truth": [False, False, False, True]})
    assert score._reference(table) == "gpf"
    table.loc[1, "tracker_label"] = "kfnn"
    assert score._reference(table) == "kfnn"


def test_other_runs_are_compared_by_their_finished_steps(world_dir, tmp_path):
    world = score.read_world(world_dir)
    rows = score.score_world(world, _nothing(world.n_steps), "mine")
    other = rows.assign(tracker="kfnn", tracker_label="kfnn")
    other.loc[other["step"] == 2, ["status", "error"]] = ["error", "boom"]
    other.to_parquet(tmp_path / "results.parquet", index=False)
    with pytest.raises(UsageError, match="have 2 steps, the world 3"):
        score.load_beside(tmp_path, rows, None, 2.0)
    rows.assign(tracker="kfnn", tracker_label="kfnn").to_parquet(
        tmp_path / "results.parquet", index=False)
    assert len(score.load_beside(tmp_path, rows, None, 2.0)) == len(rows)


def test_the_default_cut_off_is_two_of_the_worlds_cells(world_dir):
    world = score.read_world(world_dir)
    card = {**world.card, "grid": {**world.card["grid"], "cell_size": 2.5}}
    rows = score.score_world(dataclasses.replace(world, card=card), _nothing(3), "mine")
    assert set(rows["ospa_c"]) == {5.0}
    # no estimate, targets present: OSPA is the cut-off
    has = rows["true_count"] > 0
    assert np.allclose(rows.loc[has, "ospa"], 5.0)


def test_a_name_of_64_characters_is_allowed():
    assert score.check_name("a" * 64) == "a" * 64
    with pytest.raises(UsageError):
        score.check_name("a" * 65)

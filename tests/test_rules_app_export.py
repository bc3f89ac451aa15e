"""Rules of ``mttbench export`` (``benchmarks/app/export.py``) where a slip shows: a grid
that is not square (the row of a cell is ``cell // nx``), a look's point at its cell's
centre, steps after the last look, a world of exactly the size limit, the scenario's own
budget without ``--looks``, a label with a dot, a world exported twice into one folder.
Worlds of 2-3 steps; the expected values are written from the documented formulas."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from mttbench import scenarios
from mttbench.benchmarks.app import export as ex
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.specs import PolicySpec
from mttbench.scenarios.spec import dumps, loads


def _wide_scenario(n_steps: int = 2):
    """The default scenario on a grid 12 cells wide and 10 high (the targets stay
    inside), ``n_steps`` long."""
    text = dumps(dataclasses.replace(scenarios.get("default"), n_steps=n_steps))
    return loads(text.replace("name = \"default\"", "name = \"wide\"").replace(
        "ny = 12", "ny = 10"))


@pytest.fixture(scope="module")
def world() -> ex.World:
    sc = _wide_scenario()
    assert (sc.grid.nx, sc.grid.ny) == (12, 10)
    return ex.draw_world(sc, PolicySpec("raster"), 5)


def test_a_looks_row_and_column_on_a_grid_that_is_not_square(world):
    looks = world.looks
    assert (looks["cell"] >= 12).any()  # the raster's 24 looks reach the second row
    np.testing.assert_array_equal(looks["ix"], looks["cell"] % 12)
    np.testing.assert_array_equal(looks["iy"], looks["cell"] // 12)


def test_the_stone_soup_looks_sit_at_the_cells_centre(world):
    s = world.scenario.grid.cell_size
    tables = ex.stonesoup_tables(world)
    both = pd.concat([tables["stonesoup_detections.csv"], tables["stonesoup_misses.csv"]])
    both = both.sort_values(["step", "look"])
    np.testing.assert_allclose(both["x"], (world.looks["ix"].to_numpy() + 0.5) * s)
    np.testing.assert_allclose(both["y"], (world.looks["iy"].to_numpy() + 0.5) * s)


def test_the_steps_table_lists_the_steps_after_the_last_look(world):
    sc = dataclasses.replace(world.scenario, n_steps=4)
    looks = world.looks[world.looks["step"] == 0]
    w = dataclasses.replace(world, scenario=sc, looks=looks)
    table = ex.steps_table(w)
    assert list(table["step"]) == [0, 1, 2, 3]
    assert list(table["n_looks"]) == [len(looks), 0, 0, 0]
    assert list(table["n_positive"]) == [int(looks["return"].sum()), 0, 0, 0]


def test_a_world_of_exactly_the_size_limit_is_allowed():
    sc = dataclasses.replace(scenarios.get("default"), n_steps=1000)
    ex.check_size([sc], [ex.MAX_WORLD_LOOKS // 1000])
    with pytest.raises(ConfigError, match="too many to export"):
        ex.check_size([sc], [ex.MAX_WORLD_LOOKS // 1000 + 1])


def test_without_looks_the_scenarios_own_budget_is_checked():
    m = scenarios.get("default").model.sensor.looks_per_step
    sc = dataclasses.replace(scenarios.get("default"), n_steps=ex.MAX_WORLD_LOOKS // m + 1)
    with pytest.raises(ConfigError, match=f"x {m} looks"):
        ex.check_size([sc], None)


def test_a_world_name_keeps_letters_digits_dot_underscore_dash():
    assert ex.world_name("a.b-c_d", 3, "renyi(alpha=0.5)", 24) == \
        "a.b-c_d__seed3__renyi_alpha_0.5___m24"


def test_a_world_exported_again_is_listed_once(tmp_path):
    sc = _wide_scenario(2)
    for _ in range(2):
        ex.export_worlds([sc], [PolicySpec("raster")], [1], tmp_path)
    index = pd.read_csv(tmp_path / ex.WORLDS_INDEX)
    assert list(index["world"]) == [ex.world_name("wide", 1, "raster", 24)]

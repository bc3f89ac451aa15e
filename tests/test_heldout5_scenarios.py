"""Scenario rules a tracker's prior and a world's occlusions rest on: an occlusion's index
ranges and the initial count mean. References: the documented ranges applied by hand to
every pair tried; the simulator's own step-0 targets."""

from __future__ import annotations

import dataclasses
import itertools

import pytest
from test_heldout3_spec import WIDE_GRID as WIDE  # a 10 x 4 grid, an [[occlusion]] opened

from mttbench import scenarios
from mttbench.scenarios.model import BirthDeath
from mttbench.scenarios.simulator import simulate
from mttbench.scenarios.spec import ScenarioError, loads


@pytest.mark.parametrize(("field", "upper"), [("x", 10), ("y", 4), ("steps", 5)])
def test_an_occlusions_ranges_are_indices_below_the_grid_size_and_step_count(field, upper):
    """``[first, last]`` with ``0 <= first <= last < upper`` (nx, ny, n_steps), every pair
    of -1..upper+1 tried: the allowed ones load, the others are refused naming the field."""
    base = {"x": [0, 1], "y": [0, 1], "steps": [0, 4]}
    for first, last in itertools.product(range(-1, upper + 2), repeat=2):
        ranges = {**base, field: [first, last]}
        text = WIDE + "".join(f"{k} = {v}\n" for k, v in ranges.items())
        if 0 <= first <= last < upper:
            loads(text)
        else:
            with pytest.raises(ScenarioError, match=field):
                loads(text)


@pytest.mark.parametrize(("declared", "drawn"), [(0, 3), (2, 0), (2, 3)])
def test_the_initial_count_mean_is_every_target_present_at_step_zero(declared, drawn):
    """The declared initial states plus the randomly drawn initial targets: the number of
    targets the simulator puts at step 0 (no deaths, no births)."""
    sc = scenarios.get("default")
    states = tuple((1.5 + i, 0.0, 1.5, 0.0) for i in range(declared))
    bd = BirthDeath(initial_states=states, n_random_initial=drawn, survival_probability=1.0,
                    birth_rate=0.0)
    sc = dataclasses.replace(sc, model=dataclasses.replace(sc.model, birth_death=bd),
                             n_steps=1)
    assert bd.initial_count_mean == len(simulate(sc, 0).states[0]) == declared + drawn


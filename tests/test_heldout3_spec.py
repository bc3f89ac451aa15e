"""Occlusion speeds on a grid that is not square: each axis's speed is bounded by that
axis's own cell count (``|vx| < nx``, ``|vy| < ny``, the spec's documented rule, applied
here by hand to every speed tried)."""

from __future__ import annotations

import itertools

import pytest

from mttbench.scenarios.spec import ScenarioError, loads

WIDE_GRID = """
name = "wide"
n_steps = 5

[grid]
nx = 10
ny = 4

[dynamics]
wna_intensity = 0.001

[targets]
initial_states = [[1.5, 0.0, 1.5, 0.0]]

[sensor]
kind = "rayleigh"
snr = 10.0
looks_per_step = 4

[[occlusion]]
"""
#: one occlusion box on ``WIDE_GRID`` (its speed added by each test)
WIDE = WIDE_GRID + "x = [0, 1]\ny = [0, 1]\nsteps = [0, 4]\n"


@pytest.mark.parametrize("vx, vy", list(itertools.product([0.0, 3.5, 9.5, 10.0, -10.0],
                                                     [0.0, 3.5, 4.0, -4.0, 9.5])))
def test_each_speed_is_bounded_by_its_own_axis(vx, vy):
    text = WIDE + f"velocity = [{vx}, {vy}]\n"
    if abs(vx) < 10 and abs(vy) < 4:
        occ = loads(text).model.visibility.occlusions[0]
        assert occ.velocity == (vx, vy)
    else:
        with pytest.raises(ScenarioError, match="velocity"):
            loads(text)

"""Visibility in the model: the ``[[occlusion]]`` tables, the blind cells of a step, and
every policy choosing among the visible cells (the harness drops any other look)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mttbench import scenarios
from mttbench.benchmarks.engine.loop import TIMING_COLUMNS, Job, play, run_job
from mttbench.benchmarks.engine.policies import (
    Policy,
    Raster,
    available_policies,
    get_policy_class,
    make_policy,
)
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec
from mttbench.scenarios.model import Grid, Occlusion, Visibility
from mttbench.scenarios.spec import ScenarioError, dumps, loads
from mttbench.trackers import make as make_tracker
from mttbench.trackers.cells import CellCounts

BASE = dumps(dataclasses.replace(scenarios.get("default"), n_steps=30))
BAND = """
[[occlusion]]
x = [2, 4]
y = [0, 11]
steps = [3, 25]
velocity = [1, 0]

[[occlusion]]
x = [9, 11]
y = [9, 11]
steps = [0, 10]
"""


def occluded(text: str = BAND):
    return loads(BASE + text)


def brute_blind(occ: Occlusion, k: int, grid: Grid) -> set[int]:
    """The blind cells by walking the rectangle cell by cell, shifted and wrapped."""
    if not occ.steps[0] <= k <= occ.steps[1]:
        return set()
    t = k - occ.steps[0]
    out = set()
    for ix in range(occ.x[0], occ.x[1] + 1):
        for iy in range(occ.y[0], occ.y[1] + 1):
            jx = (ix + int(np.floor(occ.velocity[0] * t))) % grid.nx
            jy = (iy + int(np.floor(occ.velocity[1] * t))) % grid.ny
            out.add(jy * grid.nx + jx)
    return out


# ------------------------------------------------------------------------ the model
@pytest.mark.parametrize("velocity", [(0, 0), (1, 0), (-2, 1), (3, -4), (0.25, -0.5)])
def test_blocked_cells_match_brute_force(velocity):
    grid = Grid(7, 5)
    occ = Occlusion(x=(1, 3), y=(2, 4), steps=(2, 9), velocity=velocity)
    other = Occlusion(x=(5, 6), y=(0, 0), steps=(4, 4))
    vis = Visibility((occ, other))
    every = np.arange(grid.n_cells)
    for k in range(12):
        want = sorted(brute_blind(occ, k, grid) | brute_blind(other, k, grid))
        got = vis.blocked(k, grid)
        assert got.tolist() == want
        assert got.dtype == np.int64
        assert np.flatnonzero(vis.is_blocked(k, every, grid)).tolist() == want


def test_no_visibility_blinds_nothing():
    sc = scenarios.get("default")
    assert sc.model.visibility == Visibility()
    assert sc.model.blocked_cells(0).size == 0


# ---------------------------------------------------------------------- the format
def test_round_trip_and_preset_text_unchanged():
    sc = occluded()
    assert loads(dumps(sc)) == sc
    assert sc.model.visibility.occlusions[0] == Occlusion((2, 4), (0, 11), (3, 25), (1.0, 0.0))
    assert sc.model.visibility.occlusions[1].velocity == (0, 0)
    # a scenario without occlusions writes no occlusion key (older files stay as they were)
    assert "occlusion" not in dumps(scenarios.get("default"))


@pytest.mark.parametrize("table, message", [
    ("x = [2, 12]\ny = [0, 1]\nsteps = [0, 3]",
     "[[occlusion]] #1.x = [2, 12] is not allowed: expected two column indices [first, "
     "last] with 0 <= first <= last < 12"),
    ("x = [4, 2]\ny = [0, 1]\nsteps = [0, 3]", "#1.x = [4, 2] is not allowed"),
    ("x = [1]\ny = [0, 1]\nsteps = [0, 3]", "#1.x = [1] is not allowed"),
    ("x = [0.5, 2]\ny = [0, 1]\nsteps = [0, 3]", "#1.x = [0.5, 2] is not allowed"),
    ("x = [true, 2]\ny = [0, 1]\nsteps = [0, 3]", "#1.x = [True, 2] is not allowed"),
    ("x = [0, 2]\ny = [-1, 1]\nsteps = [0, 3]", "#1.y = [-1, 1] is not allowed: expected two row"),
    ("x = [0, 2]\ny = [0, 1]\nsteps = [0, 30]",
     "#1.steps = [0, 30] is not allowed: expected two steps [first, last] with 0 <= first "
     "<= last < 30"),
    ("x = [0, 2]\ny = [0, 1]\nsteps = [5, 3]", "#1.steps = [5, 3] is not allowed"),
    ("x = [0, 2]\ny = [0, 1]\nsteps = [0, 3]\nvelocity = [12, 0]",
     "#1.velocity = [12, 0] is not allowed: expected two numbers [vx, vy]"),
    ("x = [0, 2]\ny = [0, 1]\nsteps = [0, 3]\nvelocity = [nan, 0]", "#1.velocity = [nan, 0]"),
    ("x = [0, 2]\ny = [0, 1]\nsteps = [0, 3]\nvelocity = [1]", "#1.velocity = [1]"),
    ("x = [0, 2]\ny = [0, 1]", "missing field(s) ['steps'] in [[occlusion]] #1"),
    ("x = [0, 2]\ny = [0, 1]\nsteps = [0, 3]\nwhen = 2", "unknown key(s) ['when'] in"),
])
def test_bad_occlusions_are_refused_in_one_line(table, message):
    with pytest.raises(ScenarioError) as err:
        loads(BASE + "\n[[occlusion]]\n" + table + "\n")
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def test_second_table_named_and_other_shapes_refused():
    good = "\n[[occlusion]]\nx = [0, 1]\ny = [0, 1]\nsteps = [0, 3]\n"
    with pytest.raises(ScenarioError, match=r"\[\[occlusion\]\] #2.x = \[0, 99\]"):
        loads(BASE + good + "\n[[occlusion]]\nx = [0, 99]\ny = [0, 1]\nsteps = [0, 3]\n")
    with pytest.raises(ScenarioError, match="occlusion must be an array of tables"):
        loads(BASE.replace("n_steps = 30", "n_steps = 30\nocclusion = 3"))


def test_occlusion_needs_a_grid_sensor():
    text = dumps(scenarios.get("superposition"))
    with pytest.raises(ScenarioError, match="applies to a rayleigh"):
        loads(text + "\n[[occlusion]]\nx = [0, 1]\ny = [0, 1]\nsteps = [0, 3]\n")


# ---------------------------------------------------------------------- the policies
def _counts(rng, n_cells, n_counts=3):
    return rng.dirichlet(np.ones(n_counts) * 0.4, size=n_cells)


@pytest.mark.parametrize("name", available_policies())
@pytest.mark.parametrize("looks", [5, 24, 200])
def test_every_policy_looks_at_visible_cells_only_and_wastes_none(name, looks):
    sc = occluded()
    model, grid = sc.model, sc.grid
    policy = make_policy(name)
    policy.reset(model, looks, np.random.default_rng(1))
    rng = np.random.default_rng(2)
    for k in range(sc.n_steps):
        blind = model.blocked_cells(k)
        n_visible = grid.n_cells - blind.size
        truth = np.array([0, 30, 31, blind[0] if blind.size else 7])
        cells = policy.select(k, counts=_counts(rng, grid.n_cells), truth_cells=truth)
        assert not np.isin(cells, blind).any(), (name, k)
        repeats_allowed = name == "raster"
        if name == "all":
            assert len(cells) == n_visible
        elif repeats_allowed:
            assert len(cells) == looks
        else:
            assert len(cells) == min(looks, n_visible) == len(np.unique(cells))


@pytest.mark.parametrize("name, repeats", [("renyi", False), ("renyi", True),
                                           ("lookahead", False), ("lookahead", True),
                                           ("search-track", None)])
def test_sparse_path_skips_blind_cells(name, repeats):
    """A grid beyond the dense path (60x60): the blind cells, own or default, are never
    chosen, and a blind band over most own cells leaves the looks to visible ones."""
    sc = loads(BASE.replace("nx = 12", "nx = 60").replace("ny = 12", "ny = 60")
               + "\n[[occlusion]]\nx = [0, 29]\ny = [0, 59]\nsteps = [0, 29]\nvelocity = [1, 0]\n")
    model = sc.model
    rng = np.random.default_rng(3)
    own = np.sort(rng.choice(model.grid.n_cells, 80, replace=False))
    default = np.array([0.995, 0.004, 0.001])
    rows = rng.dirichlet(np.ones(3), size=own.size)
    policy = make_policy(name) if repeats is None else make_policy(name, repeats=repeats)
    policy.reset(model, 40, np.random.default_rng(4))
    for k in range(0, 30, 7):
        cells = policy.select(k, counts=CellCounts(model.grid.n_cells, own, rows, default))
        blind = model.blocked_cells(k)
        assert not np.isin(cells, blind).any()
        assert len(cells) == 40
        if name == "renyi" and not repeats:  # own rows beat the near-empty default row
            assert set(own[~np.isin(own, blind)]) <= set(cells)


class _Stubborn(Policy):
    """Always the first M cells, blind or not."""

    name = "stubborn"
    parameters = {}

    def select(self, k, counts=None, truth_cells=None):
        return np.arange(self._n_looks, dtype=np.int64)


def test_play_drops_looks_at_blind_cells():
    sc = occluded("\n[[occlusion]]\nx = [0, 3]\ny = [0, 0]\nsteps = [2, 4]\n")
    for rec in play(sc, make_tracker("null"), 0, policy=_Stubborn(), looks_per_step=6):
        blind = sc.model.blocked_cells(rec.k)
        assert not np.isin(rec.looks.cells, blind).any()
        want = [4, 5] if 2 <= rec.k <= 4 else [0, 1, 2, 3, 4, 5]
        assert rec.looks.cells.tolist() == want


# --------------------------------------------------------------- nothing blind, no change
SAMENESS_POLICIES = ["raster", "random", "renyi", "oracle", "lookahead", "all"]


@pytest.mark.parametrize("policy", SAMENESS_POLICIES)
def test_inactive_occlusion_changes_no_row(policy):
    """A visibility whose occlusion never blinds a cell during the run (it lies past the
    last step: the model type allows it, a file would not) gives the rows of the scenario
    without one, bit for bit: the visibility code paths (the harness's filter, raster's
    walking pointer, the policies' visible draws) are the identity when nothing is blind."""
    plain = dataclasses.replace(scenarios.get("default"), n_steps=12)
    late = dataclasses.replace(plain, model=dataclasses.replace(
        plain.model, visibility=Visibility((Occlusion((0, 11), (0, 11), (50, 60)),))))
    spec = PolicySpec.parse(policy).validated()
    tracker = TrackerSpec.parse("gpf").validated()
    rows = [run_job(Job(sc, tracker, spec, 24, 3)).drop(columns=[*TIMING_COLUMNS, "peak_rss_mb"])
            for sc in (plain, late)]
    assert (rows[1]["status"] == "ok").all()
    assert rows[0].equals(rows[1])


def test_raster_walks_the_visible_cells_and_resumes():
    sc = loads(BASE + "\n[[occlusion]]\nx = [0, 11]\ny = [1, 1]\nsteps = [1, 1]\n")
    r = Raster()
    r.reset(sc.model, 10, np.random.default_rng(0))
    assert r.select(0).tolist() == list(range(10))
    # step 1: row 1 (cells 12-23) is blind, the sweep continues at 10, 11, then 24..31
    assert r.select(1).tolist() == [10, 11, *range(24, 32)]
    assert r.select(2).tolist() == list(range(32, 42))


def test_every_registered_policy_is_covered():
    """A policy registered later is run by the tests above through the registry."""
    assert {"lookahead", "renyi", "raster"} <= set(available_policies())
    assert all(issubclass(get_policy_class(n), Policy) for n in available_policies())

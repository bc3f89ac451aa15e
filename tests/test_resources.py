"""Resource estimates (``benchmarks/app/resources.py``): the formulas, the refusal, the warning,
and that the memory estimate bounds what a run really takes -- on a 1e5 x 1e5 grid too,
which the estimate must accept and a run must not need ``O(cells)`` memory for."""

from __future__ import annotations

import ctypes
import ctypes.util
import dataclasses
import gc
import math
import multiprocessing
import re
import resource
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from mttbench import scenarios, trackers
from mttbench.benchmarks.app import resources
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.app.compare import default_tracker_texts
from mttbench.benchmarks.engine import policies
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.information import DENSE_CELLS
from mttbench.benchmarks.engine.loop import Job, build_jobs, run_job
from mttbench.benchmarks.engine.specs import (
    PolicySpec,
    TrackerSpec,
    parse_spec,
    resolve_trackers,
)
from mttbench.scenarios import simulator
from mttbench.scenarios.model import Grid
from mttbench.scenarios.spec import dumps
from mttbench.trackers.base import BOX_CELLS, LOOKED_CELL_BYTES, ResourceTerms
from mttbench.trackers.jmpd.ap import AP_SLOT_BYTES, _auto_slots
from mttbench.trackers.jmpd.tracker import (
    JMPD_IP_SLOT_T_BYTES,
    JMPD_LOOK_BYTES,
    JMPD_SLOT_BYTES,
    JMPD_SLOT_T_BYTES,
    default_t_max,
)
from mttbench.trackers.null import NullTracker

GIB = 2.0**30
MIB = 2.0**20
HUGE = 100_000  # a 1e5 x 1e5 grid: 1e10 cells


def scenario(nx: int, ny: int | None = None, steps: int = 100, looks: int | None = None,
             preset: str = "default"):
    sc = scenarios.get(preset)
    sensor = sc.model.sensor if looks is None else dataclasses.replace(sc.model.sensor,
                                                                       looks_per_step=looks)
    model = dataclasses.replace(sc.model, grid=Grid(nx, ny or nx), sensor=sensor)
    return dataclasses.replace(sc, model=model, n_steps=steps, name=f"grid{nx}")


def job(sc, tracker="null", policy="raster", looks=None, policy_params=None, **params) -> Job:
    return Job(sc, TrackerSpec(tracker, params), PolicySpec(policy, policy_params or {}),
               looks, 0)


# ------------------------------------------------------------------ the formulas
def test_simulator_term_is_jump_tables_and_looks():
    """10,000 x 20,000 cells: positions below 2e8 take two 16-bit jump tables; the
    looks' arrays are per look, the grid's cells add nothing."""
    est = resources.estimate_job(job(scenario(10_000, 20_000, steps=7)))
    assert est.parts["simulator"] == 2 * resources.JUMP_TABLE_BYTES + 24 * resources.LOOK_BYTES
    assert resources.JUMP_TABLE_BYTES == 2 * MIB
    assert est.memory == pytest.approx(sum(est.parts.values()))
    assert est.largest_part() == "worker"
    small = resources.estimate_job(job(scenario(12, steps=7)))
    assert small.parts["simulator"] == resources.JUMP_TABLE_BYTES + 24 * resources.LOOK_BYTES


@pytest.mark.parametrize(("looks", "cells", "repeats", "rows"), [
    (24, 144, False, 1), (144, 144, False, 1), (145, 144, False, 2), (312, 144, False, 3),
    (24, 144, True, 24), (0, 144, False, 1),
])
def test_rows_per_step(looks, cells, repeats, rows):
    assert resources.rows_per_step(looks, cells, repeats) == rows


@pytest.mark.parametrize("n", [1, 2, 2**16 - 1, 2**16, 2**16 + 1, 144 * 312, 10**10,
                               2**48 - 1, 2**48])
def test_jump_tables_are_those_the_simulator_builds(monkeypatch, n):
    """:func:`resources.jump_tables` against the tables ``pcg64_uniforms`` asks for when
    it draws the last position below ``n``."""
    asked = []
    real = simulator._jump_table

    def spy(i):
        asked.append(i)
        return real(i)

    monkeypatch.setattr(simulator, "_jump_table", spy)
    simulator.pcg64_uniforms(12345, 6789, [n - 1])
    assert resources.jump_tables(n) == max(asked) + 1


def test_no_term_grows_with_the_grid_past_the_dense_path():
    """Every registered tracker under raster and renyi: a 1e5 x 1e5 grid costs what a
    3000 x 3000 one does (both above DENSE_CELLS), but for the simulator's jump tables
    (three against two); on a grid within the dense path renyi adds its dense rows."""
    assert 3000**2 > DENSE_CELLS
    extra_tables = resources.jump_tables(HUGE**2) - resources.jump_tables(3000**2)
    assert extra_tables == 1
    for name in trackers.available():
        for policy in ("raster", "renyi"):
            small = resources.estimate_job(job(scenario(3000, preset="large"), name, policy))
            huge = resources.estimate_job(job(scenario(HUGE, preset="large"), name, policy))
            assert small.parts.keys() == huge.parts.keys(), (name, policy)
            for part, value in huge.parts.items():
                more = extra_tables * resources.JUMP_TABLE_BYTES if part == "simulator" else 0
                assert value == small.parts[part] + more, (name, policy, part)
    dense = resources.estimate_job(job(scenario(50), "null", "renyi"))
    sparse = resources.estimate_job(job(scenario(51), "null", "renyi"))
    per_row = resources.PREDICTION_ROW_BYTES + 2 * resources.PREDICTION_COUNT_BYTES
    assert dense.parts["predicted cell counts"] == 2500 * per_row  # null: no own rows
    assert sparse.parts["predicted cell counts"] == 0


def test_tracker_and_prediction_terms_follow_the_parameters():
    sc = scenario(12)  # 24 looks on 144 cells, 3 targets, 100 steps
    r = resources
    small = r.estimate_job(job(sc, "jmpd", n_particles=1000, t_max=5))
    big = r.estimate_job(job(sc, "jmpd", n_particles=4000, t_max=10))
    assert small.parts["tracker"] == (1000 * 5 * (JMPD_SLOT_BYTES + 5 * JMPD_SLOT_T_BYTES)
                                      + 24 * 6 * JMPD_LOOK_BYTES)
    assert big.parts["tracker"] == (4000 * 10 * (JMPD_SLOT_BYTES + 10 * JMPD_SLOT_T_BYTES)
                                    + 24 * 11 * JMPD_LOOK_BYTES)
    ip = r.estimate_job(job(sc, "jmpd-ip", n_particles=1000, t_max=5))
    assert ip.parts["tracker"] == (1000 * 5 * (JMPD_SLOT_BYTES + 5 * JMPD_IP_SLOT_T_BYTES)
                                   + 24 * 6 * JMPD_LOOK_BYTES)
    assert ip.seconds > small.seconds
    assert "predicted cell counts" not in small.parts
    # jmpd without t_max: the slots the model asks for (default_t_max)
    t_auto = default_t_max(sc.model)
    auto = r.estimate_job(job(sc, "jmpd", n_particles=1000))
    assert t_auto != 5 and auto.parts["tracker"] == (
        1000 * t_auto * (JMPD_SLOT_BYTES + t_auto * JMPD_SLOT_T_BYTES)
        + 24 * (t_auto + 1) * JMPD_LOOK_BYTES)
    # jmpd-ap without t_max: its automatic slots
    t_ap = _auto_slots(sc.model)
    ap = r.estimate_job(job(sc, "jmpd-ap"))
    assert ap.parts["tracker"] == 500 * t_ap * AP_SLOT_BYTES + 24 * (t_ap + 1) * JMPD_LOOK_BYTES
    # renyi on 144 cells (the dense path): the gpf's 2 T + 16 = 22 Gaussians' boxes, its
    # own rows capped by the grid, plus the dense rows
    renyi = r.estimate_job(job(sc, "gpf", "renyi", n_counts=7))
    entries = 22 * BOX_CELLS
    rows = min(144, entries + 144) + 144
    assert renyi.parts["predicted cell counts"] == (
        entries * r.ENTRY_BYTES + rows * (r.PREDICTION_ROW_BYTES + 7 * r.PREDICTION_COUNT_BYTES))
    # the fields of the cells looked at so far: 24 per step, at most the grid
    assert renyi.parts["looked cells"] == 144 * LOOKED_CELL_BYTES
    huge = r.estimate_job(job(scenario(HUGE, steps=10), "kfnn"))
    assert huge.parts["looked cells"] == 10 * 24 * LOOKED_CELL_BYTES
    assert "looked cells" not in r.estimate_job(job(scenario(HUGE), "truth-aided")).parts
    # renyi with repeats: a cell may take all 24 looks, positions up to 24 x 1e10
    repeats = r.estimate_job(job(scenario(HUGE), "null", "renyi", policy_params={"repeats": True}))
    assert repeats.parts["simulator"] == (r.jump_tables(24 * HUGE**2) * r.JUMP_TABLE_BYTES
                                          + 24 * r.LOOK_BYTES)
    # the all policy looks at every cell: O(cells) by definition
    every = r.estimate_job(job(scenario(300, steps=3), "null", "all"))
    assert every.parts["simulator"] == r.JUMP_TABLE_BYTES * 2 + 300**2 * r.LOOK_BYTES
    # random: numpy's choice shuffles every cell when there are fewer than 50 per look
    assert r.estimate_job(job(scenario(12), "null", "random")).parts["policy"] == 144 * 8
    assert r.estimate_job(job(scenario(HUGE), "null", "random")).parts["policy"] == 50 * 24 * 8


#: the worlds of :data:`OLD_ESTIMATES`: (grid side, steps, preset)
WORLDS = {"12": (12, 100, "default"), "1e5": (HUGE, 100, "large"), "scale": (500, 10, "scale"),
          "superposition": (12, 100, "superposition")}


def world_job(world: str, tracker: str, policy: str | None, looks: int | None) -> Job:
    side, steps, preset = WORLDS[world]
    return Job(scenario(side, steps=steps, preset=preset),
               TrackerSpec(*parse_spec(tracker, "tracker")),
               PolicySpec(*parse_spec(policy, "policy")) if policy else None, looks, 0)


#: (world, tracker, policy, looks) -> (memory, seconds, parts) as ``estimate_job`` gave them
#: when resources.py still knew every tracker and policy by name: computed
#: by that function (commit c68a429, run from a copy while the classes took their costs
#: over) and pasted here. The classes' terms must give the same numbers, bit for bit
OLD_ESTIMATES: dict[tuple[str, str, str | None, int | None], tuple[float, float, dict]] = {
    ('12', 'null', 'raster', None): (
        422194240.0, 0.2048,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0}),
    ('12', 'null', 'renyi', None): (
        422277184.0, 0.20768000000000003,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'predicted cell counts': 82944.0}),
    ('1e5', 'null', 'renyi', None): (
        426609856.0, 0.25,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'predicted cell counts': 0.0}),
    ('superposition', 'null', None, None): (
        420080000.0, 0.2,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0}),
    ('12', 'kfnn', 'raster', None): (
        422212672.0, 0.314944,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'looked cells': 18432.0}),
    ('12', 'kfnn', 'renyi', None): (
        423515200.0, 0.382784,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'looked cells': 18432.0, 'predicted cell counts': 1302528.0}),
    ('1e5', 'kfnn', 'renyi', None): (
        465230016.0, 2.6698,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'looked cells': 3200000.0, 'predicted cell counts': 35420160.0}),
    ('superposition', 'kfnn', None, None): (
        420080000.0, 0.29000000000000004,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0}),
    ('12', 'truth-aided', 'raster', None): (
        423816256.0, 0.3176,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'tracker': 1622016.0}),
    ('12', 'truth-aided', 'renyi', None): (
        425118784.0, 0.38544,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'predicted cell counts': 1302528.0, 'tracker': 1622016.0}),
    ('1e5', 'truth-aided', 'renyi', None): (
        493518016.0, 3.2447999999999997,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'predicted cell counts': 16220160.0, 'tracker': 50688000.0}),
    ('superposition', 'truth-aided', None, None): (
        420080000.0, 0.24,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0}),
    ('12', 'gpf', 'raster', None): (
        426341440.0, 1.3273440000000003,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'looked cells': 18432.0, 'tracker': 4128768.0}),
    ('12', 'gpf', 'renyi', None): (
        427643968.0, 1.3951840000000004,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'looked cells': 18432.0, 'predicted cell counts': 1302528.0,
         'tracker': 4128768.0}),
    ('1e5', 'gpf', 'renyi', None): (
        518887616.0, 5.3698,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'looked cells': 3200000.0, 'predicted cell counts': 35420160.0,
         'tracker': 53657600.0}),
    ('superposition', 'gpf', None, None): (
        422537600.0, 1.2400000000000002,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0,
         'tracker': 2457600.0}),
    ('12',
     'gpf:n_counts=7,max_components=2,max_combinations=100,max_particles=50',
     'raster', None): (
        424248640.0, 0.827344,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'looked cells': 18432.0, 'tracker': 2035968.0}),
    ('12',
     'gpf:n_counts=7,max_components=2,max_combinations=100,max_particles=50',
     'renyi', None): (
        425634112.0, 0.903824,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'looked cells': 18432.0, 'predicted cell counts': 1385472.0,
         'tracker': 2035968.0}),
    ('1e5',
     'gpf:n_counts=7,max_components=2,max_combinations=100,max_particles=50',
     'renyi', None): (
        528860864.0, 6.1266799999999995,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'looked cells': 3200000.0, 'predicted cell counts': 47486208.0,
         'tracker': 51564800.0}),
    ('superposition',
     'gpf:n_counts=7,max_components=2,max_combinations=100,max_particles=50',
     None, None): (
        420444800.0, 0.74,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0,
         'tracker': 364800.0}),
    ('12', 'jmpd:t_max=5', 'raster', None): (
        425558848.0, 0.8048000000000001,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'tracker': 3364608.0}),
    ('12', 'jmpd:t_max=5', 'renyi', None): (
        427755328.0, 0.9737792500144231,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'predicted cell counts': 2196480.0, 'tracker': 3364608.0}),
    ('1e5', 'jmpd:t_max=5', 'renyi', None): (
        441537856.0, 1.6016992500144231,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'predicted cell counts': 11520000.0, 'tracker': 3408000.0}),
    ('superposition', 'jmpd:t_max=5', None, None): (
        423440000.0, 0.8,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0,
         'tracker': 3360000.0}),
    ('12', 'jmpd:t_max=10,n_particles=500', 'raster', None): (
        424282688.0, 0.5548,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'tracker': 2088448.0}),
    ('12', 'jmpd:t_max=10,n_particles=500', 'renyi', None): (
        425657408.0, 0.6710743161863729,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'predicted cell counts': 1374720.0, 'tracker': 2088448.0}),
    ('1e5', 'jmpd:t_max=10,n_particles=500', 'renyi', None): (
        436937856.0, 1.234594316186373,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'predicted cell counts': 8160000.0, 'tracker': 2168000.0}),
    ('superposition', 'jmpd:t_max=10,n_particles=500', None, None): (
        422160000.0, 0.5499999999999999,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0,
         'tracker': 2080000.0}),
    ('12', 'jmpd:proposal=ip,t_max=5', 'raster', None): (
        427158848.0, 2.6048,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'tracker': 4964608.0}),
    ('12', 'jmpd:proposal=ip,t_max=5', 'renyi', None): (
        429355328.0, 2.7737792500144236,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'predicted cell counts': 2196480.0, 'tracker': 4964608.0}),
    ('1e5', 'jmpd:proposal=ip,t_max=5', 'renyi', None): (
        443137856.0, 3.4016992500144236,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'predicted cell counts': 11520000.0, 'tracker': 5008000.0}),
    ('superposition', 'jmpd:proposal=ip,t_max=5', None, None): (
        425040000.0, 2.6,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0,
         'tracker': 4960000.0}),
    ('12', 'jmpd-ip:t_max=5', 'raster', None): (
        427158848.0, 2.6048,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'tracker': 4964608.0}),
    ('12', 'jmpd-ip:t_max=5', 'renyi', None): (
        429355328.0, 2.7737792500144236,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'predicted cell counts': 2196480.0, 'tracker': 4964608.0}),
    ('1e5', 'jmpd-ip:t_max=5', 'renyi', None): (
        443137856.0, 3.4016992500144236,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'predicted cell counts': 11520000.0, 'tracker': 5008000.0}),
    ('superposition', 'jmpd-ip:t_max=5', None, None): (
        425040000.0, 2.6,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0,
         'tracker': 4960000.0}),
    ('12', 'jmpd-ap', 'raster', None): (
        424141120.0, 0.704944,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'looked cells': 18432.0, 'tracker': 1928448.0}),
    ('12', 'jmpd-ap', 'renyi', None): (
        425349952.0, 0.8039383161863729,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'looked cells': 18432.0, 'predicted cell counts': 1208832.0,
         'tracker': 1928448.0}),
    ('1e5', 'jmpd-ap', 'renyi', None): (
        490729856.0, 6.157193424530331,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'looked cells': 3200000.0, 'predicted cell counts': 50112000.0,
         'tracker': 10808000.0}),
    ('superposition', 'jmpd-ap', None, None): (
        421616000.0, 0.6,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0,
         'tracker': 1536000.0}),
    ('12', 'jmpd-ap:t_max=8,n_particles=300', 'raster', None): (
        423141184.0, 0.444944,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'looked cells': 18432.0, 'tracker': 928512.0}),
    ('12', 'jmpd-ap:t_max=8,n_particles=300', 'renyi', None): (
        423850816.0, 0.4985596400069231,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'looked cells': 18432.0, 'predicted cell counts': 709632.0,
         'tracker': 928512.0}),
    ('1e5', 'jmpd-ap:t_max=8,n_particles=300', 'renyi', None): (
        454937856.0, 1.924215640006923,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'looked cells': 3200000.0, 'predicted cell counts': 24134400.0,
         'tracker': 993600.0}),
    ('superposition', 'jmpd-ap:t_max=8,n_particles=300', None, None): (
        421001600.0, 0.43999999999999995,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0,
         'tracker': 921600.0}),
    ('12', 'ss-gnn', 'raster', None): (
        422212672.0, 3.204944,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'looked cells': 18432.0}),
    ('12', 'ss-gnn', 'renyi', None): (
        423515200.0, 3.272784,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'looked cells': 18432.0, 'predicted cell counts': 1302528.0}),
    ('1e5', 'ss-gnn', 'renyi', None): (
        465230016.0, 27.1198,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'looked cells': 3200000.0, 'predicted cell counts': 35420160.0}),
    ('superposition', 'ss-gnn', None, None): (
        420080000.0, 2.2,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0}),
    ('12', 'ss-gmphd', 'raster', None): (
        422194240.0, 3.2048,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0}),
    ('12', 'ss-gmphd', 'renyi', None): (
        423496768.0, 3.2726400000000004,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'predicted cell counts': 1302528.0}),
    ('1e5', 'ss-gmphd', 'renyi', None): (
        442830016.0, 26.094800000000003,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'predicted cell counts': 16220160.0}),
    ('superposition', 'ss-gmphd', None, None): (
        420080000.0, 2.2,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0}),
    ('12', 'ss-gmphd:max_components=50', 'raster', None): (
        422194240.0, 3.2048,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0}),
    ('12', 'ss-gmphd:max_components=50', 'renyi', None): (
        423496768.0, 3.2726400000000004,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'predicted cell counts': 1302528.0}),
    ('1e5', 'ss-gmphd:max_components=50', 'renyi', None): (
        438897856.0, 25.890000000000004,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'predicted cell counts': 12288000.0}),
    ('superposition', 'ss-gmphd:max_components=50', None, None): (
        420080000.0, 2.2,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0}),
    ('12', 'crashing_tracker:Crash', 'raster', None): (
        422194240.0, 0.2048,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0}),
    ('12', 'crashing_tracker:Crash', 'renyi', None): (
        423496768.0, 0.27264,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'predicted cell counts': 1302528.0}),
    ('1e5', 'crashing_tracker:Crash', 'renyi', None): (
        442830016.0, 1.0948,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'predicted cell counts': 16220160.0}),
    ('superposition', 'crashing_tracker:Crash', None, None): (
        420080000.0, 0.2,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0}),
    ('12', 'nowhere.at_all:Thing:n_counts=9,t_max=3', 'raster', None): (
        422194240.0, 0.2048,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0}),
    ('12', 'nowhere.at_all:Thing:n_counts=9,t_max=3', 'renyi', None): (
        423635008.0, 0.28703999999999996,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2109440.0, 'predicted cell counts': 1440768.0}),
    ('1e5', 'nowhere.at_all:Thing:n_counts=9,t_max=3', 'renyi', None): (
        450940096.0, 1.9396,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 145600.0, 'result rows': 614400.0,
         'simulator': 6419456.0, 'predicted cell counts': 24330240.0}),
    ('superposition', 'nowhere.at_all:Thing:n_counts=9,t_max=3', None, None): (
        420080000.0, 0.2,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 35200.0, 'result rows': 614400.0}),
    ('12', 'null', 'all', 200): (
        422255680.0, 0.2288,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2170880.0}),
    ('12', 'null', 'random', 200): (
        422285504.0, 0.24,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'policy': 1152.0}),
    ('12', 'null', 'oracle', 200): (
        422285504.0, 0.24,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'policy': 1152.0}),
    ('12', 'null', 'renyi:repeats=true', 200): (
        422367296.0, 0.24288,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'predicted cell counts': 82944.0}),
    ('12', 'null', 'crashing_tracker:FirstCells', 200): (
        422284352.0, 0.24,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0}),
    ('12', 'gpf', 'all', 200): (
        434758720.0, 1.6633440000000004,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2170880.0, 'looked cells': 18432.0, 'tracker': 12484608.0}),
    ('12', 'gpf', 'random', 200): (
        434788544.0, 1.674544,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'policy': 1152.0, 'looked cells': 18432.0,
         'tracker': 12484608.0}),
    ('12', 'gpf', 'oracle', 200): (
        434788544.0, 1.674544,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'policy': 1152.0, 'looked cells': 18432.0,
         'tracker': 12484608.0}),
    ('12', 'gpf', 'renyi:repeats=true', 200): (
        436089920.0, 1.742384,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'looked cells': 18432.0, 'predicted cell counts': 1302528.0,
         'tracker': 12484608.0}),
    ('12', 'gpf', 'crashing_tracker:FirstCells', 200): (
        434787392.0, 1.674544,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'looked cells': 18432.0, 'tracker': 12484608.0}),
    ('12', 'jmpd-ap', 'all', 200): (
        424244800.0, 0.728944,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2170880.0, 'looked cells': 18432.0, 'tracker': 1970688.0}),
    ('12', 'jmpd-ap', 'random', 200): (
        424274624.0, 0.740144,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'policy': 1152.0, 'looked cells': 18432.0, 'tracker': 1970688.0}),
    ('12', 'jmpd-ap', 'oracle', 200): (
        424274624.0, 0.740144,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'policy': 1152.0, 'looked cells': 18432.0, 'tracker': 1970688.0}),
    ('12', 'jmpd-ap', 'renyi:repeats=true', 200): (
        425482304.0, 0.8391383161863729,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'looked cells': 18432.0, 'predicted cell counts': 1208832.0,
         'tracker': 1970688.0}),
    ('12', 'jmpd-ap', 'crashing_tracker:FirstCells', 200): (
        424273472.0, 0.740144,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'looked cells': 18432.0, 'tracker': 1970688.0}),
    ('12', 'truth-aided', 'all', 200): (
        431987776.0, 0.6055999999999999,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2170880.0, 'tracker': 9732096.0}),
    ('12', 'truth-aided', 'random', 200): (
        432017600.0, 0.6168,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'policy': 1152.0, 'tracker': 9732096.0}),
    ('12', 'truth-aided', 'oracle', 200): (
        432017600.0, 0.6168,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'policy': 1152.0, 'tracker': 9732096.0}),
    ('12', 'truth-aided', 'renyi:repeats=true', 200): (
        433318976.0, 0.6846399999999999,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'predicted cell counts': 1302528.0, 'tracker': 9732096.0}),
    ('12', 'truth-aided', 'crashing_tracker:FirstCells', 200): (
        432016448.0, 0.6168,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 40000.0, 'result rows': 614400.0,
         'simulator': 2199552.0, 'tracker': 9732096.0}),
    ('scale', 'gpf', 'raster', None): (
        750847104.0, 3.5865000000000005,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 530560.0, 'result rows': 61440.0,
         'simulator': 5474304.0, 'looked cells': 3200000.0, 'tracker': 322150400.0}),
    ('scale', 'jmpd-ap', 'raster', None): (
        973864704.0, 10.1825,
        {'worker': 402653184.0, 'run': 16777216.0, 'truth': 530560.0, 'result rows': 61440.0,
         'simulator': 5474304.0, 'looked cells': 3200000.0, 'tracker': 545168000.0}),
}


@pytest.mark.parametrize("case", list(OLD_ESTIMATES), ids=lambda c: "|".join(map(str, c)))
def test_the_classes_terms_give_the_estimates_resources_py_gave_by_name(case):
    """Every shipped tracker (and settings of their cost parameters), trackers named by
    class path (one that cannot be found), every policy, on a dense and a sparse grid, the
    superposition sensor and ``scale``."""
    memory, seconds, parts = OLD_ESTIMATES[case]
    est = resources.estimate_job(world_job(*case))
    assert (est.memory, est.seconds, est.parts) == (memory, seconds, parts)
    assert list(est.parts) == list(parts)


def test_a_tracker_and_a_policy_from_elsewhere_declare_their_own_terms(monkeypatch):
    """The hooks are all resources.py asks: a tracker's and a policy's overrides are
    counted where their terms go, by no name."""

    class Told(NullTracker):
        name = "test-costs-declared"

        @classmethod
        def resource_terms(cls, params, model, looks_per_step, targets):
            return ResourceTerms(state_bytes=1000.0, look_bytes=10.0, looked_cell_bytes=1.0,
                                 prediction_entries=7.0, prediction_counts=3.0)

    class Twice(policies.RenyiGain):
        name = "test-twice-the-looks"

        @classmethod
        def resource_terms(cls, params, model, looks_per_step):
            return policies.PolicyTerms(2 * looks_per_step, repeats=True, state_bytes=5.0)

    real = policies.get_policy_class
    monkeypatch.setattr(policies, "get_policy_class",
                        lambda name: Twice if name == Twice.name else real(name))
    trackers.register(Told)
    try:
        est = resources.estimate_job(job(scenario(HUGE, steps=10), Told.name, Twice.name))
    finally:
        trackers.unregister(Told.name)
    # 48 distinct looks per step, repeats: positions up to 48 x 1e10
    assert est.parts["simulator"] == (resources.jump_tables(48 * HUGE**2)
                                      * resources.JUMP_TABLE_BYTES + 48 * resources.LOOK_BYTES)
    assert est.parts["policy"] == 5.0
    assert est.parts["looked cells"] == 10 * 48 * 1.0
    assert est.parts["tracker"] == 1000.0 + 48 * 10.0
    rows = 7.0 + 10 * 48  # its entries and the looked cells (it keeps them), no dense rows
    assert est.parts["predicted cell counts"] == (
        7.0 * resources.ENTRY_BYTES
        + rows * (resources.PREDICTION_ROW_BYTES + 3.0 * resources.PREDICTION_COUNT_BYTES))


def test_a_job_that_cannot_fit_is_refused_on_any_machine():
    """JMPD with 1e9 particles of 5 slots: about 1.5 TiB of particles, refused with one line
    even with 1 TiB available (512 GiB per worker)."""
    jobs = build_jobs([scenario(12)], [TrackerSpec("jmpd", {"n_particles": 10**9,
                                                           "t_max": 5})], None,
                      None, [0, 1])
    with pytest.raises(ConfigError) as err:
        resources.check_jobs(jobs, workers=2, available=1024 * GIB)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith("scenario 'grid12' (12x12 grid, 100 steps) with tracker "
                          "jmpd(n_particles=1000000000,t_max=5): one run needs about ")
    assert re.search(r"needs about 1\.\d\d TiB of memory \(mostly the tracker, 1\.\d\d TiB\), "
                     r"more than the 512 GiB per worker \(1 TiB available / 2 workers\); use "
                     r"fewer particles or looks, fewer --steps or fewer --workers$", msg), msg
    # looking at every cell of a 1e6 x 1e6 grid is O(cells): refused too
    every = build_jobs([scenario(10**6)], [TrackerSpec("null")], [PolicySpec("all")], None, [0])
    with pytest.raises(ConfigError, match=r"mostly the simulator, [\d.]+ TiB"):
        resources.check_jobs(every, workers=1, available=1024 * GIB)


def test_huge_grids_are_accepted_for_every_tracker():
    """1e5 x 1e5 and 1e6 x 1e6 grids, 100 steps of large's 25 targets and 250 looks: every
    registered tracker under raster and renyi fits in 1 GiB per worker."""
    for side in (HUGE, 10**6):
        sc = scenario(side, preset="large")
        jobs = build_jobs([sc], [TrackerSpec(n) for n in trackers.available()],
                          [PolicySpec("raster"), PolicySpec("renyi")], None, [0, 1])
        resources.check_jobs(jobs, workers=2, available=2 * GIB)
        worst = max(resources.estimate_job(j).memory for j in jobs)
        assert worst < 1 * GIB, worst / MIB


def test_limit_is_shared_by_the_runs_that_execute_at_once():
    sc = scenario(12, steps=100)
    need = resources.estimate_job(job(sc, "jmpd", n_particles=10**6)).memory  # ~1.9 GiB
    jobs = build_jobs([sc], [TrackerSpec("jmpd", {"n_particles": 10**6})], None, None,
                      [0, 1, 2])
    resources.check_jobs(jobs, workers=3, available=3.01 * need)
    with pytest.raises(ConfigError, match="per worker"):
        resources.check_jobs(jobs, workers=3, available=2.99 * need)
    # more workers than jobs: only three runs at once
    resources.check_jobs(jobs, workers=64, available=3.01 * need)
    resources.check_jobs(jobs[:1], workers=64, available=1.01 * need)


def test_results_table_must_fit_in_the_main_process():
    jobs = build_jobs([scenario(12, steps=1000)], [TrackerSpec("null")], None, None,
                      list(range(1000)))
    table = 1000 * 1000 * resources.RESULT_ROW_BYTES
    assert table > 4 * resources.estimate_job(jobs[0]).memory  # the table is the limit here
    resources.check_jobs(jobs, workers=1, available=1.01 * table)
    with pytest.raises(ConfigError, match=r"results table of 1000 runs \(1000000 steps\)"):
        resources.check_jobs(jobs, workers=1, available=0.99 * table)


def test_slow_sweeps_warn_and_the_default_compare_does_not():
    default = build_jobs([scenarios.get(n) for n in ("default", "crossing", "births", "paper")],
                         resolve_trackers(default_tracker_texts()), None, None, list(range(10)))
    assert resources.check_jobs(default, workers=2, available=64 * GIB) == []
    slow = build_jobs([scenario(12, steps=50_000)], [TrackerSpec("jmpd", {"n_particles": 10**5})],
                      None, None, list(range(4)))
    warnings = resources.check_jobs(slow, workers=2, available=64 * GIB)
    assert len(warnings) == 1 and "\n" not in warnings[0]
    assert warnings[0].startswith("warning: this sweep may take about ")
    assert "jmpd(n_particles=100000)" in warnings[0]


def test_memory_override_and_available_memory(monkeypatch):
    monkeypatch.setenv(resources.MEMORY_ENV, "1.5")
    assert resources.available_memory() == 1.5 * GIB
    for bad in ("lots", "0", "-1", "nan", "inf"):
        monkeypatch.setenv(resources.MEMORY_ENV, bad)
        with pytest.raises(ConfigError, match=resources.MEMORY_ENV):
            resources.available_memory()
    monkeypatch.delenv(resources.MEMORY_ENV)
    found = resources.available_memory()
    if sys.platform.startswith("linux"):
        assert found is not None and found > 0


@pytest.mark.parametrize(("n", "text"), [
    (0, "0 B"), (1023, "1023 B"), (1024, "1 KiB"), (1536, "1.5 KiB"), (8 * 10**12, "7.28 TiB"),
    (2.0**70, "1.02e+03 EiB"),
])
def test_fmt_bytes(n, text):
    assert resources.fmt_bytes(n) == text


# ------------------------------------------------------- the estimate bounds reality
def _status_mb(key: str) -> float:
    text = Path("/proc/self/status").read_text()
    return int(re.search(key + r":\s+(\d+)", text).group(1)) / 1024.0


def _peak_growth(warm: Job, j: Job) -> float:
    """Bytes the peak RSS grows by while ``j`` runs, in a process forked from a warm one.
    ``warm`` runs first in the child too (the pages of code and data the parent shares
    are mapped into the child as they are touched: ~19 MB that are the fork's, not the
    run's), the allocator's free memory goes back to the system (``malloc_trim``: what
    earlier tests freed would otherwise hide the run's arrays), then the high-water mark
    is reset (``/proc/self/clear_refs``) and compared with the resident size before the
    run. The address space may grow by 4 GiB at most,
    so that an ``O(cells)`` array on a huge grid fails at once (MemoryError: an error
    row)."""
    room = int((_status_mb("VmSize") + 4096) * MIB)
    resource.setrlimit(resource.RLIMIT_AS, (room, room))
    run_job(warm)
    gc.collect()
    # the free memory earlier tests left in the allocator's heap back to the system, so
    # that the run's arrays are counted when they touch it again
    ctypes.CDLL(ctypes.util.find_library("c")).malloc_trim(0)
    Path("/proc/self/clear_refs").write_text("5")
    before = _status_mb("VmRSS")
    rows = run_job(j)
    assert (rows["status"] == "ok").all(), rows["error"].unique()
    return (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0 - before) * MIB


MEASURED = [  # (tracker, params, policy, grid side, steps)
    ("kfnn", {}, "raster", HUGE, 5),  # the huge grid: nothing per cell
    ("kfnn", {}, "renyi", HUGE, 5),  # P_c and renyi's sparse path, three jump tables
    ("gpf", {}, "renyi", HUGE, 5),
    ("jmpd", {}, "renyi", HUGE, 5),  # int64 cells, P_c rows for the particles' cells
    ("jmpd", {"n_particles": 50_000}, "raster", 12, 5),  # the particles
    ("null", {}, "all", 300, 3),  # 90,000 looks per step
    ("gpf", {}, "all", 300, 3),  # a birth candidate per look, pairs in the boxes only
]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and fork")
@pytest.mark.parametrize(("tracker", "params", "policy", "side", "steps"), MEASURED,
                         ids=[f"{m[0]}-{m[2]}-{m[3]}" for m in MEASURED])
def test_estimate_bounds_the_measured_peak(tracker, params, policy, side, steps):
    """The estimate (worker base aside) is at least the measured growth of the peak RSS
    of one run, and not wildly above it (at most 4x + 48 MiB: the constants are rounded
    up from measurements, not arbitrary; RUN_BASE alone is 16 MiB). On the 1e5 x 1e5 grid
    the sweep check must accept the run with 256 MiB beyond the worker's base."""
    warm = job(scenario(12, steps=2), tracker, policy)  # imports, numba kernels
    run_job(warm)
    if side > 46_340:  # more than 2^31 - 1 cells: the int64 kernels
        run_job(job(scenario(side, steps=2), tracker, policy))
    j = job(scenario(side, steps=steps), tracker, policy, **params)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("fork")) as pool:
        measured = pool.submit(_peak_growth, warm, j).result()
    est = resources.estimate_job(j).memory - resources.WORKER_BASE
    assert measured <= est, (measured / MIB, est / MIB)
    assert est <= 4 * measured + 48 * MIB, (measured / MIB, est / MIB)
    assert math.isfinite(measured)
    if side == HUGE:
        resources.check_jobs([j], workers=1, available=resources.WORKER_BASE + 256 * MIB)


def test_mttbench_run_accepts_and_runs_a_huge_grid(monkeypatch, tmp_path, capsys):
    """The command line on a 1e5 x 1e5 grid (kfnn, 3 steps) under a 1 GiB limit: accepted,
    run, its rows written."""
    monkeypatch.setenv(resources.MEMORY_ENV, "1")
    sc = scenario(HUGE, steps=3, preset="large")
    path = tmp_path / "huge.toml"
    path.write_text(dumps(dataclasses.replace(sc, name="huge")), encoding="utf-8")
    rc = main(["run", "--scenarios", str(path), "--trackers", "kfnn", "--seeds", "1",
               "--workers", "1", "--no-progress", "--out", str(tmp_path / "out")])
    assert rc == 0, capsys.readouterr().err
    assert any((tmp_path / "out").rglob("*.parquet"))


def test_every_sweep_of_the_app_has_a_run_timeout(monkeypatch, tmp_path):
    """The app's run_sweep (run, compare, tune, reproduce) passes a wall-time limit to the
    engine: the one given, else 10x the slowest run's estimate, at least 60 s."""
    from mttbench.benchmarks.app import progress
    from mttbench.benchmarks.engine import sweep
    from mttbench.benchmarks.engine.loop import Job
    from mttbench.benchmarks.engine.specs import TrackerSpec

    seen = {}
    monkeypatch.setattr(sweep, "run_sweep", lambda jobs, out, **kw: seen.update(kw))
    monkeypatch.setattr(resources, "cold_modules", lambda: [])  # a warmed install
    jobs = [Job(scenarios.get("large"), TrackerSpec("gpf")),
            Job(scenarios.get("default"), TrackerSpec("null"))]
    progress.run_sweep(jobs, tmp_path, progress=False)
    slowest = max(resources.estimate_job(j).seconds for j in jobs)
    assert seen["run_timeout"] == max(60.0, 10.0 * slowest)
    progress.run_sweep(jobs, tmp_path, progress=False, run_timeout=7.5)
    assert seen["run_timeout"] == 7.5


def test_default_run_timeout_is_ten_times_the_slowest_estimate_with_a_floor(monkeypatch):
    """The default ``--run-timeout``: 10x the slowest run's estimated seconds, never below
    60 s; a run with no estimate counts as 0 (the floor)."""
    seconds = {"fast": 2.0, "slow": 30.0}

    def fake_estimate(job):
        if job == "broken":
            raise ValueError("no estimate")
        return type("Estimate", (), {"seconds": seconds[job]})()

    monkeypatch.setattr(resources, "estimate_job", fake_estimate)
    monkeypatch.setattr(resources, "cold_modules", lambda: [])
    assert resources.default_run_timeout(["fast", "slow"]) == 300.0
    assert resources.default_run_timeout(["fast"]) == 60.0
    assert resources.default_run_timeout(["broken", "slow"]) == 300.0
    assert resources.default_run_timeout([]) == 60.0
    # a cold kernel cache: a worker's first run compiles, so the floor is 600 s
    monkeypatch.setattr(resources, "cold_modules", lambda: ["mttbench.trackers.grid_kernels"])
    assert resources.default_run_timeout(["fast", "slow"]) == 600.0
    seconds["slow"] = 90.0
    assert resources.default_run_timeout(["slow"]) == 900.0

"""``mttbench export``: open world files that a tracker written elsewhere can run on.

A **world** is one ``(scenario, seed, policy, looks per step)``: the truth and every look
the sensor made, with its 0/1 return. It is drawn by the suite's one step loop
(:func:`~mttbench.benchmarks.engine.loop.play`, run with the ``null`` tracker), so an
exported world is the in-process world bit for bit: the same truth, the same cells looked
at, the same returns, for the same seeds. The schema (every column, the model card's
fields, the format version) is ``docs/world_format.md``; one folder per world::

    OUT/worlds.csv                        one line per world folder written
    OUT/<world>/truth.parquet, truth.csv  step, target_id, px, vx, py, vy
    OUT/<world>/looks.parquet, looks.csv  step, look, cell, ix, iy, return (every look)
    OUT/<world>/steps.csv                 step, time, n_looks, n_positive (every step)
    OUT/<world>/stonesoup_truth.csv       Stone Soup's CSVGroundTruthReader reads it
    OUT/<world>/stonesoup_detections.csv  positive looks at the cell centre (CSVDetectionReader)
    OUT/<world>/stonesoup_misses.csv      negative looks, same layout (their own file)
    OUT/<world>/model_card.json           the model, the policy, versions, sha256 of each file

Only **open-loop** policies are exported (``all``, ``random``, ``raster``: their looks
depend on the world's seed alone). A closed-loop policy (``renyi``) chooses its looks from
the tracker's own predicted cell counts, so its looks exist only for one tracker's run: a
file of them would be another tracker's looks, not a world. The ``oracle`` chooses its
looks from the true targets' cells: a reference flagged as using the truth, refused too.
The superposition sensor (no cells) is not exported.

Stone Soup's readers want a time: ``time = step * tau`` seconds after the Unix epoch
(read them with ``timestamp=True``). A step without a positive look has no row in the
detections file, so a Stone Soup reader yields no scan for it: ``steps.csv`` lists every
step ``0 .. n_steps - 1`` with its time, so a tracker's loop runs over the steps, not over
the scans. The negative looks, which no Stone Soup detection type can carry, are kept in
``stonesoup_misses.csv``.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ... import __version__
from ... import trackers as trackers_pkg
from ...scenarios.model import RayleighGridSensor
from ...scenarios.spec import Scenario, dumps
from ..engine.errors import ConfigError
from ..engine.loop import play
from ..engine.specs import PolicySpec

#: the format's name and version (``model_card.json``); a reader refuses other versions
FORMAT = "mttbench-world"
FORMAT_VERSION = 1
CARD = "model_card.json"
WORLDS_INDEX = "worlds.csv"
TRUTH_COLUMNS = ["step", "target_id", "px", "vx", "py", "vy"]
LOOKS_COLUMNS = ["step", "look", "cell", "ix", "iy", "return"]
STONESOUP_TRUTH_COLUMNS = ["time", "step", "target_id", "px", "vx", "py", "vy"]
STONESOUP_LOOK_COLUMNS = ["time", "step", "look", "cell", "x", "y"]
STEPS_COLUMNS = ["step", "time", "n_looks", "n_positive"]
#: the counts ``T`` of the model card's ``p_d(T)`` table
PD_TABLE_COUNTS = 5
#: the files of one world, in the order the model card lists them
WORLD_FILES = ("truth.parquet", "truth.csv", "looks.parquet", "looks.csv", "steps.csv",
               "stonesoup_truth.csv", "stonesoup_detections.csv", "stonesoup_misses.csv")


def closed_loop_reason(spec: PolicySpec) -> str | None:
    """Why ``spec``'s policy cannot be exported (one line), or None for an open-loop one:
    a policy that reads the tracker's prediction (``uses_prediction``) or the truth
    (``uses_truth``) has no world of its own."""
    cls = spec.target()
    if getattr(cls, "uses_prediction", False):
        return (f"policy {spec.label!r} is closed-loop: its looks depend on the tracker's own "
                "estimates (its predicted cell counts), so they exist only for one tracker's "
                "run; export an open-loop policy (all, random, raster)")
    if getattr(cls, "uses_truth", False):
        return (f"policy {spec.label!r} chooses its looks from the true targets' cells (a "
                "reference that uses the truth), not a sensor an outside tracker can be "
                "scored under; export an open-loop policy (all, random, raster)")
    return None


def check_exportable(scenario: Scenario, specs: Sequence[PolicySpec]) -> None:
    """:class:`ConfigError` (one line) for a scenario without cells or a closed-loop
    policy; nothing otherwise."""
    if not isinstance(scenario.model.sensor, RayleighGridSensor):
        raise ConfigError(f"scenario {scenario.name!r} has the superposition sensor (no cells, "
                          "no looks): export writes grid-sensor worlds only")
    for spec in specs:
        reason = closed_loop_reason(spec)
        if reason:
            raise ConfigError(f"cannot export: {reason}")


@dataclass(frozen=True)
class World:
    """One world's tables: ``truth`` (one row per target and step, :data:`TRUTH_COLUMNS`),
    ``looks`` (one row per look, :data:`LOOKS_COLUMNS`) and the run's identity."""

    scenario: Scenario
    seed: int
    policy: PolicySpec
    policy_params: dict[str, Any]
    looks_per_step: int
    truth: pd.DataFrame
    looks: pd.DataFrame


def draw_world(scenario: Scenario, policy: PolicySpec, seed: int,
               looks_per_step: int | None = None) -> World:
    """The world ``(scenario, seed, policy, looks_per_step)`` as :func:`play` makes it (the
    ``null`` tracker; an open-loop policy's looks do not depend on the tracker): per step
    the truth ``(n_k, 4)`` with ids, and the looks ``cells (L_k,)`` in the order the policy
    chose them, with their returns. ``looks_per_step`` None: the sensor's budget."""
    m = int(scenario.model.sensor.looks_per_step if looks_per_step is None else looks_per_step)
    pol = policy.make()
    params = pol.get_params()
    nx = scenario.grid.nx
    truth_parts, look_parts = [], []
    for rec in play(scenario, trackers_pkg.make("null"), int(seed), policy=pol,
                    looks_per_step=m, tracker_label="null", policy_label=policy.label):
        n = len(rec.truth)
        truth_parts.append(pd.DataFrame({
            "step": np.full(n, rec.k, np.int64), "target_id": rec.truth_ids.astype(np.int64),
            "px": rec.truth[:, 0], "vx": rec.truth[:, 1], "py": rec.truth[:, 2],
            "vy": rec.truth[:, 3]}))
        cells = np.asarray(rec.looks.cells, np.int64)
        look_parts.append(pd.DataFrame({
            "step": np.full(len(cells), rec.k, np.int64),
            "look": np.arange(len(cells), dtype=np.int64), "cell": cells,
            "ix": cells % nx, "iy": cells // nx,
            "return": np.asarray(rec.looks.returns, bool).astype(np.int64)}))
    truth = pd.concat(truth_parts, ignore_index=True)[TRUTH_COLUMNS]
    looks = pd.concat(look_parts, ignore_index=True)[LOOKS_COLUMNS]
    return World(scenario, int(seed), policy, params, m, truth, looks)


def world_name(scenario: str, seed: int, policy_label: str, looks_per_step: int) -> str:
    """The folder of a world: ``<scenario>__seed<seed>__<policy>__m<looks>``, characters
    other than letters, digits, ``.``, ``_``, ``-`` replaced by ``_``."""
    def safe(text: str) -> str:
        return re.sub(r"[^A-Za-z0-9._-]", "_", text)
    return f"{safe(scenario)}__seed{seed}__{safe(policy_label)}__m{looks_per_step}"


def stonesoup_tables(world: World) -> dict[str, pd.DataFrame]:
    """The three Stone Soup files: the truth with ``time = step * tau`` (seconds after the
    epoch), and the positive and the negative looks as points at the looked cell's centre
    ``((ix + 1/2) s, (iy + 1/2) s)``, ``s`` the cell size."""
    tau = float(world.scenario.model.dynamics.tau)
    truth = world.truth.assign(time=world.truth["step"] * tau)[STONESOUP_TRUTH_COLUMNS]
    s = float(world.scenario.grid.cell_size)
    looks = world.looks.assign(time=world.looks["step"] * tau,
                               x=(world.looks["ix"] + 0.5) * s, y=(world.looks["iy"] + 0.5) * s)
    positive = looks["return"] == 1
    return {"stonesoup_truth.csv": truth,
            "stonesoup_detections.csv": looks.loc[positive, STONESOUP_LOOK_COLUMNS],
            "stonesoup_misses.csv": looks.loc[~positive, STONESOUP_LOOK_COLUMNS]}


def steps_table(world: World) -> pd.DataFrame:
    """One row per step ``0 .. n_steps - 1``, those without looks or without a positive
    look included: ``time = step * tau`` (the Stone Soup files' time), the looks made and
    the positive ones."""
    n = int(world.scenario.n_steps)
    step = np.arange(n, dtype=np.int64)
    looks = world.looks
    return pd.DataFrame({
        "step": step, "time": step * float(world.scenario.model.dynamics.tau),
        "n_looks": np.bincount(looks["step"], minlength=n).astype(np.int64),
        "n_positive": np.bincount(looks["step"], weights=looks["return"],
                                  minlength=n).astype(np.int64)})[STEPS_COLUMNS]


def sha256_of(path: Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def replace_file(path: Path, write) -> None:
    """``write(tmp)`` then ``os.replace`` onto ``path``: a file is whole or absent."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def model_card(world: World, files: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The model card (JSON) of ``world``: everything a tracker may know (grid, dynamics,
    sensor with its ``p_d(T)`` table, births and deaths), the policy and seed, versions,
    and each file's ``sha256``, bytes and rows. Fields: ``docs/world_format.md``."""
    sc, model = world.scenario, world.scenario.model
    grid, dyn, bd, sensor = model.grid, model.dynamics, model.birth_death, model.sensor
    pd_table = sensor.detection_probability(np.arange(PD_TABLE_COUNTS))
    return {
        "format": FORMAT, "format_version": FORMAT_VERSION, "mttbench_version": __version__,
        "scenario": {"name": sc.name, "description": sc.description, "n_steps": sc.n_steps,
                     "toml": dumps(sc)},
        "seed": world.seed,
        "policy": {"name": world.policy.name, "label": world.policy.label,
                   "params": world.policy_params, "looks_per_step": world.looks_per_step,
                   "open_loop": True},
        "grid": {"nx": grid.nx, "ny": grid.ny, "cell_size": grid.cell_size,
                 "n_cells": grid.n_cells, "extent": list(grid.extent),
                 "cell": "c = iy * nx + ix, ix = floor(px / cell_size), "
                         "iy = floor(py / cell_size)"},
        "dynamics": {"state": ["px", "vx", "py", "vy"], "tau": dyn.tau, "F": dyn.F.tolist(),
                     "Q": dyn.Q.tolist(), "equation": "x[k+1] = F x[k] + v, v ~ N(0, Q)"},
        "sensor": {"kind": "rayleigh", "p_d": sensor.p_d, "snr": sensor.snr,
                   "p_f": sensor.p_f, "p_d_of_T": [float(v) for v in pd_table],
                   "equation": "P(return 1 | T targets in the cell) = "
                               "p_d ** ((1 + snr) / (1 + T snr)); T = 0 gives p_f",
                   "looks_per_step": sensor.looks_per_step},
        "targets": {"survival_probability": bd.survival_probability,
                    "birth_rate": bd.birth_rate, "birth_velocity_std": bd.birth_velocity_std,
                    "boundary": bd.boundary, "n_random_initial": bd.n_random_initial,
                    "initial_states": [list(s) for s in bd.initial_states]},
        "columns": {"truth": TRUTH_COLUMNS, "looks": LOOKS_COLUMNS,
                    "steps": STEPS_COLUMNS, "stonesoup_truth": STONESOUP_TRUTH_COLUMNS,
                    "stonesoup_looks": STONESOUP_LOOK_COLUMNS},
        "files": files,
    }


def write_world(world: World, folder: str | Path) -> dict[str, Any]:
    """Write ``world``'s files into ``folder`` (created) and its model card last; returns
    the card. Floats in the CSV files are written in their shortest round-trip form, so
    CSV and Parquet hold the same float64 numbers."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tables = {"truth": world.truth, "looks": world.looks, "steps": steps_table(world)}
    files: dict[str, dict[str, Any]] = {}
    for name in WORLD_FILES:
        stem, suffix = name.rsplit(".", 1)
        df = tables.get(stem)
        if df is None:
            df = stonesoup_tables(world)[name]
        path = folder / name
        if suffix == "parquet":
            replace_file(path, lambda tmp, df=df: df.to_parquet(tmp, index=False))
        else:
            replace_file(path, lambda tmp, df=df: df.to_csv(tmp, index=False,
                                                            lineterminator="\n"))
        files[name] = {"sha256": sha256_of(path), "bytes": path.stat().st_size,
                       "rows": len(df)}
    card = model_card(world, files)
    text = json.dumps(card, indent=1) + "\n"
    replace_file(folder / CARD, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    return card


#: the most look rows one exported world may have (its tables are built in memory, and
#: written as Parquet, CSV and Stone Soup CSV: about 100 bytes per row in all)
MAX_WORLD_LOOKS = 10_000_000
#: the most steps of an exported world (its truth is drawn step by step in memory)
MAX_WORLD_STEPS = 1_000_000


def check_size(scenarios: Sequence[Scenario], looks: Sequence[int] | None) -> None:
    """:class:`ConfigError` (one line, before any work) for a world too large to export:
    more than :data:`MAX_WORLD_STEPS` steps, or more than :data:`MAX_WORLD_LOOKS` looks
    (steps x looks per step; every cell per step for the ``all`` policy is not counted
    here: its grid is bounded by the scenario's checks)."""
    for sc in scenarios:
        if sc.n_steps > MAX_WORLD_STEPS:
            raise ConfigError(f"scenario {sc.name!r}: {sc.n_steps} steps is too many to export "
                              f"(at most {MAX_WORLD_STEPS}); give fewer --steps")
        for m in list(looks or []) or [int(sc.model.sensor.looks_per_step)]:
            rows = sc.n_steps * int(m)
            if rows > MAX_WORLD_LOOKS:
                raise ConfigError(f"scenario {sc.name!r}: {sc.n_steps} steps x {m} looks = "
                                  f"{rows} look rows per world is too many to export (at most "
                                  f"{MAX_WORLD_LOOKS}); give fewer --steps or --looks")


def _names(scenarios: Sequence[Scenario], policies: Sequence[PolicySpec],
           seeds: Sequence[int], looks: Sequence[int] | None) -> list[tuple]:
    """``(scenario, policy, looks or None, seed, folder name)`` of every world."""
    budgets: list[int | None] = list(looks) if looks else [None]
    plan = [(sc, pol, m, int(seed)) for sc in scenarios for pol in policies
            for m in budgets for seed in seeds]
    names = [world_name(sc.name, seed, pol.label,
                        int(sc.model.sensor.looks_per_step if m is None else m))
             for sc, pol, m, seed in plan]
    if len(set(names)) != len(names):
        raise ConfigError("two worlds map to the same folder name (scenario names that differ "
                          "only in characters other than letters, digits, '.', '_', '-')")
    return [(*item, name) for item, name in zip(plan, names, strict=True)]


def check_names(scenarios: Sequence[Scenario], policies: Sequence[PolicySpec],
                seeds: Sequence[int], out_dir: str | Path,
                looks: Sequence[int] | None = None) -> None:
    """:class:`ConfigError` (one line, before any file is written) for two worlds of one
    folder name, and for a world that ``out_dir`` holds already from an export with other
    settings (another scenario text, e.g. other ``--steps``): replacing it would leave the
    estimates made on the old world beside the new one."""
    for sc, _, _, _, name in _names(scenarios, policies, seeds, looks):
        card = Path(out_dir) / name / CARD
        if not card.is_file():
            continue
        try:
            old = json.loads(card.read_text(encoding="utf-8"))["scenario"]["toml"]
        except (OSError, ValueError, KeyError, TypeError):
            old = None
        if old != dumps(sc):
            raise ConfigError(f"{card.parent} holds a world exported with other settings "
                              "(another scenario or --steps); export into another --out")


def export_worlds(scenarios: Sequence[Scenario], policies: Sequence[PolicySpec],
                  seeds: Sequence[int], out_dir: str | Path,
                  looks: Sequence[int] | None = None) -> pd.DataFrame:
    """Export every world scenario x policy x looks x seed into ``out_dir`` (see the module
    docstring) and write ``worlds.csv`` (``world, scenario, seed, policy, looks_per_step,
    n_steps, n_truth_rows, n_looks, n_positive``; worlds exported into the folder earlier
    stay listed); returns that table. Refuses
    (:class:`ConfigError`) what :func:`check_exportable` refuses, before writing."""
    out_dir = Path(out_dir)
    for sc in scenarios:
        check_exportable(sc, policies)
    rows = []
    for sc, pol, m, seed, name in _names(scenarios, policies, seeds, looks):
        world = draw_world(sc, pol, seed, m)
        write_world(world, out_dir / name)
        rows.append({"world": name, "scenario": sc.name, "seed": seed, "policy": pol.label,
                     "looks_per_step": world.looks_per_step, "n_steps": sc.n_steps,
                     "n_truth_rows": len(world.truth), "n_looks": len(world.looks),
                     "n_positive": int(world.looks["return"].sum())})
    index = pd.DataFrame(rows)
    old = out_dir / WORLDS_INDEX
    if old.is_file():  # worlds exported earlier into the same folder stay listed
        try:
            kept = pd.read_csv(old)
        except (OSError, ValueError):
            kept = pd.DataFrame(columns=index.columns)
        if list(kept.columns) == list(index.columns):
            kept = kept[~kept["world"].isin(index["world"])
                        & kept["world"].map(lambda w: (out_dir / str(w) / CARD).is_file())]
            index = pd.concat([kept, index], ignore_index=True) if len(kept) else index
    replace_file(out_dir / WORLDS_INDEX,
             lambda tmp: index.to_csv(tmp, index=False, lineterminator="\n"))
    return index

"""The simulator: ``(scenario, seed) -> Run`` with the truth and a sensor world.

Common random numbers (DESIGN.md). The world of a run depends on
``(scenario name, seed)`` only. For every step ``k`` the world holds uniforms
``U[k, j, c]``: the ``j``-th look at cell ``c`` during step ``k`` returns
``U[k, j, c] < p_d(T_kc)``. Row ``j`` of step ``k`` is the ``j``-th block of
``n_cells`` draws from a generator keyed by ``(scenario, seed, k)``, created only
when some step first looks at a cell ``j+1`` times, so the answer to a look
depends neither on which other cells were looked at nor on the order of the
looks. Every tracker and every cell-selection policy therefore sees the same world.
"""

from __future__ import annotations

import hashlib
import zlib
from dataclasses import dataclass, field

import numpy as np

from .model import Looks, RayleighGridSensor, SuperpositionSensor, TrackingModel
from .spec import Scenario

# spawn-key tags; the world uses (scenario, TAG, ...) and trackers use their own tag
_TRUTH, _LOOKS, _LINEAR = 0, 1, 2
TRACKER_TAG = 3


def stable_hash(name: str) -> int:
    """A platform-independent 32-bit hash of a name (for seed spawn keys)."""
    return zlib.crc32(name.encode("utf-8"))


def world_seed(scenario_name: str, seed: int, *tags: int) -> np.random.SeedSequence:
    """Seed sequence of one stream of the world of ``(scenario, seed)``."""
    return np.random.SeedSequence(seed, spawn_key=(stable_hash(scenario_name), *tags))


def tracker_seed(scenario_name: str, seed: int, identity: str) -> np.random.SeedSequence:
    """Seed of a tracker's or a policy's own randomness: depends on (scenario, seed,
    identity). The harness passes the canonical configuration
    (:meth:`mttbench.trackers.params.Configurable.canonical_config`: kind, implementation,
    every resolved parameter), so equal configurations draw equal numbers; the identity
    enters as a 128-bit SHA-256 prefix (no practical collision between configurations)."""
    key = int.from_bytes(hashlib.sha256(identity.encode("utf-8")).digest()[:16], "little")
    return np.random.SeedSequence(seed, spawn_key=(stable_hash(scenario_name), TRACKER_TAG, key))


# ----------------------------------------------------------------------- dynamics
def _reflect(pos: np.ndarray, vel: np.ndarray, length: float) -> None:
    """Fold positions into ``[0, length)`` in place, flipping velocity on odd bounces."""
    folded = np.mod(pos, 2.0 * length)
    bounced = folded >= length
    pos[:] = np.where(bounced, 2.0 * length - folded, folded)
    # an exact hit on the far edge would land outside the last cell
    np.minimum(pos, np.nextafter(length, 0.0), out=pos)
    # folded in [length, 2 length) means an odd number of bounces
    vel[:] = np.where(bounced, -vel, vel)


def _draw_births(rng: np.random.Generator, n: int, model: TrackingModel) -> np.ndarray:
    width, height = model.grid.extent
    bd = model.birth_death
    states = np.empty((n, 4))
    states[:, 0] = rng.uniform(0.0, width, n)
    states[:, 2] = rng.uniform(0.0, height, n)
    states[:, 1] = rng.normal(0.0, bd.birth_velocity_std, n)
    states[:, 3] = rng.normal(0.0, bd.birth_velocity_std, n)
    return states


def simulate_truth(scenario: Scenario, seed: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Target ids ``(n_k,)`` and states ``(n_k, 4)`` for each step ``k < n_steps``.

    Step 0 holds the initial targets; each later step applies survival, the
    dynamics ``x <- F x + v``, the boundary rule and then births.
    """
    model = scenario.model
    rng = np.random.default_rng(world_seed(scenario.name, seed, _TRUTH))
    bd, dyn = model.birth_death, model.dynamics
    F, chol_q = dyn.F, np.linalg.cholesky(dyn.Q + 1e-15 * np.eye(4))
    width, height = model.grid.extent

    states = np.array(bd.initial_states, dtype=float).reshape(-1, 4)
    states = np.concatenate([states, _draw_births(rng, bd.n_random_initial, model)])
    ids = np.arange(len(states), dtype=np.int64)
    next_id = len(states)
    all_ids, all_states = [ids.copy()], [states.copy()]
    for _ in range(1, scenario.n_steps):
        alive = rng.random(len(states)) < bd.survival_probability
        states, ids = states[alive], ids[alive]
        # x <- F x + chol(Q) e, e ~ N(0, I), vectorised over targets
        states = states @ F.T + rng.standard_normal(states.shape) @ chol_q.T
        if bd.boundary == "reflect":
            _reflect(states[:, 0], states[:, 1], width)
            _reflect(states[:, 2], states[:, 3], height)
        else:
            inside = ((states[:, 0] >= 0) & (states[:, 0] < width)
                      & (states[:, 2] >= 0) & (states[:, 2] < height))
            states, ids = states[inside], ids[inside]
        n_new = rng.poisson(bd.birth_rate)
        if n_new:
            states = np.concatenate([states, _draw_births(rng, n_new, model)])
            ids = np.concatenate([ids, np.arange(next_id, next_id + n_new)])
            next_id += n_new
        all_ids.append(ids.copy())
        all_states.append(states.copy())
    return all_ids, all_states


# -------------------------------------------------------------------------- world
@dataclass
class Run:
    """One simulated run: the truth and the sensor world of ``(scenario, seed)``.

    ``ids[k]`` is ``(n_k,)`` int64 and ``states[k]`` is ``(n_k, 4)``. Use
    :meth:`look` (grid sensor) or :meth:`measure` (superposition sensor) to
    observe step ``k``.
    """

    scenario: Scenario
    seed: int
    ids: list[np.ndarray]
    states: list[np.ndarray]
    _rows: dict[int, list[np.ndarray]] = field(default_factory=dict, repr=False)
    _gens: dict[int, np.random.Generator] = field(default_factory=dict, repr=False)

    @property
    def n_steps(self) -> int:
        return len(self.states)

    def positions(self, k: int) -> np.ndarray:
        """True positions ``(n_k, 2)`` as ``(px, py)`` at step ``k``."""
        return self.states[k][:, [0, 2]]

    def cell_counts(self, k: int) -> np.ndarray:
        """Number of targets in every cell at step ``k``, shape ``(n_cells,)``."""
        grid = self.scenario.grid
        cells = grid.cell_of(self.states[k][:, 0], self.states[k][:, 2])
        return np.bincount(cells[cells >= 0], minlength=grid.n_cells)

    def _uniform_rows(self, k: int, n_rows: int) -> np.ndarray:
        """The first ``n_rows`` rows ``U[k, :n_rows, :]`` (created on first use)."""
        rows = self._rows.setdefault(k, [])
        if len(rows) < n_rows:
            gen = self._gens.get(k)
            if gen is None:
                gen = np.random.default_rng(world_seed(self.scenario.name, self.seed, _LOOKS, k))
                self._gens[k] = gen
            n_cells = self.scenario.grid.n_cells
            while len(rows) < n_rows:
                rows.append(gen.random(n_cells))
        return np.stack(rows[:n_rows])

    def look(self, k: int, cells: np.ndarray) -> Looks:
        """Look at ``cells (L,)`` (repeats allowed) during step ``k``.

        All looks of one step go in one call: the ``j``-th occurrence of a cell in
        ``cells`` is that cell's ``j``-th look of the step.
        """
        sensor = self.scenario.model.sensor
        if not isinstance(sensor, RayleighGridSensor):
            raise TypeError(f"scenario {self.scenario.name!r} has no grid sensor")
        cells = np.asarray(cells, dtype=np.int64).reshape(-1)
        n_cells = self.scenario.grid.n_cells
        if cells.size and (cells.min() < 0 or cells.max() >= n_cells):
            raise ValueError(f"cell indices must lie in [0, {n_cells}), got {cells}")
        if not 0 <= k < self.n_steps:
            raise ValueError(f"step {k} outside [0, {self.n_steps})")
        # repeat index of every look: its rank among earlier looks at the same cell
        order = np.argsort(cells, kind="stable")
        sorted_cells = cells[order]
        first = np.searchsorted(sorted_cells, sorted_cells, side="left")
        repeat = np.empty_like(cells)
        repeat[order] = np.arange(cells.size) - first
        n_rows = int(repeat.max()) + 1 if cells.size else 0
        u = self._uniform_rows(k, n_rows)[repeat, cells] if cells.size else np.zeros(0)
        p = sensor.detection_probability(self.cell_counts(k)[cells])
        return Looks(cells=cells, returns=u < p)

    def measure(self, k: int) -> Looks:
        """Superposition measurement of step ``k``: ``z = mean_i H x_i + w`` (``w`` if empty)."""
        sensor = self.scenario.model.sensor
        if not isinstance(sensor, SuperpositionSensor):
            raise TypeError(f"scenario {self.scenario.name!r} has no superposition sensor")
        rng = np.random.default_rng(world_seed(self.scenario.name, self.seed, _LINEAR, k))
        H, R = sensor.H, sensor.R
        noise = np.linalg.cholesky(R) @ rng.standard_normal(R.shape[0])
        x = self.states[k]
        z = (x @ H.T).mean(axis=0) + noise if len(x) else noise
        return Looks(cells=np.zeros(0, dtype=np.int64), returns=np.zeros(0, dtype=bool), z=z)


def simulate(scenario: Scenario, seed: int) -> Run:
    """Simulate the truth of ``(scenario, seed)`` and open its sensor world."""
    if not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    ids, states = simulate_truth(scenario, int(seed))
    return Run(scenario=scenario, seed=int(seed), ids=ids, states=states)

"""The simulator: ``(scenario, seed) -> Run`` with the truth and a sensor world.

Common random numbers (docs/architecture.md). The world of a run depends on
``(scenario name, seed)`` only. For every step ``k`` the world holds uniforms
``U[k, j, c]``: the ``j``-th look at cell ``c`` during step ``k`` returns
``U[k, j, c] < p_d(T_kc)``. ``U[k, j, c]`` is draw number ``j n_cells + c`` of
``Generator.random`` on numpy's PCG64 keyed by ``(scenario, seed, k)`` (row ``j`` of
step ``k`` is the ``j``-th block of ``n_cells`` draws), so the answer to a look
depends neither on which other cells were looked at nor on the order of the
looks. Every tracker and every cell-selection policy therefore sees the same world.

Cost per step: ``O(targets + looks)``, nothing per cell of the grid. A look's uniform
is computed directly from its position in the generator's stream (PCG64 is a 128-bit
linear congruential generator: its state after ``n`` steps is ``A_n s_0 + S_n inc``
mod 2^128, :func:`pcg64_uniforms`), bit for bit the number ``Generator.random`` would
draw there, without drawing the ``n_cells`` numbers of a row; the number of targets of
a looked cell is counted from the targets' cells.
"""

from __future__ import annotations

import hashlib
import itertools
import zlib
from collections.abc import Iterator
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
    enters as a 128-bit SHA-256 prefix read little-endian (no practical collision between
    configurations; stored references depend on every detail of this derivation)."""
    key = int.from_bytes(hashlib.sha256(identity.encode("utf-8")).digest()[:16], "little")
    return np.random.SeedSequence(seed, spawn_key=(stable_hash(scenario_name), TRACKER_TAG, key))


# --------------------------------------------------------- the PCG64 stream, jumped
#: numpy's PCG64 (XSL-RR 128/64) multiplier
_PCG_MULT = 0x2360ED051FC65DA44385DF649FCCF645
_MASK64 = (1 << 64) - 1
_MASK128 = (1 << 128) - 1
#: bits of the stream position per jump table (one table of 2^16 entries per 16 bits)
_DIGIT_BITS = 16
_LOW32 = np.uint64(0xFFFFFFFF)
_U32 = np.uint64(32)
_JUMP_TABLES: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []


def _mulhi64(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """High 64 bits of the 128-bit products ``a b`` (uint64 arrays, 32-bit halves)."""
    a0, a1, b0, b1 = a & _LOW32, a >> _U32, b & _LOW32, b >> _U32
    p00, p01, p10 = a0 * b0, a0 * b1, a1 * b0
    mid = (p00 >> _U32) + (p01 & _LOW32) + (p10 & _LOW32)
    return a1 * b1 + (p01 >> _U32) + (p10 >> _U32) + (mid >> _U32)


def _mul128(ah, al, bh, bl):
    """``a b mod 2^128`` of 128-bit numbers held as (high, low) uint64 arrays."""
    return _mulhi64(al, bl) + al * bh + ah * bl, al * bl


def _add128(ah, al, bh, bl):
    """``a + b mod 2^128``."""
    lo = al + bl
    return ah + bh + (lo < al).astype(np.uint64), lo


def _split(x: int) -> tuple[np.ndarray, np.ndarray]:
    return np.array([x >> 64], dtype=np.uint64), np.array([x & _MASK64], dtype=np.uint64)


def _jump(n: int) -> tuple[int, int]:
    """``(A_n, S_n)``: ``n`` LCG steps map ``s`` to ``A_n s + S_n inc`` (mod 2^128), with
    ``A_n = MULT^n`` and ``S_n = sum_{i<n} MULT^i`` (the geometric sum, computed exactly
    modulo ``(MULT - 1) 2^128``)."""
    a = pow(_PCG_MULT, n, 1 << 128)
    s = ((pow(_PCG_MULT, n, (_PCG_MULT - 1) << 128) - 1) // (_PCG_MULT - 1)) & _MASK128
    return a, s


def _jump_table(i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``A``, ``S`` (high and low words) of the jumps ``d 2^(16 i)``, ``d < 2^16``, built
    by doubling (vectorised) and kept for the process."""
    while len(_JUMP_TABLES) <= i:
        a, s = _jump(1 << (_DIGIT_BITS * len(_JUMP_TABLES)))
        size = 1 << _DIGIT_BITS
        Ah, Al = np.zeros(size, np.uint64), np.zeros(size, np.uint64)
        Sh, Sl = np.zeros(size, np.uint64), np.zeros(size, np.uint64)
        Al[0] = 1
        for b in range(_DIGIT_BITS):  # entries [2^b, 2^(b+1)): jump 2^b base steps more
            h = 1 << b
            ah, al = _split(a)
            sh, sl = _split(s)
            Ah[h:2 * h], Al[h:2 * h] = _mul128(ah, al, Ah[:h], Al[:h])
            Sh[h:2 * h], Sl[h:2 * h] = _add128(*_mul128(ah, al, Sh[:h], Sl[:h]), sh, sl)
            a, s = (a * a) & _MASK128, (a * s + s) & _MASK128
        _JUMP_TABLES.append((Ah, Al, Sh, Sl))
    return _JUMP_TABLES[i]


def pcg64_uniforms(state: int, inc: int, positions: np.ndarray) -> np.ndarray:
    """Draws number ``positions`` (0-based, int64 ``>= 0``) of ``Generator.random`` on a
    PCG64 whose state is ``state`` and increment ``inc`` (``bit_generator.state``),
    without drawing the numbers before them: ``O(len(positions) log(max position))``.

    Draw ``n`` is the output of the state after ``n + 1`` steps, ``A s + S inc`` with
    ``(A, S)`` composed from one table entry per 16 bits of ``n + 1`` (the affine maps
    of one LCG commute); XSL-RR gives 64 bits, and ``random`` keeps the top 53. Equal,
    bit for bit, to ``Generator.random(n + 1)[n]`` (tests/test_scaling.py).
    """
    m = np.asarray(positions, dtype=np.int64).reshape(-1).astype(np.uint64) + np.uint64(1)
    digit_mask, shift = np.uint64((1 << _DIGIT_BITS) - 1), np.uint64(_DIGIT_BITS)
    d = (m & digit_mask).astype(np.intp)
    th, tl, sh, sl = _jump_table(0)
    Ah, Al, Sh, Sl = th[d], tl[d], sh[d], sl[d]  # the lowest 16 bits: one table entry
    m = m >> shift
    i = 1
    while len(m) and m.any():
        d = (m & digit_mask).astype(np.intp)
        th, tl, sh, sl = _jump_table(i)
        bh, bl = th[d], tl[d]
        # this jump after the ones so far: A <- B A, S <- B S + S_B
        Sh, Sl = _add128(*_mul128(bh, bl, Sh, Sl), sh[d], sl[d])
        Ah, Al = _mul128(bh, bl, Ah, Al)
        m = m >> shift
        i += 1
    s0h, s0l = _split(state)
    ih, il = _split(inc)
    xh, xl = _add128(*_mul128(Ah, Al, s0h, s0l), *_mul128(Sh, Sl, ih, il))
    # XSL-RR: (high xor low) rotated right by the top 6 bits of the state
    x, rot = xh ^ xl, xh >> np.uint64(58)
    raw = (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))
    return (raw >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


#: draw the whole prefix when it is at most this many numbers per position asked for (plus
#: a constant): ``Generator.random`` makes a number in about 2 ns, a jump costs ~40 ns
_PREFIX_PER_POSITION, _PREFIX_CONSTANT = 16, 4096


def stream_uniforms(state: int, inc: int, positions: np.ndarray) -> np.ndarray:
    """:func:`pcg64_uniforms`, the same numbers bit for bit, by the cheaper of two ways:
    when the largest position is small against the number asked for (a small grid, or
    most of a large one), ``Generator.random(max + 1)`` of a PCG64 set to the state, read
    at the positions; else the jumps, which cost nothing per cell of the grid."""
    positions = np.asarray(positions, dtype=np.int64).reshape(-1)
    if not len(positions):
        return np.zeros(0)
    top = int(positions.max()) + 1
    if top > _PREFIX_PER_POSITION * len(positions) + _PREFIX_CONSTANT:
        return pcg64_uniforms(state, inc, positions)
    bits = np.random.PCG64()
    bits.state = {"bit_generator": "PCG64", "state": {"state": state, "inc": inc},
                  "has_uint32": 0, "uinteger": 0}
    return np.random.Generator(bits).random(top)[positions]


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


def iter_truth(scenario: Scenario, seed: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Target ids ``(n_k,)`` and states ``(n_k, 4)`` of step ``k = 0, 1, ...`` (without
    end: :func:`simulate_truth` takes the first ``n_steps``), one step per ``next``:
    ``O(targets)`` each.

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
    yield ids.copy(), states.copy()
    while True:
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
        yield ids.copy(), states.copy()


def simulate_truth(scenario: Scenario, seed: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Target ids ``(n_k,)`` and states ``(n_k, 4)`` for each step ``k < n_steps``
    (:func:`iter_truth`)."""
    steps = list(itertools.islice(iter_truth(scenario, seed), max(scenario.n_steps, 1)))
    return [i for i, _ in steps], [x for _, x in steps]


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
    #: PCG64 (state, inc) of the generator of step k's looks, made on first use
    _streams: dict[int, tuple[int, int]] = field(default_factory=dict, repr=False)

    @property
    def n_steps(self) -> int:
        return len(self.states)

    def positions(self, k: int) -> np.ndarray:
        """True positions ``(n_k, 2)`` as ``(px, py)`` at step ``k``."""
        return self.states[k][:, [0, 2]]

    def cell_counts(self, k: int) -> np.ndarray:
        """Number of targets in every cell at step ``k``, shape ``(n_cells,)``
        (``O(cells)``: tests and plots; a look uses :meth:`counts_in`)."""
        grid = self.scenario.grid
        cells = grid.cell_of(self.states[k][:, 0], self.states[k][:, 2])
        return np.bincount(cells[cells >= 0], minlength=grid.n_cells)

    def counts_in(self, k: int, cells: np.ndarray) -> np.ndarray:
        """Number of targets at step ``k`` in each of ``cells`` (int64, any order, repeats
        allowed): ``O((targets + len(cells)) log targets)``."""
        grid = self.scenario.grid
        own = np.sort(grid.cell_of(self.states[k][:, 0], self.states[k][:, 2]))
        cells = np.asarray(cells, dtype=np.int64)
        return (np.searchsorted(own, cells, side="right")
                - np.searchsorted(own, cells, side="left")).astype(np.int64)

    def uniforms(self, k: int, cells: np.ndarray, repeat: np.ndarray) -> np.ndarray:
        """``U[k, repeat, cells]`` (element-wise): draw ``repeat * n_cells + cell`` of step
        ``k``'s generator (:func:`pcg64_uniforms`; nothing per cell of the grid)."""
        stream = self._streams.get(k)
        if stream is None:
            bits = np.random.PCG64(world_seed(self.scenario.name, self.seed, _LOOKS, k))
            stream = (int(bits.state["state"]["state"]), int(bits.state["state"]["inc"]))
            self._streams[k] = stream
        n_cells = self.scenario.grid.n_cells
        positions = np.asarray(repeat, dtype=np.int64) * n_cells + np.asarray(cells, np.int64)
        return stream_uniforms(*stream, positions)

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
        u = self.uniforms(k, cells, repeat)
        p = sensor.detection_probability(self.counts_in(k, cells))
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

"""Model types shared by the simulator and the trackers.

Everything here is *model*: the grid, the target dynamics, the birth/death
process and the sensors. Trackers may import these types (and nothing else from
``scenarios``); the truth and the random numbers of a run live in
:mod:`scenarios.simulator`.

State of one target: ``x = [px, vx, py, vy]`` in workspace units (cell size
times cell index), velocities in workspace units per time unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np


# ----------------------------------------------------------------------------- grid
@dataclass(frozen=True)
class Grid:
    """An ``nx x ny`` grid of square cells of side ``cell_size``.

    The workspace is ``[0, nx*cell_size) x [0, ny*cell_size)``. Cells are numbered
    row-major in y: ``c = iy * nx + ix`` with ``ix = floor(px / cell_size)``.
    """

    nx: int
    ny: int
    cell_size: float = 1.0

    @property
    def n_cells(self) -> int:
        return self.nx * self.ny

    @property
    def extent(self) -> tuple[float, float]:
        """Workspace width and height, ``(nx*cell_size, ny*cell_size)``."""
        return (self.nx * self.cell_size, self.ny * self.cell_size)

    def cell_of(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Flat cell index of positions (any matching shapes); -1 outside the grid."""
        ix = np.floor(np.asarray(px, dtype=float) / self.cell_size)
        iy = np.floor(np.asarray(py, dtype=float) / self.cell_size)
        inside = (ix >= 0) & (ix < self.nx) & (iy >= 0) & (iy < self.ny)
        flat = np.where(inside, iy * self.nx + ix, -1)
        return flat.astype(np.int64)

    def cell_centers(self, cells: np.ndarray | None = None) -> np.ndarray:
        """Centres ``(n, 2)`` as ``(px, py)`` of the given flat cells (all if None)."""
        cells = np.arange(self.n_cells) if cells is None else np.asarray(cells, dtype=np.int64)
        out = np.empty(cells.shape + (2,))
        out[..., 0] = (cells % self.nx + 0.5) * self.cell_size
        out[..., 1] = (cells // self.nx + 0.5) * self.cell_size
        return out

    def cell_bounds(self, cells: np.ndarray) -> tuple[np.ndarray, ...]:
        """Lower and upper edges ``(x0, x1, y0, y1)``, each of shape ``cells.shape``."""
        cells = np.asarray(cells, dtype=np.int64)
        ix = cells % self.nx
        iy = cells // self.nx
        s = self.cell_size
        return ix * s, (ix + 1) * s, iy * s, (iy + 1) * s


# ------------------------------------------------------------------------- dynamics
@dataclass(frozen=True)
class Dynamics:
    """Nearly-constant-velocity dynamics ``x_{k+1} = F x_k + v``, ``v ~ N(0, Q)``.

    ``F = [[1,tau,0,0],[0,1,0,0],[0,0,1,tau],[0,0,0,1]]`` (the paper's F).
    ``Q`` is either given explicitly as a 4x4 matrix (``q_matrix``, the paper's
    ``diag(20, 0.2, 20, 0.2)``) or built from the intensity ``q`` of continuous
    white-noise acceleration (units: length^2 / time^3), per axis::

        Q_axis = q * [[tau^3/3, tau^2/2], [tau^2/2, tau]]

    Exactly one of ``q_matrix`` and ``wna_intensity`` must be set.
    """

    tau: float = 1.0
    q_matrix: tuple[tuple[float, ...], ...] | None = None
    wna_intensity: float | None = None

    @property
    def F(self) -> np.ndarray:  # noqa: N802 - the paper's name
        """State transition matrix, shape ``(4, 4)``."""
        t = self.tau
        return np.array(
            [[1.0, t, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, t], [0.0, 0.0, 0.0, 1.0]]
        )

    @property
    def Q(self) -> np.ndarray:  # noqa: N802
        """Process-noise covariance, shape ``(4, 4)``."""
        if self.q_matrix is not None:
            return np.array(self.q_matrix, dtype=float)
        t, q = self.tau, float(self.wna_intensity)
        block = q * np.array([[t**3 / 3.0, t**2 / 2.0], [t**2 / 2.0, t]])
        Q = np.zeros((4, 4))
        Q[0:2, 0:2] = block
        Q[2:4, 2:4] = block
        return Q


# ---------------------------------------------------------------------- birth/death
Boundary = Literal["reflect", "die"]


@dataclass(frozen=True)
class BirthDeath:
    """Target existence process (the truth's, and the trackers' prior).

    Each step every target survives with ``survival_probability``; then a
    Poisson(``birth_rate``) number of new targets appear, uniform over the
    workspace, with velocity ``N(0, birth_velocity_std^2)`` per axis. A target
    that leaves the workspace either reflects off its edge or dies (``boundary``).

    The run starts with the explicit ``initial_states`` (each ``[px,vx,py,vy]``)
    plus ``n_random_initial`` targets drawn like births.
    """

    initial_states: tuple[tuple[float, float, float, float], ...] = ()
    n_random_initial: int = 0
    survival_probability: float = 1.0
    birth_rate: float = 0.0
    birth_velocity_std: float = 0.1
    boundary: Boundary = "reflect"

    @property
    def initial_count_mean(self) -> float:
        """Expected number of targets at the first step (a prior, not the truth)."""
        return float(len(self.initial_states) + self.n_random_initial)


# -------------------------------------------------------------------------- sensors
@dataclass(frozen=True)
class RayleighGridSensor:
    """Thresholded Rayleigh returns from a look at one cell (paper Section V).

    A look at a cell holding ``T`` targets returns 1 with probability
    ``p_d(T) = p_d ** ((1 + snr) / (1 + T * snr))``; ``T = 0`` gives the false
    alarm probability ``p_f = p_d ** (1 + snr)``. ``snr`` is linear (not dB).
    ``looks_per_step`` is ``M``, the number of looks the sensor may make per step.
    """

    p_d: float = 0.5
    snr: float = 10.0
    looks_per_step: int = 24

    @property
    def p_f(self) -> float:
        return self.p_d ** (1.0 + self.snr)

    def detection_probability(self, n_targets: np.ndarray | int) -> np.ndarray:
        """``p_d(T)`` for an array of in-cell counts ``T >= 0`` (same shape)."""
        t = np.asarray(n_targets, dtype=float)
        return self.p_d ** ((1.0 + self.snr) / (1.0 + t * self.snr))

    def log_likelihood_ratio(self, returns: np.ndarray, n_targets: np.ndarray) -> np.ndarray:
        """``log l(T) = log p(z|T) - log p(z|0)`` for returns ``z`` (bool) and counts ``T``.

        Broadcasts; the result is exactly 0 where ``T == 0``.
        """
        pd = self.detection_probability(n_targets)
        pf = self.p_f
        z = np.asarray(returns, dtype=bool)
        # log1p keeps precision when p_d(T) and p_f are both tiny or both near 1
        return np.where(z, np.log(pd) - math.log(pf), np.log1p(-pd) - math.log1p(-pf))


@dataclass(frozen=True)
class SuperpositionSensor:
    """The paper's linear sensor: ``z = (1/N) sum_i H x_i + w``, ``w ~ N(0, R)``.

    ``H`` is ``(m, 4)`` and ``R`` is ``(m, m)``. With no target present the sensor
    reports pure noise ``z = w`` (the paper leaves this case undefined).
    """

    h_matrix: tuple[tuple[float, ...], ...] = ((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0))
    r_matrix: tuple[tuple[float, ...], ...] = ((0.25, 0.0), (0.0, 0.25))

    @property
    def H(self) -> np.ndarray:  # noqa: N802
        return np.array(self.h_matrix, dtype=float)

    @property
    def R(self) -> np.ndarray:  # noqa: N802
        return np.array(self.r_matrix, dtype=float)


Sensor = RayleighGridSensor | SuperpositionSensor


# ----------------------------------------------------------------------- visibility
@dataclass(frozen=True)
class Occlusion:
    """Cells the sensor cannot look at during a range of steps.

    The rectangle of columns ``x[0]..x[1]`` and rows ``y[0]..y[1]`` (cell indices,
    inclusive) is blind during steps ``steps[0]..steps[1]`` (inclusive). With a
    ``velocity`` ``(vx, vy)`` (cells per step, fractions allowed) it moves: at step ``k``
    it is shifted by ``floor((vx, vy) * (k - steps[0]))`` whole cells and wraps around the
    grid's edges (a blind band sweeping the grid; ``vx = 0.25`` moves it one cell every 4
    steps). A cell ``(ix, iy)`` is blind at step ``k`` if, with ``t = k - k0``::

        (ix - x0 - floor(vx t)) mod nx < x1 - x0 + 1
        and (iy - y0 - floor(vy t)) mod ny < y1 - y0 + 1

    (a static rectangle inside the grid: ``x0 <= ix <= x1`` and ``y0 <= iy <= y1``).
    """

    x: tuple[int, int]
    y: tuple[int, int]
    steps: tuple[int, int]
    velocity: tuple[float, float] = (0.0, 0.0)

    def active(self, k: int) -> bool:
        return self.steps[0] <= k <= self.steps[1]

    def origin(self, k: int, grid: Grid) -> tuple[int, int]:
        """The rectangle's lower-left cell ``(ix, iy)`` at step ``k``, wrapped into the grid."""
        t = k - self.steps[0]
        return ((self.x[0] + math.floor(self.velocity[0] * t)) % grid.nx,
                (self.y[0] + math.floor(self.velocity[1] * t)) % grid.ny)

    @property
    def size(self) -> tuple[int, int]:
        """Width and height in cells."""
        return self.x[1] - self.x[0] + 1, self.y[1] - self.y[0] + 1


@dataclass(frozen=True)
class Visibility:
    """Which cells can be looked at, step by step: none blind unless ``occlusions`` say so.

    Every query costs ``O(blind cells)`` or ``O(cells asked about x active occlusions)``,
    never ``O(grid)``: the occlusions are rectangles, not a per-cell map.
    """

    occlusions: tuple[Occlusion, ...] = ()

    def active(self, k: int) -> tuple[Occlusion, ...]:
        """The occlusions in force at step ``k``."""
        return tuple(o for o in self.occlusions if o.active(k))

    def blocked(self, k: int, grid: Grid) -> np.ndarray:
        """Flat indices of the cells that cannot be looked at during step ``k``: sorted,
        distinct, int64 (empty when nothing is blind)."""
        parts = []
        for o in self.active(k):
            ox, oy = o.origin(k, grid)
            w, h = o.size
            ix = (ox + np.arange(w, dtype=np.int64)) % grid.nx
            iy = (oy + np.arange(h, dtype=np.int64)) % grid.ny
            parts.append((iy[:, None] * grid.nx + ix[None, :]).reshape(-1))
        if not parts:
            return np.zeros(0, dtype=np.int64)
        return np.unique(np.concatenate(parts))

    def is_blocked(self, k: int, cells: np.ndarray, grid: Grid) -> np.ndarray:
        """Boolean mask ``(n,)``: which of the flat ``cells (n,)`` are blind at step ``k``."""
        cells = np.asarray(cells, dtype=np.int64)
        out = np.zeros(cells.shape, dtype=bool)
        ix, iy = cells % grid.nx, cells // grid.nx
        for o in self.active(k):
            ox, oy = o.origin(k, grid)
            w, h = o.size
            out |= ((ix - ox) % grid.nx < w) & ((iy - oy) % grid.ny < h)
        return out


# ------------------------------------------------------------------ tracking model
@dataclass(frozen=True)
class TrackingModel:
    """What a tracker is told about a scenario: the model, never the truth.

    ``visibility`` says which cells the sensor cannot look at during which steps; a look
    at a blind cell is not made (the harness drops it), so a tracker only ever sees
    looks at visible cells."""

    grid: Grid
    dynamics: Dynamics
    birth_death: BirthDeath = field(default_factory=BirthDeath)
    sensor: Sensor = field(default_factory=RayleighGridSensor)
    #: cells the grid sensor cannot look at, by step (none by default)
    visibility: Visibility = field(default_factory=Visibility)

    def blocked_cells(self, k: int) -> np.ndarray:
        """Sorted flat cells ``(n,)`` int64 that cannot be looked at during step ``k``."""
        return self.visibility.blocked(k, self.grid)

    @property
    def is_grid(self) -> bool:
        return isinstance(self.sensor, RayleighGridSensor)


# ----------------------------------------------------------------------- one step
@dataclass(frozen=True)
class Looks:
    """The measurements of one step, in the order the looks were made.

    Grid sensor: ``cells (L,) int64`` flat indices (repeats allowed: each repeat is
    an independent look) and ``returns (L,) bool``. Superposition sensor: ``z (m,)``
    and empty ``cells``/``returns``.
    """

    cells: np.ndarray
    returns: np.ndarray
    z: np.ndarray | None = None

    @staticmethod
    def empty() -> Looks:
        return Looks(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool))

    def __len__(self) -> int:
        return int(self.cells.shape[0])

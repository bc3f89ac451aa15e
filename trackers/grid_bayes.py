"""``grid-bayes``: the exact Bayes filter of a single-target model on a point-mass grid.

A REFERENCE, not a contestant (``reference = True``): it is the model's own posterior,
computed on a grid instead of approximated by particles or Gaussians, for models that can
hold at most one target. It uses no truth. It answers, on such scenarios, "how well could
anyone do here", independently of the particle reference (``jmpd-ap`` at large N).

**Models it runs.** At most one target at any time: at most one initial target (a
declared state, or ``n_random_initial = 1``), ``p_s <= 1``, and no births (the model's
births are Poisson, and a Poisson number of arrivals can be two in one step, or one
beside a living target). The dynamics must act on x and y separately (no x-y terms in
``Q``). Anything else is refused in one line (:meth:`GridBayesTracker.unsupported_reason`).

**State.** The probability ``1 - E`` of "no target" and a point-mass density
``P[s_x, s_y]`` over the per-axis grids (``s = i n_v + j`` for position node ``i`` and
velocity node ``j``), ``sum P = E`` (the existence probability). Position nodes sit at
the centres of ``ppc`` equal bins per sensor cell, ``x_i = (i + 1/2) h_x`` with ``h_x =
cell / ppc``, so each node lies in exactly one sensor cell; velocity nodes at ``v_j = j
h_v``, ``|j| <= n``.

**Resolution from the model** (``spacing`` multiplies both spacings; 0.5 halves them):

* ``ppc = round(4 / spacing)`` position nodes per cell (4 at the default);
* velocity half-extent ``V = max |v_0| + velocity_sds * sqrt(s_0^2 + horizon * Q_vv)``
  per axis, with ``s_0`` the birth velocity sd when the initial target is random (0 for a
  declared one), ``Q_vv`` the per-step velocity noise variance, ``horizon`` a number of
  steps (the velocity's random walk spreads as ``sqrt(k Q_vv)``); ``h_v = spacing V / 16``
  (33 velocity nodes per axis at the default). A velocity pushed beyond ``+-V`` by the
  noise is kept on the edge node (the one approximation that does not vanish with
  ``spacing``; it vanishes with ``velocity_sds``).

No search range: these are accuracy settings, not a tuning. The default (``spacing =
1``) is the fast one; on the shipped single-target scenarios it is not converged at every
step (existence off by up to 0.08 against a 200,000-particle Bernoulli filter), while
``spacing = 0.5`` agrees with that filter to its Monte Carlo error on ``single-clean`` and
to 0.036 on ``single-clutter``: use 0.5 for reference numbers (docs/bayes_grid.md).

**Prediction** (``x <- F x + w``, ``w ~ N(0, Q)``, then the wall rule, then survival),
per axis, as a sparse transition matrix ``K (S, S)`` built once in :meth:`reset`:
from node ``(x_i, v_j)`` the successor ``y ~ N((x_i + tau v_j, v_j), Q_axis)`` is
represented by the Gaussian's weights on a symmetric lattice of offsets of spacing
``(h_x / 2, h_v / 2)`` within 4.5 sd (normalised to sum 1, so mass and mean are exact),
each lattice point then moved by the model's wall rule as the simulator moves the truth
(``die``: a point outside ``[0, L)`` is lost, which is the death at the wall;
``reflect``: the position folded into ``[0, L)`` and the velocity negated on an odd
number of bounces) and split between its two neighbouring nodes per coordinate by
linear interpolation (mean-preserving; it adds at most ``h^2 / 4`` variance per step,
an error of order ``h^2`` that the spacing study bounds). The 4-D prediction is then
``P <- p_s K_x P K_y^T``, over the rows and columns holding mass above ``1e-14`` of the
total (the rest, less than ``S * 1e-14`` in all, is dropped). The simulator's step 0
holds the initial targets before any motion or survival, so the first :meth:`predict`
leaves the prior unchanged.

**Update.** With at most one target, a look at cell ``c`` sees 1 target there with the
density's mass in ``c`` and 0 otherwise; looks (repeats included) are independent
given the state. Dividing every hypothesis by ``prod_looks p(z | 0)``::

    P(s) <- P(s) Lambda_{c(s)} / Z,   1 - E <- (1 - E) / Z,
    Lambda_c = prod_{looks at c} p(z | 1) / p(z | 0),   Z = 1 - E + sum_s P(s) Lambda_{c(s)}

with ``p(z=1 | 1) = RayleighGridSensor.detection_probability(1)`` and ``p(z=1 | 0) =
p_f`` (in logs, scaled by the largest ``Lambda``, so many positive repeats cannot
overflow). This is exact Bayes on the grid.

**Estimate.** ``count = E``, the existence probability. The state reported is the
posterior mean given existence, ``E[x | target] = sum_s P(s) x_s / E``, and it is reported
iff ``E >= 0.5``. Why this suits OSPA with cut-off ``c``: with at most one target the
cardinality part costs ``c^p`` when the reported count (0 or 1) is wrong, so reporting a
state iff ``P(target) > 1/2`` minimises its expected value; given a reported state the
localisation part ``min(d, c)^p`` is minimised approximately by the posterior mean (the
MMSE position, exact for ``p = 2`` when the posterior lies within ``c`` of it). The
covariance is the posterior's given existence; the track label is 0.

**P_c(t).** Dense ``(n_cells, 2)``: ``[1 - m_c, m_c]`` with ``m_c`` the predicted mass in
cell ``c``, exact since no cell can hold two targets; ``O(cells)``, fine on the small
grids this filter runs on (the density itself is larger).

Cost per step: ``O(S_x S_y k)`` for the prediction (``k`` the transition's entries per
column, ~10-40) and ``O(S_x S_y)`` for the update; memory ``O(S_x S_y)``. A model whose
grid would hold more than ``max_states`` nodes is refused.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from scipy import sparse
from scipy.special import ndtr

from ..scenarios.model import Looks, RayleighGridSensor, TrackingModel
from .base import Estimate, ResourceTerms, Tracker, param_number, register
from .params import Param

#: position nodes per sensor cell at ``spacing = 1``
BASE_NODES_PER_CELL = 4
#: velocity nodes per half-extent at ``spacing = 1``
BASE_VELOCITY_NODES = 16
#: the transition's Gaussian lattice covers this many sd per coordinate
LATTICE_SDS = 4.5
#: rows / columns of P with less than this share of the total mass are not propagated
PRUNE = 1e-14
#: build the transition in chunks of at most this many (source, lattice point) pairs
_CHUNK = 2_000_000


# ------------------------------------------------------------------ the axis grids
def _fold(pos: np.ndarray, vel: np.ndarray, length: float) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's reflection: positions folded into ``[0, length)``, velocities
    negated on an odd number of bounces."""
    folded = np.mod(pos, 2.0 * length)
    bounced = folded >= length
    pos = np.minimum(np.where(bounced, 2.0 * length - folded, folded), np.nextafter(length, 0))
    return pos, np.where(bounced, -vel, vel)


class AxisGrid:
    """The grid of one axis: ``n_p`` position nodes ``(i + 1/2) h_x`` on ``[0, length)``
    and ``2 n + 1`` velocity nodes ``j h_v``; flat index ``s = i n_v + (j + n)``."""

    def __init__(self, length: float, n_cells: int, ppc: int, h_v: float, n_half: int) -> None:
        self.length, self.ppc = float(length), int(ppc)
        self.n_p = int(n_cells) * self.ppc
        self.h_x = self.length / self.n_p
        self.h_v, self.n_half = float(h_v), int(n_half)
        self.n_v = 2 * self.n_half + 1
        self.x = (np.arange(self.n_p) + 0.5) * self.h_x
        self.v = np.arange(-self.n_half, self.n_half + 1) * self.h_v

    @property
    def size(self) -> int:
        return self.n_p * self.n_v

    def features(self) -> np.ndarray:
        """``(S, 2)``: ``[x, v]`` of every flat node."""
        return np.stack([np.repeat(self.x, self.n_v), np.tile(self.v, self.n_p)], axis=1)

    def split(self, x: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear interpolation of points ``(x, v)`` (inside ``[0, length)``) onto the
        nodes: flat indices ``(..., 4)`` and weights ``(..., 4)`` (positions beyond the
        outer node centres go to the outer node, velocities beyond ``+-V`` to the edge)."""
        u = x / self.h_x - 0.5
        i0 = np.floor(u)
        fx = u - i0
        i0 = i0.astype(np.int64)
        ia = np.clip(i0, 0, self.n_p - 1)
        ib = np.clip(i0 + 1, 0, self.n_p - 1)
        if self.n_half == 0:
            ja = jb = np.zeros_like(ia)
            fv = np.zeros_like(fx)
        else:
            w = np.clip(v / self.h_v + self.n_half, 0.0, self.n_v - 1.0)
            j0 = np.minimum(np.floor(w), self.n_v - 2)
            fv = w - j0
            ja = j0.astype(np.int64)
            jb = ja + 1
        idx = np.stack([ia * self.n_v + ja, ia * self.n_v + jb,
                        ib * self.n_v + ja, ib * self.n_v + jb], axis=-1)
        wts = np.stack([(1 - fx) * (1 - fv), (1 - fx) * fv, fx * (1 - fv), fx * fv], axis=-1)
        return idx, wts


def _lattice(q: np.ndarray, d_x: float, d_v: float) -> tuple[np.ndarray, np.ndarray]:
    """Offsets ``(G, 2)`` on a symmetric lattice of spacing ``(d_x, d_v)`` within
    :data:`LATTICE_SDS` sd of ``N(0, q)`` per coordinate, and their weights ``(G,)``
    (the Gaussian density there, normalised to sum 1; a zero-variance coordinate has the
    single offset 0)."""
    sd = np.sqrt(np.maximum(np.diag(q), 0.0))
    n_x = int(LATTICE_SDS * sd[0] / d_x) if sd[0] > 0 else 0
    n_v = int(LATTICE_SDS * sd[1] / d_v) if sd[1] > 0 and d_v > 0 else 0
    ox, ov = np.meshgrid(np.arange(-n_x, n_x + 1) * d_x, np.arange(-n_v, n_v + 1) * d_v,
                         indexing="ij")
    off = np.stack([ox.ravel(), ov.ravel()], axis=1)
    keep = np.array([n_x > 0, n_v > 0])
    if not keep.any():
        return off, np.ones(1)
    sub = q[np.ix_(keep, keep)]
    o = off[:, keep]
    logw = -0.5 * np.einsum("gi,ij,gj->g", o, np.linalg.inv(sub), o)
    w = np.exp(logw - logw.max())
    w /= w.sum()
    return off, w


def axis_transition(axis: AxisGrid, q: np.ndarray, tau: float, boundary: str) -> sparse.csc_matrix:
    """Per-axis transition ``K (S, S)``: column ``s`` is the grid image of ``N((x + tau v,
    v), q)`` from node ``s`` after the wall rule (module docstring); a column sums to the
    probability of staying inside (1 under ``reflect``)."""
    off, w = _lattice(q, axis.h_x / 2.0, axis.h_v / 2.0)
    feats = axis.features()
    S, G = axis.size, len(w)
    mats = []
    per_chunk = max(1, _CHUNK // G)
    for start in range(0, S, per_chunk):
        src = np.arange(start, min(S, start + per_chunk))
        mean_x = feats[src, 0] + tau * feats[src, 1]
        x = mean_x[:, None] + off[None, :, 0]
        v = feats[src, 1][:, None] + off[None, :, 1]
        wt = np.broadcast_to(w, x.shape)
        if boundary == "reflect":
            x, v = _fold(x, v, axis.length)
            alive = np.ones(x.shape, dtype=bool)
        else:
            alive = (x >= 0.0) & (x < axis.length)
        cols = np.broadcast_to(src[:, None], x.shape)[alive]
        idx, wts = axis.split(x[alive], v[alive])
        data = (wts * wt[alive][:, None]).ravel()
        mats.append(sparse.coo_matrix((data, (idx.ravel(), np.repeat(cols, 4))),
                                      shape=(S, S)).tocsc())
    K = mats[0]
    for m in mats[1:]:
        K = K + m
    K.sum_duplicates()
    return K


def _velocity_scales(model: TrackingModel, spacing: float, velocity_sds: float,
                     horizon: float) -> list[tuple[float, int]]:
    """``(h_v, n)`` per axis (module docstring)."""
    bd, Q = model.birth_death, model.dynamics.Q
    s0 = float(bd.birth_velocity_std) if bd.n_random_initial else 0.0
    declared = np.asarray(bd.initial_states, dtype=float).reshape(-1, 4)
    out = []
    for vi in (1, 3):
        v0 = float(np.abs(declared[:, vi]).max()) if len(declared) else 0.0
        spread = math.sqrt(s0 ** 2 + horizon * max(float(Q[vi, vi]), 0.0))
        V = v0 + velocity_sds * spread
        if V <= 0.0:
            out.append((1.0, 0))
            continue
        h_v = spacing * V / BASE_VELOCITY_NODES
        out.append((h_v, int(math.ceil(V / h_v - 1e-9))))
    return out


def grid_size(model: TrackingModel, spacing: float, velocity_sds: float,
              horizon: float) -> tuple[int, int]:
    """Flat nodes ``(S_x, S_y)`` of the grid the filter would build for ``model``."""
    ppc = max(1, round(BASE_NODES_PER_CELL / spacing))
    (_, nx_half), (_, ny_half) = _velocity_scales(model, spacing, velocity_sds, horizon)
    g = model.grid
    return g.nx * ppc * (2 * nx_half + 1), g.ny * ppc * (2 * ny_half + 1)


# ----------------------------------------------------------------------- tracker
@register
class GridBayesTracker(Tracker):
    """Exact single-target Bayes filter on a point-mass grid (module docstring). A
    reference that uses no truth; not a contestant."""

    name = "grid-bayes"
    summary = ("REFERENCE (no truth): the exact Bayes filter of a single-target model on a "
               "point-mass grid over (px, vx, py, vy) with existence")
    reference = True
    conformance_exceptions: ClassVar[dict[str, str]] = {
        check: "runs only models with at most one target (this check's has several)"
        for check in ("check_runs_200_steps", "check_deterministic",
                      "check_reset_no_state_leak", "check_step_without_looks",
                      "check_count_distribution_on_large", "check_tracks_two_targets")
    }
    parameters: ClassVar[dict[str, Param]] = {
        "spacing": Param(float, 0.0, 4.0, low_open=True,
                         doc="grid spacing, a multiple of 1/4 cell and of V/16"),
        "velocity_sds": Param(float, 0.0, low_open=True,
                              doc="velocity half-extent, in sd of the velocity spread"),
        "horizon": Param(float, 0.0,
                         doc="steps of velocity noise in the velocity spread"),
        "max_states": Param(int, 1, doc="largest grid (nodes) accepted"),
    }

    def __init__(self, spacing: float = 1.0, velocity_sds: float = 4.0, horizon: float = 50.0,
                 max_states: int = 20_000_000) -> None:
        self.spacing = spacing
        self.velocity_sds = velocity_sds
        self.horizon = horizon
        self.max_states = max_states

    # ------------------------------------------------------------ what it runs
    def unsupported_reason(self, model: TrackingModel) -> str | None:
        if not isinstance(model.sensor, RayleighGridSensor):
            return "the exact grid filter is built for the Rayleigh grid sensor"
        bd = model.birth_death
        n0 = len(bd.initial_states) + bd.n_random_initial
        if n0 > 1:
            return f"holds at most one target: this model starts with {n0}"
        if bd.birth_rate > 0:
            return (f"holds at most one target: Poisson births (rate {bd.birth_rate:g}) can "
                    "bring a second target")
        Q = model.dynamics.Q
        if np.any(Q[np.ix_([0, 1], [2, 3])] != 0):
            return "needs dynamics without x-y terms in Q (it predicts per axis)"
        if n0 == 0:
            return None
        sx, sy = grid_size(model, self.spacing, self.velocity_sds, self.horizon)
        if sx * sy > self.max_states:
            return (f"its grid would hold {sx * sy:,} nodes, more than max_states = "
                    f"{self.max_states:,}")
        return None

    # --------------------------------------------------------------- life cycle
    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        self.validate_params(self.get_params())
        reason = self.unsupported_reason(model)
        if reason:
            raise ValueError(f"grid-bayes cannot run this model: {reason}")
        self._model = model
        self._first = True
        bd, dyn, g = model.birth_death, model.dynamics, model.grid
        self._p_s = float(bd.survival_probability)
        self._sensor = model.sensor
        n0 = len(bd.initial_states) + bd.n_random_initial
        self._sub: np.ndarray | None = None  # the density on its support
        self._no_target = 1.0
        self._pred_cells: np.ndarray | None = None
        if n0 == 0:
            return
        ppc = max(1, round(BASE_NODES_PER_CELL / self.spacing))
        scales = _velocity_scales(model, self.spacing, self.velocity_sds, self.horizon)
        self._ax = AxisGrid(g.extent[0], g.nx, ppc, *scales[0])
        self._ay = AxisGrid(g.extent[1], g.ny, ppc, *scales[1])
        Q = dyn.Q
        self._Kx = axis_transition(self._ax, Q[0:2, 0:2], dyn.tau, bd.boundary)
        self._Ky = axis_transition(self._ay, Q[2:4, 2:4], dyn.tau, bd.boundary)
        self._fx, self._fy = self._ax.features(), self._ay.features()
        if bd.initial_states:
            self._set_density(self._point_prior(np.asarray(bd.initial_states[0], dtype=float)))
        else:
            self._set_density(np.outer(self._random_axis_prior(self._ax, bd.birth_velocity_std),
                                       self._random_axis_prior(self._ay, bd.birth_velocity_std)))
        self._no_target = 0.0

    @staticmethod
    def _random_axis_prior(axis: AxisGrid, s0: float) -> np.ndarray:
        """``(S,)``: uniform position (``1 / n_p`` per node, each node one equal bin) times
        ``N(0, s0^2)`` integrated over each velocity node's bin (outer bins to infinity)."""
        if axis.n_half == 0 or s0 <= 0:
            pv = (axis.v == 0).astype(float)
        else:
            edges = np.concatenate([[-np.inf], (axis.v[:-1] + axis.v[1:]) / 2, [np.inf]])
            pv = np.diff(ndtr(edges / s0))
        return np.outer(np.full(axis.n_p, 1.0 / axis.n_p), pv).ravel()

    def _point_prior(self, state: np.ndarray) -> np.ndarray:
        """A declared initial state, split onto its 16 neighbouring nodes (mean kept)."""
        ix, wx = self._ax.split(np.array([state[0]]), np.array([state[1]]))
        iy, wy = self._ay.split(np.array([state[2]]), np.array([state[3]]))
        P = np.zeros((self._ax.size, self._ay.size))
        np.add.at(P, (ix[0][:, None], iy[0][None, :]), wx[0][:, None] * wy[0][None, :])
        return P

    def _set_density(self, P: np.ndarray, rows: np.ndarray | None = None,
                     cols: np.ndarray | None = None) -> None:
        """Keep ``P`` on its support: the rows and columns (flat x and y nodes, sorted)
        holding more than :data:`PRUNE` of the total mass."""
        rows = np.arange(P.shape[0]) if rows is None else rows
        cols = np.arange(P.shape[1]) if cols is None else cols
        total = P.sum()
        keep_r = P.sum(axis=1) > PRUNE * total
        keep_c = P.sum(axis=0) > PRUNE * total
        if not keep_r.all() or not keep_c.all():
            P = P[np.ix_(keep_r, keep_c)]
            rows, cols = rows[keep_r], cols[keep_c]
        self._sub, self._rows, self._cols = np.ascontiguousarray(P), rows, cols

    @staticmethod
    def _propagate(K: sparse.csc_matrix, src: np.ndarray, M: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """``K[:, src] @ M`` on the rows it reaches: ``(reached rows, product)``."""
        Ks = K[:, src]
        reached = np.unique(Ks.indices)
        return reached, np.asarray(Ks.tocsr()[reached] @ M)

    def predict(self) -> None:
        self._pred_cells = None
        if self._sub is None:
            return
        if self._first:  # the simulator's step 0 is the prior itself
            self._first = False
            return
        before = self._sub.sum()
        if before <= 0.0:
            return
        # P <- p_s K_x P K_y^T, on the support
        rows, half = self._propagate(self._Kx, self._rows, self._sub)
        cols, out_t = self._propagate(self._Ky, self._cols, half.T)
        out = out_t.T * self._p_s
        self._no_target += before - out.sum()
        self._set_density(out, rows, cols)

    def _cells_xy(self) -> tuple[np.ndarray, np.ndarray]:
        """Sensor-cell column (x) of each support row and row (y) of each support column."""
        return ((self._rows // self._ax.n_v) // self._ax.ppc,
                (self._cols // self._ay.n_v) // self._ay.ppc)

    def _cell_mass(self) -> np.ndarray:
        """``(nx, ny)`` mass of the target in each sensor cell ``(cx, cy)``."""
        g = self._model.grid
        cx, cy = self._cells_xy()
        ax_ind = sparse.csr_matrix((np.ones(len(cx)), (cx, np.arange(len(cx)))),
                                   shape=(g.nx, len(cx)))
        ay_ind = sparse.csr_matrix((np.ones(len(cy)), (cy, np.arange(len(cy)))),
                                   shape=(g.ny, len(cy)))
        by_x = np.asarray(ax_ind @ self._sub)  # (nx, |cols|)
        return np.asarray(ay_ind @ by_x.T).T

    def cell_count_distribution(self) -> np.ndarray:
        """Dense ``(n_cells, 2)``: ``[1 - m_c, m_c]``, ``m_c`` the mass in cell ``c``."""
        n_cells = self._model.grid.n_cells
        if self._sub is None:
            return np.column_stack([np.ones(n_cells), np.zeros(n_cells)])
        if self._pred_cells is None:  # flat cell c = cy nx + cx
            self._pred_cells = np.clip(self._cell_mass().T.ravel(), 0.0, 1.0)
        m = self._pred_cells
        return np.column_stack([1.0 - m, m])

    def update(self, looks: Looks) -> None:
        if self._sub is None or not len(looks):
            return
        g, sensor = self._model.grid, self._sensor
        pd1, pf = float(sensor.detection_probability(1)), sensor.p_f
        z = np.asarray(looks.returns, dtype=bool)
        # log Lambda of each look, summed per cell (repeats are independent looks)
        lr = np.where(z, math.log(pd1) - math.log(pf), math.log1p(-pd1) - math.log1p(-pf))
        log_lam = np.bincount(np.asarray(looks.cells, dtype=np.int64), weights=lr,
                              minlength=g.n_cells)
        top = max(float(log_lam.max()), 0.0)
        lam = np.exp(log_lam - top).reshape(g.ny, g.nx).T  # (nx, ny), scaled
        cx, cy = self._cells_xy()
        self._sub *= lam[cx[:, None], cy[None, :]]
        none = self._no_target * math.exp(-top)
        Z = none + self._sub.sum()
        self._sub /= Z
        self._no_target = none / Z

    # ----------------------------------------------------------------- estimate
    @property
    def existence(self) -> float:
        """``P(a target exists)`` now."""
        return 0.0 if self._sub is None else float(self._sub.sum())

    def posterior_moments(self) -> tuple[float, np.ndarray, np.ndarray]:
        """``(E, mean (4,), covariance (4, 4))`` of the state given existence
        (``[px, vx, py, vy]``); NaN moments when ``E = 0``."""
        E = self.existence
        if E <= 0.0:
            return 0.0, np.full(4, np.nan), np.full((4, 4), np.nan)
        P = self._sub
        fx, fy = self._fx[self._rows], self._fy[self._cols]
        rx, ry = P.sum(axis=1), P.sum(axis=0)
        mx, my = fx.T @ rx / E, fy.T @ ry / E
        dx, dy = fx - mx, fy - my
        cxx = (dx * rx[:, None]).T @ dx / E
        cyy = (dy * ry[:, None]).T @ dy / E
        cxy = dx.T @ (P @ dy) / E
        mean = np.array([mx[0], mx[1], my[0], my[1]])
        cov = np.zeros((4, 4))
        cov[0:2, 0:2], cov[2:4, 2:4], cov[0:2, 2:4] = cxx, cyy, cxy
        cov[2:4, 0:2] = cxy.T
        return E, mean, cov

    def density(self) -> np.ndarray:
        """The full density ``(S_x, S_y)`` (zeros off the support; ``O(S_x S_y)``: tests
        and plots)."""
        P = np.zeros((self._ax.size, self._ay.size))
        P[np.ix_(self._rows, self._cols)] = self._sub
        return P

    def estimate(self) -> Estimate:
        E, mean, cov = self.posterior_moments()
        if E < 0.5:
            return Estimate(E, np.zeros((0, 4)), np.zeros((0, 4, 4)), np.zeros(0, np.int64))
        return Estimate(E, mean[None], cov[None], np.zeros(1, np.int64))

    @classmethod
    def resource_terms(cls, params, model, looks_per_step, targets) -> ResourceTerms:
        """The density and two temporaries (8 B per node each), the transitions (~40
        entries per node and axis, 16 B each); ~30 ns per node and step (measured on
        single-clean: 0.6 M nodes in ~30 ms, 9.7 M in ~0.5-0.8 s); a dense ``P_c(t)``. A
        model whose grid exceeds ``max_states`` nodes is refused at once: nothing."""
        cap = param_number(params, "max_states", 20_000_000)
        try:
            sx, sy = grid_size(model, param_number(params, "spacing", 1.0) or 1.0,
                               param_number(params, "velocity_sds", 4.0),
                               param_number(params, "horizon", 50.0))
        except (ValueError, ZeroDivisionError, OverflowError):
            return ResourceTerms(prediction_counts=2.0)
        nodes = float(sx) * float(sy)
        if nodes > cap:
            return ResourceTerms(prediction_counts=2.0)
        return ResourceTerms(state_bytes=nodes * 24 + (sx + sy) * 40 * 16,
                             step_seconds=nodes * 3e-8,
                             prediction_entries=float(model.grid.n_cells),
                             prediction_counts=2.0)

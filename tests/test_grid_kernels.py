"""The grid arithmetic's numba kernels (``trackers/grid_kernels.py``) against the numpy
forms they replace, bit for bit: each kernel on random inputs (NaN and infinite box
edges, degenerate and very narrow Gaussians, boxes larger than the looks), and whole
runs of the trackers that use them (GPF, pmb, KF-NN), per step a digest of every array
of the tracker's state and of the estimate. Each comparison picks the backend with
``use_backend``, so ``MTTBENCH_NO_NUMBA`` does not matter here.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from mttbench import scenarios
from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.policies import AllCells
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.scenarios.model import Grid, RayleighGridSensor
from mttbench.trackers import cell_evidence, cells, grid_backend
from mttbench.trackers.cells import CellField
from mttbench.trackers.gpf import grid as gpf_grid
from mttbench.trackers.jmpd import use_backend
from mttbench.trackers.pmb import ppp

pytest.importorskip("mttbench.trackers.grid_kernels", reason="numba is not installed")


@pytest.fixture(autouse=True, scope="module")
def _gpf_kernels_loaded():
    """The GPF's kernels load in a thread (:func:`.grid_backend.compiled_gpf_kernels`);
    here they must be in before any comparison, or both sides would run numpy."""
    with use_backend("compiled"):
        assert grid_backend.compiled_gpf_kernels(wait=None) is not None


def _both(f):
    """``f()`` with the numpy forms, then with the kernels."""
    out = []
    for backend in ("numpy", "compiled"):
        with use_backend(backend):
            out.append(f())
    return out


def _equal(a, b) -> bool:
    if isinstance(a, tuple | list):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b, strict=True))
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


def _gaussians(rng, n: int, sd_range: tuple[float, float], spread: float):
    sd = np.exp(rng.uniform(np.log(sd_range[0]), np.log(sd_range[1]), (n, 2)))
    rho = rng.uniform(-0.99, 0.99, n)
    cov = np.empty((n, 2, 2))
    cov[:, 0, 0], cov[:, 1, 1] = sd[:, 0] ** 2, sd[:, 1] ** 2
    cov[:, 0, 1] = cov[:, 1, 0] = rho * sd[:, 0] * sd[:, 1]
    mean = rng.uniform(-3.0, spread, (n, 2))
    return mean, cov


def test_rect_position_moments_equal_the_numpy_form():
    """Every Gauss-Legendre order (8 to 24 nodes, by difficulty), from Gaussians a
    hundredth of a cell wide to 8 cells, correlations up to 0.99."""
    rng = np.random.default_rng(0)
    mean, cov = _gaussians(rng, 3000, (0.01, 8.0), 6.0)
    x0, y0 = np.floor(rng.uniform(-3, 5, (2, 3000)))
    got = _both(lambda: gpf_grid.rect_position_moments(mean, cov, x0, x0 + 1, y0, y0 + 1))
    assert _equal(*got)
    # every rule was used: the difficulty of each pair, as the docstring defines it
    sx, k = np.sqrt(cov[:, 0, 0]), cov[:, 0, 1] / cov[:, 0, 0]
    s = np.sqrt(np.maximum(cov[:, 1, 1] - cov[:, 0, 1] * k, 1e-24))
    length = np.maximum(np.minimum(x0 + 1 - mean[:, 0], 7 * sx)
                        - np.maximum(x0 - mean[:, 0], -7 * sx), 0.0)
    difficulty = length * np.maximum(1.0 / sx, np.abs(k) / s)
    bounds = [b for b, _ in gpf_grid._GL_ORDERS]
    assert len(np.unique(np.searchsorted(bounds, difficulty, side="right"))) == len(bounds)


def test_rect_position_moments_shared_edges_equal_the_numpy_form():
    """A wide Gaussian meets many looked cells, row after row, and the kernel shares a
    column's nodes and the edge between a cell and the one below it: blocks of cells in
    row order with gaps, one Gaussian's block split by another's (a new run), a signed
    zero at a shared edge, NaN and infinite y edges (a NaN x edge has no rule in the
    numpy form), equal to the numpy form bit for bit; and the blocks do share (most
    pairs' lower edge is the upper edge of the pair before them in their column)."""
    from mttbench.trackers import grid_kernels

    rng = np.random.default_rng(7)
    mean, cov = _gaussians(rng, 8, (0.3, 6.0), 4.0)
    rows = []  # (gaussian, x0, x1, y0, y1)
    for g in range(8):
        ax, ay = rng.integers(-4, 4, 2)
        for iy in range(ay, ay + 7):
            for ix in range(ax, ax + 6):
                if rng.random() < 0.8:  # a gap now and then
                    rows.append((g, float(ix), ix + 1.0, float(iy), iy + 1.0))
    rows.insert(len(rows) // 2, (3, 0.0, 1.0, 0.0, 1.0))  # splits a block: a new run
    rows += [(0, 0.0, 1.0, -1.0, -0.0), (0, 0.0, 1.0, 0.0, 1.0),  # -0.0 then 0.0
             (0, -0.0, 1.0, 1.0, 2.0), (0, 0.0, 1.0, 2.0, np.inf), (0, 0.0, 1.0, np.inf, 3.0),
             (0, 0.0, 1.0, np.nan, 4.0), (0, 0.0, 1.0, 4.0, 5.0)]
    g = np.array([r[0] for r in rows])
    x0, x1, y0, y1 = (np.array([r[i] for r in rows]) for i in range(1, 5))
    got = _both(lambda: gpf_grid.rect_position_moments(mean[g], cov[g], x0, x1, y0, y1))
    assert _equal(*got)
    run, col, _ = grid_kernels._columns(mean[g], cov[g], x0, x1)
    below = {}
    shared = 0
    for p in range(len(rows)):
        key = (run[p], col[p])
        shared += below.get(key) == y0[p]
        below[key] = y1[p]
    assert shared > len(rows) / 2, (shared, len(rows))
    assert len(np.unique(run)) >= 10  # the split block, and the eight others


def test_rect_position_moments_follow_patched_rules(monkeypatch):
    """The kernel reads the module's rules when called (a test may patch them)."""
    monkeypatch.setattr(gpf_grid, "_GL_ORDERS", ((np.inf, 96),))
    monkeypatch.setattr(gpf_grid, "_GL_RULES", {96: np.polynomial.legendre.leggauss(96)})
    rng = np.random.default_rng(1)
    mean, cov = _gaussians(rng, 200, (0.1, 4.0), 3.0)
    zero, one = np.zeros(200), np.ones(200)
    assert _equal(*_both(lambda: gpf_grid.rect_position_moments(mean, cov, zero, one,
                                                                 zero, one)))


def _random_boxes(rng, nx: int, ny: int, k: int) -> list[np.ndarray]:
    lo = rng.uniform(-10, 50, (2, k))
    width = rng.uniform(-3, 30, (2, k))
    edges = [np.floor(lo[0]), np.floor(lo[0] + width[0]), np.floor(lo[1]),
             np.floor(lo[1] + width[1])]
    for e in edges:  # NaN and infinite bounds
        e[rng.random(k) < 0.05] = np.nan
        e[rng.random(k) < 0.03] = np.inf
        e[rng.random(k) < 0.03] = -np.inf
    return edges


def test_looked_in_boxes_equals_the_numpy_form():
    rng = np.random.default_rng(2)
    for _ in range(300):
        nx, ny = (int(v) for v in rng.integers(1, 40, 2))
        looked = np.unique(rng.integers(0, nx * ny, rng.integers(0, 60)))
        edges = _random_boxes(rng, nx, ny, int(rng.integers(0, 30)))
        want = cells.looked_in_boxes(*edges, looked, nx, ny)
        with use_backend("compiled"):
            got = grid_backend.looked_in_boxes(*edges, looked, nx, ny)
        assert _equal(want, got)


def test_cell_evidence_equals_the_numpy_form():
    rng = np.random.default_rng(3)
    for _ in range(300):
        nx, ny = (int(v) for v in rng.integers(2, 30, 2))
        grid = Grid(nx, ny, float(rng.choice([1.0, 0.5, 2.0])))
        k = int(rng.integers(0, 15))
        mean, cov = _gaussians(rng, k, (0.02, 7.0), max(nx, ny) * grid.cell_size + 2)
        if k:
            cov[0] = 0.0  # degenerate: the sd floor
        looks = rng.integers(0, nx * ny, rng.integers(0, 80))
        looked, _, det, log_r = cell_evidence.looked_log_ratios(
            looks, rng.random(len(looks)) < 0.2, 6.9, -0.6)
        n_rows = min(k, len(det))
        rows = rng.choice(k, n_rows, replace=False) if n_rows else np.zeros(0, np.int64)
        args = (grid, mean, cov, looked, log_r, det, rows, det[:n_rows])
        assert _equal(*_both(lambda args=args: cell_evidence.cell_evidence(*args)))


def test_recycling_equals_the_numpy_form():
    """Overlapping boxes (sums per cell in the Gaussians' order), boxes beyond the
    grid, a zero variance."""
    rng = np.random.default_rng(4)
    for _ in range(300):
        nx, ny = (int(v) for v in rng.integers(1, 40, 2))
        grid = Grid(nx, ny, float(rng.choice([1.0, 0.5, 3.0])))
        k = int(rng.integers(0, 6))
        m = np.zeros((k, 4))
        m[:, [0, 2]] = rng.uniform(-5, max(nx, ny) * grid.cell_size + 5, (k, 2))
        sd = np.exp(rng.uniform(-5, 2.5, (k, 2))) * grid.cell_size
        P = np.tile(np.eye(4), (k, 1, 1))
        P[:, 0, 0], P[:, 2, 2] = sd[:, 0] ** 2, sd[:, 1] ** 2
        P[:, 0, 2] = P[:, 2, 0] = 0.3 * sd[:, 0] * sd[:, 1]
        if k:
            P[0, 0, 0] = 0.0
        r = rng.random(k)

        def field(m=m, P=P, r=r, grid=grid):
            f = CellField(grid.n_cells, 0.01)
            f.set(np.array([0]), np.array([0.2]))
            ppp.recycle(f, grid, r, m, P)
            return f.default, f.cells, f.values

        assert _equal(*_both(field))


def test_looked_log_ratios_equal_the_numpy_form():
    """Repeated looks at a cell, every one positive or none, no looks; the ratios of a
    sensor with p_d = 1 (``log_neg = -inf``: NaN where every look of a cell was
    positive) and p_f = 0 (``log_pos`` beyond the clip)."""
    rng = np.random.default_rng(5)
    ratios = [(6.9, -0.6), (0.3, -0.01), (np.log(0.9) - np.log(5e-324), -2.3),
              (2.0, -np.inf), (np.inf, -1.0)]
    n_nan = n_clipped = 0
    for trial in range(400):
        n_cells = int(rng.integers(1, 60))
        looks = rng.integers(0, n_cells, int(rng.integers(0, 120)))
        returns = rng.random(len(looks)) < rng.choice([0.0, 0.2, 0.9, 1.0])
        log_pos, log_neg = ratios[trial % len(ratios)]

        def ratios_of(looks=looks, returns=returns, a=log_pos, b=log_neg):
            with np.errstate(invalid="ignore"):  # 0 * -inf
                return cell_evidence.looked_log_ratios(looks, returns, a, b)

        want, got = _both(ratios_of)
        assert _equal(want, got)
        n_nan += int(np.isnan(want[3]).sum())
        n_clipped += int((want[3] == 700.0).sum())
    assert n_nan > 0 and n_clipped > 0  # both special cases met


def test_look_log_ratios_equal_the_numpy_form():
    """Up to four looks at a cell (their rows summed in look order: with three or more
    the order matters), every look positive or none, t_max 1 to 6, no looks; sensors
    whose p_f is tiny (a large ``log l``) and whose p_d is near 1."""
    rng = np.random.default_rng(8)
    sensors = [RayleighGridSensor(p_d=0.5, snr=10.0), RayleighGridSensor(p_d=0.9, snr=2.0),
               RayleighGridSensor(p_d=0.999, snr=40.0)]
    repeats = 0
    for trial in range(300):
        n_cells = int(rng.integers(1, 40))
        looks = rng.integers(0, n_cells, int(rng.integers(0, 4 * n_cells)))
        returns = rng.random(len(looks)) < rng.choice([0.0, 0.3, 1.0])
        sensor, t_max = sensors[trial % 3], int(rng.integers(1, 7))
        want, got = _both(lambda s=sensor, c=looks, r=returns, t=t_max:
                          cells.look_log_ratios(s, c, r, t))
        assert _equal(want, got) and want[1].dtype == float
        repeats += int((np.bincount(looks, minlength=1) >= 3).sum())
    assert repeats > 50


def test_unique_inverse_equals_numpys():
    """Many repeats (the kernel's sort is not stable: equal keys in any order must give
    the same two arrays), a single key, none."""
    from mttbench.trackers.numba_exact import unique_inverse

    rng = np.random.default_rng(7)
    for n in [0, 1, *rng.integers(2, 300, 200)]:
        key = rng.integers(-5, int(rng.integers(1, 40)), n)
        uniq, inv = unique_inverse(key)
        want_u, want_inv = np.unique(key, return_inverse=True)
        assert _equal((uniq, inv), (want_u, want_inv.reshape(-1).astype(np.int64)))


def test_adding_intensity_equals_the_numpy_form():
    """Repeated cells (their amounts summed in the order given, from tiny to huge), cells
    the field holds and new ones, an amount that brings a cell back to the default."""
    rng = np.random.default_rng(6)
    for _ in range(400):
        n = int(rng.integers(1, 200))
        cells = rng.integers(0, 40, n)
        amounts = rng.choice([1.0, -1.0], n) * np.exp(rng.uniform(-30, 30, n))
        amounts[rng.random(n) < 0.1] = 0.0

        def field(cells=cells, amounts=amounts):
            f = CellField(50, 0.5)
            f.set(np.array([3, 7, 20]), np.array([0.2, 0.7, 1e-9]))
            ppp.add_intensity(f, cells, amounts)
            ppp.add_intensity(f, np.array([3]), np.array([0.5 - f.at(np.array([3]))[0]]))
            return f.default, f.cells, f.values

        assert _equal(*_both(field))
    with use_backend("compiled"), pytest.raises(ValueError, match="2 amounts for 3 cells"):
        ppp.add_intensity(CellField(5, 0.0), np.array([0, 1, 1]), np.array([1.0, 2.0]))


def test_field_affine_equals_the_numpy_form():
    """``x <- a x + b`` on sparse fields: cells that round onto the new default (they
    rejoin it), ``a = 0`` (every cell rejoins), a NaN cell, an empty field."""
    rng = np.random.default_rng(7)
    for trial in range(300):
        a = float(rng.choice([0.0, 1.0, 0.999, 1e-300, rng.uniform(0.5, 1.0)]))
        b = float(rng.choice([0.0, 1e-4, 1e-20, rng.uniform(0.0, 0.1)]))
        own = np.unique(rng.integers(0, 60, int(rng.integers(0, 25))))
        values = 0.25 + rng.choice([1e-17, 5e-17, 1e-3, 0.5, -0.25], len(own))
        if trial % 10 == 0 and len(own):
            values[0] = np.nan

        def field(own=own, values=values, a=a, b=b):
            f = CellField(60, 0.25)
            f.set(own, values)
            f.affine(a, b)
            return np.array([f.default]), f.cells, f.values

        assert _equal(*_both(field))


def _observed(tracker) -> list[np.ndarray]:
    """The arrays a tracker's next step reads (its private state, by name)."""
    out = []
    for name in sorted(vars(tracker)):
        value = getattr(tracker, name)
        if isinstance(value, np.ndarray):
            out.append(value)
        elif isinstance(value, CellField):
            out += [np.array([value.default]), value.cells, value.values]
    return out


def _digests(scenario: str, spec: str, steps: int, policy=None) -> list[str]:
    out = []
    tracker = TrackerSpec.parse(spec).make()
    for rec in play(scenarios.get(scenario), tracker, 0, policy=policy, n_steps=steps):
        digest = hashlib.sha256()
        for a in _observed(tracker) + [rec.estimate.states, np.array([rec.estimate.count])]:
            digest.update(np.ascontiguousarray(a).tobytes())
        out.append(digest.hexdigest())
    return out


#: (scenario, tracker, steps, every cell looked at): walls that reflect (``default``,
#: ``crossing``: clusters) and kill (``births``), the larger grid (``large``)
RUNS = [("default", "gpf", 25, False), ("crossing", "gpf", 50, True),
        ("births", "gpf", 25, False), ("large", "gpf", 12, False),
        ("default", "pmb", 25, False), ("large", "pmb", 12, False),
        ("default", "kfnn", 30, True), ("large", "kfnn", 25, False),
        ("default", "gpf:max_components=1", 20, False)]


@pytest.mark.parametrize(("scenario", "spec", "steps", "all_cells"), RUNS,
                         ids=[f"{s}-{t}" for s, t, _, _ in RUNS])
def test_runs_are_identical_with_and_without_kernels(scenario, spec, steps, all_cells):
    policy = AllCells() if all_cells else None
    numpy_run, compiled_run = _both(lambda: _digests(scenario, spec, steps, policy))
    assert numpy_run == compiled_run

"""The GPF's compiled passes (``trackers/gpf/update_kernels.py``) against the numpy forms
they replace, bit for bit, on random inputs: the grid update's two passes (components,
birth candidates, splits, clusters, degenerate and far-away Gaussians, existence 0 and
1), the merge (both weight rules, groups, the Bhattacharyya form, coincident Gaussians),
the position regression and the wall test, the undetected field's passes, the birth
candidates and the merge's distances (``step_kernels.py``). Whole runs:
``tests/test_grid_kernels.py``. Each comparison picks the backend with ``use_backend``.
"""

from __future__ import annotations

import numpy as np
import pytest

from mttbench.scenarios.model import Grid, RayleighGridSensor
from mttbench.trackers import grid_backend, kalman
from mttbench.trackers.cells import CellField
from mttbench.trackers.gpf import grid as gpf_grid
from mttbench.trackers.gpf import tracker as gpf_tracker
from mttbench.trackers.jmpd import use_backend

pytest.importorskip("mttbench.trackers.grid_kernels", reason="numba is not installed")


@pytest.fixture(autouse=True, scope="module")
def _gpf_kernels_loaded():
    """The GPF's kernels load in a thread (:func:`.grid_backend.compiled_gpf_kernels`);
    here they must be in before any comparison, or both sides would run numpy."""
    with use_backend("compiled"):
        assert grid_backend.compiled_gpf_kernels(wait=None) is not None


def _both(f, *args, **kwargs):
    """``f(*args, **kwargs)`` with the numpy forms, then with the kernels."""
    out = []
    for backend in ("numpy", "compiled"):
        with use_backend(backend):
            out.append(f(*args, **kwargs))
    return out


def _equal(a, b) -> bool:
    if isinstance(a, tuple | list):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b, strict=True))
    if a is None or b is None:
        return a is b
    a, b = np.asarray(a), np.asarray(b)
    # bytes, so that -0.0 and 0.0 (and NaN payloads) count as different
    return (a.dtype == b.dtype and a.shape == b.shape
            and np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes())


def _states(rng, n: int, extent: float) -> tuple[np.ndarray, np.ndarray]:
    """``n`` random states and covariances: position sds from 0.02 to 6 cells, position
    and velocity correlated, some degenerate (zero variance), some far outside."""
    A = rng.normal(size=(n, 4, 4)) * np.exp(rng.uniform(-4.0, 1.8, (n, 1, 1)))
    P = A @ np.swapaxes(A, -1, -2) + 1e-9 * np.eye(4)
    m = np.zeros((n, 4))
    m[:, [0, 2]] = rng.uniform(-2.0, extent + 2.0, (n, 2))
    m[:, [1, 3]] = rng.normal(size=(n, 2))
    if n > 3:
        P[0, 0, :] = P[0, :, 0] = 0.0  # no x variance
        m[1, [0, 2]] = -50.0  # far outside the grid
        P[2, [1, 3], :] = P[2, :, [1, 3]] = 0.0  # no position-velocity correlation
    return m, P


def _update_case(rng):
    """A grid update's inputs: tracks with 1-3 Gaussian rows, birth candidates on looked
    cells, looks with repeats and returns."""
    nx, ny = (int(v) for v in rng.integers(4, 14, 2))
    grid = Grid(nx, ny, float(rng.choice([1.0, 0.5, 2.0])))
    sensor = RayleighGridSensor(p_d=float(rng.uniform(0.3, 0.9)), snr=float(rng.uniform(2, 20)))
    T = int(rng.integers(1, 7))
    n_rows = rng.integers(1, 4, T)
    own = np.repeat(np.arange(T), n_rows)
    m, P = _states(rng, len(own), nx * grid.cell_size)
    alpha = rng.random(len(own)) + 0.01
    alpha /= np.bincount(own, weights=alpha)[own]
    cells = rng.integers(0, nx * ny, int(rng.integers(1, 40)))
    returns = rng.random(len(cells)) < 0.4
    # birth candidates: each on a distinct looked cell, alone in its track
    cand = rng.permutation(np.unique(cells))[: int(rng.integers(0, 6))]
    w = np.concatenate([rng.uniform(0.0, 1.0, T), rng.uniform(0.0, 0.2, len(cand))])
    w[rng.random(len(w)) < 0.1] = 1.0
    w[rng.random(len(w)) < 0.05] = 0.0
    m = np.concatenate([m, np.zeros((len(cand), 4))])
    P = np.concatenate([P, np.repeat(np.eye(4)[None], len(cand), axis=0)])
    own = np.concatenate([own, T + np.arange(len(cand))])
    alpha = np.concatenate([alpha, np.ones(len(cand))])
    ucell = np.concatenate([np.full(len(own) - len(cand), -1), cand])
    return w, m, P, ucell, cells, returns, grid, sensor, own, alpha


@pytest.mark.parametrize("split_share", [0.0, 0.05, 0.2])
def test_grid_update_equals_the_numpy_form(split_share):
    """The two passes and the combinatorics between them, whole: every output, on 150
    random updates (clusters, splits and singletons; counted, so that each occurs)."""
    rng = np.random.default_rng(int(split_share * 10))
    seen = {"clusters": 0, "splits": 0}
    for _ in range(150):
        w, m, P, ucell, cells, returns, grid, sensor, own, alpha = _update_case(rng)
        got = _both(gpf_grid.grid_update, w, m, P, ucell, cells, returns, grid, sensor,
                    owner=own, alpha=alpha, split_share=split_share)
        a, b = got
        assert _equal([a.weights, a.means, a.covs, a.alpha, a.owner],
                      [b.weights, b.means, b.covs, b.alpha, b.owner])
        assert (a.dropped, a.n_clusters, a.max_cluster) == (b.dropped, b.n_clusters,
                                                             b.max_cluster)
        seen["clusters"] += a.n_clusters > 0
        seen["splits"] += len(a.owner) > len(own)
    assert seen["clusters"] >= 10
    assert (seen["splits"] >= 5) == (split_share > 0)


def test_the_passes_equal_their_numpy_forms():
    """Each pass's outputs (the intermediate arrays, not only the update's result)."""
    from mttbench.trackers.gpf import update_kernels as uk
    rng = np.random.default_rng(11)
    for _ in range(100):
        w, m, P, ucell, cells, returns, grid, sensor, own, alpha = _update_case(rng)
        U = np.unique(cells)
        hit = np.zeros(len(U), dtype=bool)
        hit[np.searchsorted(U, cells[returns])] = True
        want = gpf_grid._pairs_and_singletons(w, m, P, ucell, own, alpha, U, hit, cells,
                                              returns, grid, sensor, 1e-3, 6.0)
        ll_pos, ll_neg = gpf_grid._one_target_ratios(sensor)
        got = uk.pairs_and_singletons(w, m, P, ucell, own, alpha, U, hit, cells, returns,
                                      ll_pos, ll_neg, grid.cell_size, grid.nx, grid.ny,
                                      1e-3, 6.0, *gpf_grid._gl_table())
        # LL1's column 0 (T = 0) is read by nobody; numpy's is exactly zero as well
        assert _equal(list(want), [*got[:11], got[11], *got[12:]])
        ri_g, pu_g, mass_g, p1_g, p2_g, pi, pu, pair_of = want[:8]
        w_new, g_out, g_pair = want[15:18]
        B, resid = gpf_grid.position_regression(P)
        for share in (0.0, 0.1):
            args = (ri_g, pu_g, mass_g, p1_g, p2_g, pair_of, g_pair, g_out, w_new, own,
                    alpha, ucell < 0, hit, m, P, B, resid, len(w), share)
            assert _equal(list(gpf_grid._moment_match(*args)), list(uk.moment_match(*args)))


def test_a_uniform_row_off_the_looks_is_refused_by_both():
    rng = np.random.default_rng(5)
    w, m, P, ucell, cells, returns, grid, sensor, own, alpha = _update_case(rng)
    ucell = np.concatenate([ucell, [grid.n_cells - 1 if grid.n_cells - 1 not in cells
                                    else -1]])
    if ucell[-1] < 0:
        pytest.skip("every cell looked at")
    w = np.concatenate([w, [0.1]])
    m, P = np.concatenate([m, m[:1]]), np.concatenate([P, P[:1]])
    own, alpha = np.concatenate([own, [len(w) - 1]]), np.concatenate([alpha, [1.0]])
    for backend in ("numpy", "compiled"):
        with use_backend(backend), pytest.raises(ValueError, match="uniform particle"):
            gpf_grid.grid_update(w, m, P, ucell, cells, returns, grid, sensor, owner=own,
                                 alpha=alpha)


@pytest.mark.parametrize("rule", ["bounded_sum", "capped_sum"])
@pytest.mark.parametrize("metric", ["mahalanobis", "bhattacharyya"])
def test_merge_equals_the_numpy_form(rule, metric):
    """Clusters of nearby Gaussians (so that groups form), coincident ones (ties in the
    distance), weights summing beyond 1, a NaN covariance, and groups of components."""
    rng = np.random.default_rng(hash((rule, metric)) % 2**32)
    merged = 0
    for _ in range(150):
        K = int(rng.integers(1, 12))
        m, P = _states(rng, K, 4.0)
        m[:, [0, 2]] = rng.uniform(0.0, 3.0, (K, 2))
        if K > 4:
            m[4], P[4] = m[3], P[3]  # coincident
        if K > 6 and rng.random() < 0.3:
            P[6, 0, 0] = np.nan
        w = rng.uniform(0.0, 1.0, K)
        groups = rng.integers(0, 3, K) if rng.random() < 0.5 else None
        threshold = float(rng.choice([1.0, 4.0, 16.0]))
        a, b = _both(gpf_tracker.merge_groups, w, m, P, threshold, rule, metric, groups)
        assert _equal(list(a), list(b))
        merged += len(a[0]) < K
    assert merged >= 30


@pytest.mark.parametrize("metric", ["mahalanobis", "bhattacharyya"])
def test_pair_distances_equal_the_numpy_form_and_lapack(metric):
    """The merge's distances: both forms bit for bit (a NaN covariance and one that is not
    positive definite included), and against LAPACK's solve and ``slogdet`` (an
    independent method) within 1e-9 relative where the screen let a pair through."""
    rng = np.random.default_rng(17 if metric == "mahalanobis" else 18)
    checked = 0
    for _ in range(150):
        K = int(rng.integers(1, 14))
        m, P = _states(rng, K, 4.0)
        m[:, [0, 2]] = rng.uniform(0.0, 3.0, (K, 2))
        if K > 6 and rng.random() < 0.3:
            P[6, 0, 0] = np.nan
        if K > 7 and rng.random() < 0.3:
            P[7] = -P[7]  # negative definite: not a covariance, no distance
        groups = rng.integers(0, 3, K) if rng.random() < 0.5 else None
        threshold = float(rng.choice([1.0, 4.0, 16.0]))
        want, got = _both(gpf_tracker._pair_distances, m, P, threshold, metric, groups)
        assert _equal(want, got)
        i, j = np.nonzero(np.isfinite(want))
        ok = np.isfinite(P[i]).all(axis=(1, 2)) & np.isfinite(P[j]).all(axis=(1, 2))
        ok &= (np.linalg.eigvalsh(np.nan_to_num(P[i])) > 0).all(axis=1)
        ok &= (np.linalg.eigvalsh(np.nan_to_num(P[j])) > 0).all(axis=1)
        i, j = i[ok], j[ok]
        d, S = m[i] - m[j], P[i] + P[j]
        ref = np.einsum("ka,ka->k", d, np.linalg.solve(S, d[..., None])[..., 0])
        if metric == "bhattacharyya":
            ref = ref + np.maximum(2.0 * np.linalg.slogdet(0.5 * S)[1]
                                   - np.linalg.slogdet(P[i])[1] - np.linalg.slogdet(P[j])[1],
                                   0.0)
        np.testing.assert_allclose(want[i, j], ref, rtol=1e-9, atol=1e-12)
        assert np.array_equal(want, want.T, equal_nan=True)
        checked += len(i)
    assert checked > 200


@pytest.mark.parametrize("max_components", [2, 3, 8])
def test_reducing_components_equals_the_numpy_form(max_components):
    """A track's components: those below the floor dropped (the heaviest kept; one at
    the floor kept), merged on Bhattacharyya distances within the track, the lightest
    beyond ``max_components`` moment-matched; tied weights, tracks of one row, a track of
    weights 0, no merging (threshold 0)."""
    rng = np.random.default_rng(31 + max_components)
    tracker = gpf_tracker.GaussianParticleFilter(max_components=max_components)
    capped = merged = 0
    for _ in range(150):
        T, R = int(rng.integers(1, 6)), int(rng.integers(1, 30))
        own = np.sort(np.concatenate([np.arange(T), rng.integers(0, T, R)]))
        a = rng.uniform(0.0, 1.0, len(own)) ** 3  # some below the floor
        a[rng.random(len(own)) < 0.2] = 0.25  # ties
        a[rng.random(len(own)) < 0.1] = 0.02  # at the floor: kept
        if rng.random() < 0.2:
            a[own == own[0]] = 0.0  # a track whose weights all underflowed
        m, P = _states(rng, len(own), 3.0)
        m = m[: len(own)]
        P = P[: len(own)]
        m[:, [0, 2]] = rng.uniform(0.0, 2.0, (len(own), 2))
        tracker.merge_threshold = float(rng.choice([0.0, 4.0, 16.0]))
        want, got = _both(tracker._reduce_components, own, a, m, P, T)
        assert _equal(list(want), list(got))
        assert np.isfinite(want[1]).all()  # weight 1 where a track's sum is 0
        capped += int(np.bincount(want[0], minlength=T).max() == max_components)
        merged += len(want[0]) < int((a >= 0.02).sum())
    assert capped > 10 and merged > 10


def test_position_regression_and_the_fold_equal_the_numpy_forms():
    rng = np.random.default_rng(7)
    m, P = _states(rng, 500, 10.0)
    P[3, 0, 0] = P[3, 2, 2] = 0.0  # singular position block
    assert _equal(*_both(gpf_grid.position_regression, P))
    # the fold's quadrature needs an x variance (row 0 has none, row 3 a singular block)
    m, P = np.delete(m, [0, 3], axis=0), np.delete(P, [0, 3], axis=0)
    grid = Grid(10, 10, 1.0)
    got = _both(gpf_grid.fold_into_workspace, m, P, grid)
    assert _equal(*got)
    assert not np.array_equal(got[0][0], m)  # some Gaussians reached beyond a wall


def test_option_beliefs_equal_the_numpy_form():
    """Large clusters' beliefs: members sharing detected cells, options of probability 0,
    a member without detected cells, couplings to T = 1, 2 and 5."""
    rng = np.random.default_rng(13)
    for _ in range(200):
        n, n_opt = int(rng.integers(1, 9)), int(rng.integers(3, 8))
        probs = rng.random((n, n_opt)) * (rng.random((n, n_opt)) < 0.8)
        probs[:, 0] += 0.01
        probs /= probs.sum(axis=1, keepdims=True)
        n_u = int(rng.integers(1, 6))
        cell = np.where(rng.random((n, n_opt)) < 0.5, rng.integers(0, n_u, (n, n_opt)), -1)
        cell[:, :2] = -1
        if n > 1:
            cell[0] = -1
        t_max = int(rng.choice([1, 2, 5]))
        LLc = np.zeros((n_u, t_max + 1))
        LLc[:, 2:] = rng.normal(-3.0, 3.0, (n_u, t_max - 1))
        assert _equal(*_both(gpf_grid._option_beliefs, probs, cell, LLc))


def test_avoid_coalescence_equals_the_numpy_form():
    """Many combinations that differ only by which members took which detected cells
    (so that classes hold several), ties, ``-inf`` and NaN posteriors, padded members."""
    rng = np.random.default_rng(17)
    for _ in range(300):
        C, S, n_u = int(rng.integers(1, 60)), int(rng.integers(1, 6)), int(rng.integers(1, 5))
        cluster = np.sort(rng.integers(0, 3, C))
        choice = rng.integers(0, 4, (C, S))
        cell = np.where(rng.random((C, S)) < 0.6, rng.integers(0, n_u, (C, S)), -1)
        pad = rng.random((C, S)) < 0.1
        choice[pad], cell[pad] = -2, -2
        detected = rng.random(n_u) < 0.6
        log_post = np.round(rng.normal(size=C), 1)  # ties
        log_post[rng.random(C) < 0.1] = -np.inf
        log_post[rng.random(C) < 0.05] = np.nan
        got = _both(gpf_grid.avoid_coalescence, cluster, choice, cell, detected, log_post)
        assert _equal(*got)


def test_rect_state_moments_equal_the_numpy_form():
    """Rectangles of several Gaussians (owners repeated, unsorted), cells and the
    workspace, for the GPF's fold and truncation and pmb's update."""
    rng = np.random.default_rng(19)
    m, P = _states(rng, 60, 8.0)
    m, P = m[3:], P[3:]  # rows with an x variance and a regular position block
    owner = rng.integers(0, len(m), 400)
    x0, y0 = np.floor(rng.uniform(-2.0, 9.0, (2, 400)))
    assert _equal(*_both(gpf_grid.rect_state_moments, m, P, x0, x0 + 1.0, y0, y0 + 1.0,
                         owner))
    zero, wide = np.zeros(len(m)), np.full(len(m), 8.0)
    assert _equal(*_both(gpf_grid.rect_state_moments, m, P, zero, wide, zero, wide))


def _random_field(rng, n_cells: int) -> CellField:
    """A field with a default and some listed cells: values from 0 to 0.6, some equal to
    the default (they rejoin it after a map), exact zeros, now and then a NaN."""
    f = CellField(n_cells, float(rng.choice([0.0, 1e-4, rng.uniform(0.0, 0.3)])))
    k = int(rng.integers(0, min(n_cells, 40)))
    cells = np.sort(rng.choice(n_cells, k, replace=False))
    values = rng.uniform(0.0, 0.6, k)
    values[rng.random(k) < 0.2] = f.default
    values[rng.random(k) < 0.1] = 0.0
    if rng.random() < 0.05 and k:
        values[0] = np.nan
    f.cells, f.values = cells.astype(np.int64), values
    return f


def _field_equal(a: CellField, default: float, cells: np.ndarray, values: np.ndarray) -> bool:
    return (np.float64(a.default).tobytes() == np.float64(default).tobytes()
            and _equal(a.cells, cells) and _equal(a.values, values))


def test_the_fields_passes_equal_the_cellfield_forms():
    """``field_predict`` (the floor, the count bound's three cases) and ``field_set`` (with
    and without the floor, an empty set) against :class:`.CellField`'s maps and set, as
    the GPF's numpy form calls them."""
    K = grid_backend.compiled_gpf_kernels()
    rng = np.random.default_rng(23)
    cases = {"floor": 0, "scaled down": 0, "scaled up": 0, "uniform": 0}
    for _ in range(600):
        n_cells = int(rng.integers(1, 200))
        f = _random_field(rng, n_cells)
        p_s, b = float(rng.uniform(0.9, 1.0)), float(rng.choice([0.0, 1e-3 / n_cells]))
        floor = float(rng.choice([0.0, 1e-4, 0.05]))
        ref = f.copy()
        ref.map(lambda u, p_s=p_s, b=b: 1.0 - (1.0 - p_s * u) * (1.0 - b))
        if rng.random() < 0.5:
            ref.map(lambda u, floor=floor: np.maximum(u, floor))
            got = K.field_predict(f.default, f.cells, f.values, p_s, b, K.FLOOR, floor, 0.0,
                                  n_cells)
            cases["floor"] += 1
        else:
            total = ref.total()
            missing = float(rng.choice([0.0, total * rng.uniform(0.0, 2.0), 0.7]))
            if rng.random() < 0.1:  # an empty field: the uniform case
                f, ref = CellField(n_cells, 0.0), CellField(n_cells, 0.0)
                total = 0.0
            if missing < total:
                ref.map(lambda u, f=missing / total: u * f)
                cases["scaled down"] += 1
            elif total > 0:
                ref.map(lambda u, x=missing, t=total: np.minimum(x * (u / t), 0.5))
                cases["scaled up"] += 1
            else:
                ref = CellField(n_cells, min(missing * (1.0 / n_cells), 0.5))
                cases["uniform"] += 1
            got = K.field_predict(f.default, f.cells, f.values, p_s, b, K.RESPREAD, floor,
                                  missing, n_cells)
        assert _field_equal(ref, *got)
        # the update's set of the candidates' cells, then the floor (with arrivals)
        f = _random_field(rng, n_cells)
        n_s = int(rng.integers(0, min(n_cells, 12) + 1))
        set_cells = np.sort(rng.choice(n_cells, n_s, replace=False)).astype(np.int64)
        set_values = np.where(rng.random(n_s) < 0.3, 0.0, rng.uniform(0.0, 0.4, n_s))
        set_values[rng.random(n_s) < 0.2] = f.default
        apply_floor = bool(rng.random() < 0.5)
        ref = f.copy()
        ref.set(set_cells, set_values)
        if apply_floor:
            ref.map(lambda u, floor=floor: np.maximum(u, floor))
        got = K.field_set(f.default, f.cells, f.values, set_cells, set_values, floor,
                          apply_floor)
        assert _field_equal(ref, *got)
    assert min(cases.values()) >= 10, cases


def test_the_candidates_and_the_screen_equal_the_numpy_forms():
    """``candidates``: the distinct looked cells (repeats, unsorted), the field there, the
    birth candidates where it is above 0 and the tracks followed by them, as
    ``_update_grid_numpy`` builds them; ``any_close``: the merge's screen, in any order of
    the Gaussians."""
    K = grid_backend.compiled_gpf_kernels()
    rng = np.random.default_rng(29)
    grid = Grid(9, 7, 1.5)
    passed = 0
    for _ in range(300):
        f = _random_field(rng, grid.n_cells)
        looks = rng.integers(0, grid.n_cells, int(rng.integers(1, 30)))
        T = int(rng.integers(0, 5))
        own = np.sort(rng.integers(0, T, int(rng.integers(T, 2 * T + 1)))) if T else \
            np.zeros(0, np.int64)
        own[:T] = np.arange(T)  # every track has a row
        own = np.sort(own)
        R = len(own)
        m, P = _states(rng, R, 12.0)
        w, a = rng.uniform(0.0, 1.0, T), rng.uniform(0.0, 1.0, R)
        vs = float(rng.uniform(0.1, 2.0))
        births = bool(rng.random() < 0.8)
        got = K.candidates(looks, births, f.default, f.cells, f.values, w, own, a, m, P,
                           grid.cell_size, grid.nx, vs)
        looked = np.unique(looks)
        u = f.at(looked)
        cand = looked[u > 0.0] if births else looked[:0]
        n_c, s = len(cand), grid.cell_size
        cm = kalman.at_rest(grid.cell_centers(cand))
        cP = np.repeat(np.diag([s * s / 12.0, vs, s * s / 12.0, vs])[None], n_c, axis=0)
        want = (cand, f.at(cand), np.concatenate([w, f.at(cand)]),
                np.concatenate([own, T + np.arange(n_c)]), np.concatenate([a, np.ones(n_c)]),
                np.concatenate([m, cm]), np.concatenate([P, cP]),
                np.concatenate([np.full(R, -1, dtype=np.int64), cand]))
        assert _equal(list(got), list(want))
        # the screen, on clustered Gaussians so that some pairs pass
        k = int(rng.integers(0, 8))
        m, P = _states(rng, k, 4.0)
        thr = float(rng.choice([1.0, 4.0, 16.0]))
        iu, ju = np.triu_indices(k, 1)
        S, d = P[iu] + P[ju], m[iu] - m[ju]
        with np.errstate(divide="ignore", invalid="ignore"):
            lower = ((S[:, 2, 2] * d[:, 0] * d[:, 0] - 2.0 * S[:, 0, 2] * d[:, 0] * d[:, 2]
                      + S[:, 0, 0] * d[:, 2] * d[:, 2]) / (S[:, 0, 0] * S[:, 2, 2]
                                                          - S[:, 0, 2] * S[:, 0, 2]))
        want_close = bool(np.any(~(lower >= thr)))
        perm = rng.permutation(k)
        assert K.any_close(m, P, thr) is want_close
        assert K.any_close(m[perm].copy(), P[perm].copy(), thr) is want_close
        passed += want_close
    assert 30 <= passed <= 270


def test_the_estimates_rows_equal_the_numpy_form():
    """``heaviest``: the ``round_sum`` estimate's rows, ``argsort(-w, stable)[:n]``, with
    ties (equal weights, 0 and -0), NaN and every ``n``."""
    K = grid_backend.compiled_gpf_kernels()
    rng = np.random.default_rng(31)
    for _ in range(300):
        T = int(rng.integers(0, 40))
        w = np.round(rng.uniform(0.0, 1.0, T), int(rng.integers(1, 4)))
        w[rng.random(T) < 0.1] = -0.0
        w[rng.random(T) < 0.05] = np.nan
        m, P = rng.normal(size=(T, 4)), rng.normal(size=(T, 4, 4))
        tid = rng.permutation(T).astype(np.int64)
        n = int(rng.integers(0, T + 1))
        sel = np.argsort(-w, kind="stable")[:n]
        assert _equal(list(K.step_kernels.heaviest(w, n, m, P, tid)),
                      [m[sel], P[sel], tid[sel]])


def _cluster_case(rng, n: int, n_opt: int):
    """One large cluster's tilted options (absent, elsewhere, cells, missed), some of
    probability 0, some rounded so that combinations tie, and its coupling table."""
    probs = rng.random((n, n_opt)) * (rng.random((n, n_opt)) < 0.7)
    if rng.random() < 0.5:
        probs = np.round(probs, 1)  # equal options: ties in the priors and the bounds
    probs[:, 0] += 0.01
    probs /= probs.sum(axis=1, keepdims=True)
    n_u = int(rng.integers(1, 5))
    cell = np.where(rng.random((n, n_opt)) < 0.6, rng.integers(0, n_u, (n, n_opt)), -1)
    cell[:, :2] = -1
    cell[probs <= 0.0] = -1
    LLc = np.zeros((n_u, n + 1))
    LLc[:, 2:] = rng.normal(-4.0, 3.0, (n_u, n - 1))
    return probs, cell, LLc, rng.random(n_u) < 0.7


def test_the_enumeration_equals_the_numpy_form():
    """``enumerate_choices`` against :func:`.linear.enumerate_combinations` (choices in
    order and the dropped mass), with thresholds that drop everything, caps that bind,
    and ties at the cap (where the kernel must decline rather than guess)."""
    from mttbench.trackers.gpf import cluster_kernels as ck
    from mttbench.trackers.gpf.linear import _BLOCK, enumerate_combinations
    rng = np.random.default_rng(41)
    seen = {"capped": 0, "declined": 0, "nothing passes": 0}
    for _ in range(400):
        n, n_opt = int(rng.integers(1, 12)), int(rng.integers(2, 6))
        probs = _cluster_case(rng, n, n_opt)[0]
        eps = float(rng.choice([0.0, 1e-4, 1e-2, 0.5]))
        cap = int(rng.choice([1, 3, 16, 512]))
        want = enumerate_combinations(probs, eps, cap)
        choice, dropped, exact = ck.enumerate_choices(probs, eps, cap, _BLOCK)
        if not exact:
            seen["declined"] += 1
            continue
        assert _equal(choice, want.choice) and dropped == want.dropped
        seen["capped"] += len(want.choice) == cap and np.prod((probs > 0).sum(1)) > cap
        seen["nothing passes"] += eps > 0 and np.all(want.log_prior <= np.log(eps))
    assert min(seen.values()) >= 5, seen


def test_the_cluster_posterior_equals_the_numpy_form():
    """:func:`.grid._cluster_posterior` (beliefs, enumeration, exact posterior, JPDA*,
    cut) with the kernel and in numpy: the same posterior and dropped mass, bytes equal,
    over clusters of 2-14 members, caps that bind and ties."""
    rng = np.random.default_rng(43)
    for _ in range(300):
        n, n_opt = int(rng.integers(2, 15)), int(rng.integers(3, 7))
        probs, cell, LLc, detected = _cluster_case(rng, n, n_opt)
        eps = float(rng.choice([1e-4, 1e-3, 0.2]))
        cap = int(rng.choice([4, 64, 512]))
        got = _both(gpf_grid._cluster_posterior, probs, cell, LLc, eps, cap, detected)
        assert _equal(list(got[0]), list(got[1]))


def test_the_fold_equals_the_numpy_form_at_walls_and_corners():
    """:func:`.grid.fold_into_workspace` with the kernels and in numpy on Gaussians at the
    walls and corners (several images each), narrow ones far outside (no mass left: the
    prior, its position clipped; ``-0.0`` and NaN positions among them), broad ones
    (images on both sides), bytes equal."""
    rng = np.random.default_rng(47)
    seen = {"images": 0, "no mass": 0}
    for _ in range(60):
        grid = Grid(int(rng.integers(3, 12)), int(rng.integers(3, 12)),
                    float(rng.choice([0.5, 1.0, 2.0])))
        width, height = grid.extent
        n = int(rng.integers(1, 30))
        m, P = _states(rng, n, width)
        m[:, 2] = rng.uniform(-0.5, height + 0.5, n)
        corner = rng.random(n) < 0.3
        m[corner, 0] = rng.choice([0.0, width], corner.sum()) + rng.normal(0, 0.2, corner.sum())
        m[corner, 2] = rng.choice([0.0, height], corner.sum()) + rng.normal(0, 0.2, corner.sum())
        lost = rng.random(n) < 0.15  # far outside, narrow: nothing inside at all
        m[lost, 0] = rng.choice([-30.0, width + 30.0], lost.sum())
        P[lost] *= 1e-6
        if n > 5:
            m[4, 0], m[4, 2] = -0.0, -30.0
            m[5, 2] = np.nan
        got = _both(gpf_grid.fold_into_workspace, m, P, grid)
        assert _equal(*got)
        seen["images"] += int(np.sum(corner))
        seen["no mass"] += int(np.sum(got[0][0][lost, 0] != m[lost, 0]))
    assert min(seen.values()) >= 10, seen


def test_the_count_bound_equals_the_numpy_form():
    """:func:`.tracker.condition_on_count_bound` with the kernel and in numpy: bounds from
    1 to beyond the tracks, certain tracks (``w = 1``, the bound's probability 0) and
    impossible ones, one track, bytes equal."""
    rng = np.random.default_rng(53)
    for _ in range(300):
        T = int(rng.integers(1, 50))
        w = rng.random(T) ** rng.choice([0.2, 1.0, 5.0])
        w[rng.random(T) < 0.1] = 1.0
        w[rng.random(T) < 0.05] = 0.0
        n_max = int(rng.integers(0, T + 2))
        assert _equal(*_both(gpf_tracker.condition_on_count_bound, w, n_max))


def test_the_distinct_modes_equal_the_numpy_form():
    """The mixture estimate's rows (:meth:`._distinct_modes`) with the kernel and in
    numpy: tracks of 1-4 components on a few cells (so that the distance rule picks other
    rows), tied and NaN scores, NaN positions."""
    from types import SimpleNamespace
    rng = np.random.default_rng(59)
    for _ in range(300):
        T = int(rng.integers(1, 15))
        n_rows = rng.integers(1, 5, T)
        own = np.repeat(np.arange(T), n_rows)
        R = len(own)
        m = np.zeros((R, 4))
        m[:, [0, 2]] = rng.integers(0, 4, (R, 2)) + rng.choice([0.0, 0.3], (R, 2))
        m[rng.random(R) < 0.05, 0] = np.nan
        score = np.round(rng.random(R), 1)
        score[rng.random(R) < 0.05] = np.nan
        sel = rng.permutation(T)[: int(rng.integers(0, T + 1))]
        fake = SimpleNamespace(_own=own, _m=m, _w=np.ones(T), _grid=Grid(4, 4, 1.0))
        got = _both(gpf_tracker.GaussianParticleFilter._distinct_modes, fake, sel, score)
        assert _equal(*got)


def test_grid_update_with_large_clusters_equals_the_numpy_form():
    """The whole update with a small combination cap, so that most clusters take the
    large clusters' path (options, beliefs, enumeration under the cap, ``g``): every
    output equal, bytes, on 150 random updates."""
    rng = np.random.default_rng(61)
    n_large = 0
    for _ in range(150):
        w, m, P, ucell, cells, returns, grid, sensor, own, alpha = _update_case(rng)
        cap = int(rng.choice([2, 4, 8]))
        a, b = _both(gpf_grid.grid_update, w, m, P, ucell, cells, returns, grid, sensor,
                     max_combinations=cap, owner=own, alpha=alpha, split_share=0.05)
        assert _equal([a.weights, a.means, a.covs, a.alpha, a.owner],
                      [b.weights, b.means, b.covs, b.alpha, b.owner])
        assert (a.dropped, a.n_clusters, a.max_cluster) == (b.dropped, b.n_clusters,
                                                             b.max_cluster)
        n_large += a.max_cluster >= 3
    assert n_large >= 10


def test_collapse_equals_the_numpy_form():
    """:func:`.tracker.collapse` (each group's moment match) with the kernel and in numpy:
    groups in any order, empty groups, weights summing to 0 and NaN, bytes equal."""
    rng = np.random.default_rng(67)
    for _ in range(300):
        R, n = int(rng.integers(0, 30)), int(rng.integers(1, 8))
        owner = rng.integers(0, n, R)
        w = rng.random(R) * (rng.random(R) < 0.8)
        w[rng.random(R) < 0.03] = np.nan
        m, P = _states(rng, R, 10.0)
        assert _equal(*_both(gpf_tracker.collapse, w, m, P, owner, n))

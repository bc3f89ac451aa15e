"""``jmpd-ap``'s numba kernels (``trackers/jmpd/ap_kernels.py``) against the numpy forms.

Every comparison is exact (bit for bit): the kernels promise the same IEEE operations in
the same order, so a seed gives the same numbers with or without numba. Whole runs
compare everything a computation reads: the validity, the positions and velocity means
of the held slots, every velocity variance, the effective sample size and the estimates.
(The positions and velocity means of empty slots are never read; the compiled form
fills them differently: ``place``'s docstring.) Each run picks the backend with
``use_backend``, so ``MTTBENCH_NO_NUMBA`` does not matter here.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from mttbench import scenarios
from mttbench.benchmarks.engine.loop import play
from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.trackers.jmpd import JMPDAPTracker, use_backend
from mttbench.trackers.jmpd.cell_proposal import axis_window, truncated_normal
from mttbench.trackers.jmpd.likelihood import grid_log_likelihood_tables

ap_kernels = pytest.importorskip("mttbench.trackers.jmpd.ap_kernels",
                                 reason="numba is not installed")


def _observed(tr: JMPDAPTracker) -> list[np.ndarray]:
    """What later computations read of the tracker's state."""
    held = tr.valid[..., None]
    return [tr.valid, np.where(held, tr.pos, 0.0), np.where(held, tr.vel, 0.0), tr.vvar,
            np.array([tr.ess, tr.count_mean, tr.n_clusters, tr.largest_cluster])]


def _digests(scenario, n_particles: int, steps: int, compiled: bool, policy=None,
             **params) -> list[str]:
    """Per step, SHA-256 of :func:`_observed` and the estimate."""
    out = []
    with use_backend("compiled" if compiled else "numpy"):
        tr = JMPDAPTracker(n_particles=n_particles, **params)
        for rec in play(scenario, tr, 0, policy=policy, n_steps=steps):
            digest = hashlib.sha256()
            for a in _observed(tr) + [rec.estimate.states, np.array([rec.estimate.count])]:
                digest.update(np.ascontiguousarray(a).tobytes())
            out.append(digest.hexdigest())
        assert tr.uses_compiled_kernels == compiled
    return out


#: (scenario, particles, steps, tracker parameters): reflecting walls (``default``,
#: ``crossing``), walls where targets die and births (``births``, ``kreucher-50``), the
#: declared start (``kreucher``), false alarms in every look (``env-pf-0.1``: many births
#: and clusters), the look-all sensor on 2,500 cells, and a wide proposal window
RUNS = [("default", 300, 25, {}), ("births", 300, 40, {}), ("crossing", 300, 30, {}),
        ("kreucher", 300, 20, {"init_fraction": 0.1}), ("kreucher-50", 150, 10, {}),
        ("env-pf-0.1", 300, 25, {}), ("default", 200, 12, {"position_noise_floor": 0.3}),
        ("default", 100, 8, {"position_noise_floor": 1.2})]


@pytest.mark.parametrize(("name", "n", "steps", "params"), RUNS,
                         ids=[f"{r[0]}-{i}" for i, r in enumerate(RUNS)])
def test_runs_are_identical_with_and_without_kernels(name, n, steps, params):
    sc = scenarios.get(name) if not name.startswith("env-") else _envelope(name)
    numpy_run = _digests(sc, n, steps, False, **params)
    compiled_run = _digests(sc, n, steps, True, **params)
    assert compiled_run == numpy_run


def _envelope(name):
    from mttbench.benchmarks.engine.specs import resolve_scenarios
    return resolve_scenarios([name])[0]


def test_hashed_look_index_and_die_walls_are_identical():
    """A 300 x 300 grid (90,000 cells: the look index hashes instead of a direct table),
    targets that die at the walls, hand-made looks at the targets' cells and at random
    cells, some with returns."""
    grid = Grid(300, 300)
    model = TrackingModel(grid, Dynamics(wna_intensity=1e-3),
                          BirthDeath(initial_states=((299.2, 0.3, 150.5, 0.0),
                                                     (10.5, -0.1, 20.5, 0.1),
                                                     (11.5, 0.0, 21.0, -0.1)),
                                     boundary="die", birth_rate=0.1,
                                     survival_probability=0.99),
                          RayleighGridSensor())
    digests = []
    for compiled in (False, True):
        with use_backend("compiled" if compiled else "numpy"):
            tr = JMPDAPTracker(n_particles=300, init_fraction=0.5)
            tr.reset(model, np.random.default_rng(2))
            rng = np.random.default_rng(3)
            digest = hashlib.sha256()
            for k in range(10):
                tr.predict()
                P = tr.cell_count_distribution()
                truth = np.array([[150, 299 + k // 3], [20, 10], [21, 11]])
                cells = np.concatenate([truth[:, 0] * 300 + np.minimum(truth[:, 1], 299),
                                        rng.integers(0, grid.n_cells, 40)])
                returns = np.r_[[True, True, False], rng.random(40) < 0.05]
                tr.update(Looks(cells.astype(np.int64), returns))
                est = tr.estimate()
                for a in _observed(tr) + [est.states, P.cells, P.rows]:
                    digest.update(np.ascontiguousarray(a).tobytes())
            digests.append(digest.hexdigest())
    assert digests[0] == digests[1]


def test_managed_policy_runs_are_identical():
    """With a policy that reads ``P_c(t)`` (the kinematic draw, the undetected rows)."""
    from mttbench.benchmarks.engine.policies import make_policy
    sc = scenarios.get("kreucher")
    runs = [_digests(sc, 200, 12, compiled, policy=make_policy("renyi"))
            for compiled in (False, True)]
    assert runs[0] == runs[1]


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 16, 127, 128, 129, 169, 300, 1000, 4099])
def test_np_sum_is_numpys_pairwise_sum(n):
    rng = np.random.default_rng(n)
    x = rng.random(n) * 10.0 ** rng.uniform(-8, 8, n)
    assert ap_kernels.np_sum(x, n) == x.sum()


@pytest.mark.parametrize("width", [2, 5])
@pytest.mark.parametrize("reflect", [False, True])
def test_windows_and_draws_equal_the_numpy_forms(width, reflect):
    """:func:`propose`'s windows (both tails, means on and off the grid, narrow and wide
    predictives; 4 window cells summed in the kernel, 25 by ``np_sum``) equal
    :func:`axis_window`: the drawn cell's masses per axis, and with the open walls each
    draw's ``log Z`` (``Z = dead + (1 - beta) sum gamma``, likelihood ratios 1); the CDF
    values kept for the drawn cell give :func:`truncated_normal`'s draw in it."""
    rng = np.random.default_rng(7)
    n, cell, beta = 12, 1.0, 0.1
    means = np.r_[rng.uniform(-2, 14, 400), 0.0, 12.0, 5.5, 5.0, -40.0, 60.0]
    sds = np.r_[10.0 ** rng.uniform(-2.5, 1, 400), 0.03, 0.03, 1e-3, 2.0, 0.5, 0.5]
    N = len(means)
    flip = rng.permutation(N)
    rhohat = np.stack([means, means[flip]], axis=-1)[:, None, :].copy()  # (N, 1, 2)
    sd = np.stack([sds, sds[flip]], axis=-1)[:, None, :].copy()
    valid = np.ones((N, 1), bool)
    one = np.zeros(1, np.int64)
    table = np.zeros((1, 2))  # every cell's likelihood ratio 1
    log_z, log_pi = np.empty((N, 1)), np.empty((N, 1))
    new_cell, new_valid = np.empty((N, 1), np.int64), np.empty((N, 1), bool)
    start, mass = np.empty((N, 1, 2)), np.empty((N, 1, 2))
    side = np.empty((N, 1, 2), np.int8)
    ap_kernels.propose(rhohat, sd, valid, one, one[None], np.ones(1, np.int64), one,
                       rng.random((1, N, 1)), n, n, cell, n * n, width, width, reflect,
                       beta, True, np.zeros(n * n + 1, np.int32), one, table, log_z, log_pi,
                       new_cell, new_valid, start, mass, side)
    windows = [axis_window(rhohat[:, 0, ax], sd[:, 0, ax], n, cell, 0, width=width)
               for ax in range(2)]
    if not reflect:  # numpy's form of Z
        (ix, gx, in_x), (iy, gy, in_y) = windows
        gamma = (gy[:, :, None] * gx[:, None, :]).reshape(N, -1)
        total = gamma.sum(axis=-1)
        inside = in_x * in_y
        gamma *= np.where(total > 0, inside / np.where(total > 0, total, 1.0), 0.0)[:, None]
        z = beta + (1.0 - beta) * (1.0 - inside) + ((1.0 - beta) * gamma * 1.0).sum(axis=-1)
        assert np.array_equal(log_z[:, 0], np.log(z))
    drawn = 0
    for p in np.flatnonzero(new_valid[:, 0] & (side[:, 0, 0] >= 0)):
        for ax, k in enumerate((new_cell[p, 0] % n, new_cell[p, 0] // n)):
            index, masses, _ = windows[ax]
            w = int(np.flatnonzero(index[p] == k)[0])
            assert mass[p, 0, ax] == masses[p, w]
            mu, s, lo, u = rhohat[p, 0, ax], sd[p, 0, ax], k * cell, rng.random()
            expected = truncated_normal(np.array([mu]), np.array([s]), np.array([lo]),
                                        np.array([lo + cell]), np.array([u]))[0]
            assert side[p, 0, ax] == ((lo - mu) / s > 0.0)
            x = ap_kernels._draw_in_cell(mu, s, lo, lo + cell, u, start[p, 0, ax],
                                         mass[p, 0, ax], side[p, 0, ax] == 1)
            assert x == expected == ap_kernels._truncated_normal(mu, s, lo, lo + cell, u)
            drawn += 1
    assert drawn > N  # most particles drew a cell of the grid


def test_slot_log_likelihood_equals_the_numpy_form():
    """Several targets in one looked cell, cells looked twice, empty slots."""
    from mttbench.trackers.jmpd.likelihood import grid_log_likelihood
    rng = np.random.default_rng(8)
    grid = Grid(6, 5)
    N, T = 500, 6
    pos = np.stack([rng.uniform(0, 6, (N, T)), rng.uniform(0, 5, (N, T))], axis=-1)
    pos[:, :3] = pos[:, :1]  # three targets in one cell
    valid = rng.random((N, T)) < 0.7
    looks = rng.integers(0, grid.n_cells, 25)
    returns = rng.random(25) < 0.4
    sensor = RayleighGridSensor()
    index, table = grid_log_likelihood_tables(sensor, looks, returns, grid.n_cells, T)
    cells = grid.cell_of(pos[..., 0], pos[..., 1])
    cells = np.where(valid & (cells >= 0), cells, grid.n_cells)
    start = rng.normal(size=N)
    expected = start + grid_log_likelihood(cells, index, table)
    for direct in (True, False):
        got = start.copy()
        ap_kernels.slot_log_likelihood(pos, valid, grid.nx, grid.ny, 1.0, grid.n_cells,
                                       direct, index.direct_table() if direct else
                                       np.zeros(1, np.int32), index.keys, table, got)
        assert np.array_equal(got, expected)


def test_sort_and_sums_equal_the_numpy_forms():
    """One K-means sweep over a cluster of 4 slots, and the per-slot sums and holders,
    against :func:`.partitions.sort_slots` and numpy's reductions."""
    from mttbench.trackers.jmpd.partitions import sort_slots
    rng = np.random.default_rng(9)
    N, T = 800, 6
    pos = rng.normal(5.0, 2.0, (N, T, 2))
    vel, vvar = rng.normal(size=(N, T, 2)), rng.random((N, T, 2))
    valid = rng.random((N, T)) < 0.8
    slots = np.array([0, 2, 3, 5])
    arrays = [a.copy() for a in (pos, vel, vvar, valid)]
    sort_slots(arrays[0], arrays[3], [slots], arrays, iterations=1)
    held, sums = np.empty(T, np.int64), np.empty((T, 2))
    vel_sums = np.empty((T, 2))
    ap_kernels.slot_sums(pos, vel, valid, True, held, sums, vel_sums)
    assert np.array_equal(held, valid.sum(axis=0))
    assert np.array_equal(sums, (pos * valid[..., None]).sum(axis=0))
    assert np.array_equal(vel_sums, (vel * valid[..., None]).sum(axis=0))
    means = sums[slots] / np.maximum(held[slots], 1)[:, None]
    got = [a.copy() for a in (pos, vel, vvar, valid)]
    new_held, new_sums = np.empty(len(slots), np.int64), np.empty((len(slots), 2))
    moved = ap_kernels.sort_cluster(*got, slots, means, held[slots], new_held, new_sums)
    assert moved > 0
    for a, b in zip(got, arrays, strict=True):
        assert np.array_equal(a, b)
    ap_kernels.slot_sums(got[0], got[1], got[3], False, held, sums, vel_sums)
    assert np.array_equal(new_held, held[slots]) and np.array_equal(new_sums, sums[slots])


@pytest.mark.parametrize("h", [2, 3, 4, 5])
@pytest.mark.parametrize("sweeps", [1, 2])
def test_sort_sweeps_equal_the_numpy_form_with_ties(h, sweeps):
    """Sweeps per cluster size up to ``SORT_MAX``, on particles whose slots hold the
    same positions (equal costs: the first least permutation must win), positions on a
    coarse lattice (many equal costs between particles) and slots held nowhere."""
    from mttbench.trackers.jmpd.partitions import sort_slots
    rng = np.random.default_rng(10 + h)
    N, T = 600, h + 2
    pos = rng.integers(0, 4, (N, T, 2)).astype(float) * 0.5
    pos[:100, 1] = pos[:100, 2]  # ties within a particle
    vel, vvar = rng.normal(size=(N, T, 2)), rng.random((N, T, 2))
    valid = rng.random((N, T)) < 0.7
    slots = np.arange(1, h + 1)
    valid[:, slots[-1]] &= h < 4  # a slot held nowhere for the larger clusters
    arrays = [a.copy() for a in (pos, vel, vvar, valid)]
    sort_slots(arrays[0], arrays[3], [slots], arrays, iterations=sweeps)
    got = [a.copy() for a in (pos, vel, vvar, valid)]
    held, sums = np.empty(T, np.int64), np.empty((T, 2))
    ap_kernels.slot_sums(got[0], got[1], got[3], False, held, sums, np.empty((T, 2)))
    new_held, new_sums = np.empty(h, np.int64), np.empty((h, 2))
    for _ in range(sweeps):
        means = sums[slots] / np.maximum(held[slots], 1)[:, None]
        ap_kernels.sort_cluster(*got, slots, means, held[slots], new_held, new_sums)
        held[slots], sums[slots] = new_held, new_sums
    for a, b in zip(got, arrays, strict=True):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("spread", [0.3, 1.5])
def test_sort_sweep_of_separated_targets_equals_the_numpy_form(spread):
    """Five targets a few cells apart, each particle's positions near their slots' means
    (the identity is least, found without the search) but a tenth of the particles with
    two labels exchanged, some slots empty, and with ``spread`` 1.5 near-ties between
    slots (the search): one sweep against :func:`.partitions.sort_slots`."""
    from mttbench.trackers.jmpd.partitions import sort_slots
    rng = np.random.default_rng(12)
    N, T, h = 2000, 7, 5
    centres = np.array([[1.0, 1.0], [4.0, 1.5], [2.0, 5.0], [6.0, 6.0], [3.5, 3.0]])
    pos = np.zeros((N, T, 2))
    pos[:, 1:h + 1] = centres + rng.normal(0.0, spread, (N, h, 2))
    swap = rng.random(N) < 0.1
    pos[swap, 1], pos[swap, 3] = pos[swap, 3].copy(), pos[swap, 1].copy()
    vel, vvar = rng.normal(size=(N, T, 2)), rng.random((N, T, 2))
    valid = rng.random((N, T)) < 0.8
    slots = np.arange(1, h + 1)
    arrays = [a.copy() for a in (pos, vel, vvar, valid)]
    sort_slots(arrays[0], arrays[3], [slots], arrays, iterations=1)
    got = [a.copy() for a in (pos, vel, vvar, valid)]
    held = valid[:, slots].sum(axis=0)
    means = (pos[:, slots] * valid[:, slots, None]).sum(axis=0) / held[:, None]
    new_held, new_sums = np.empty(h, np.int64), np.empty((h, 2))
    moved = ap_kernels.sort_cluster(*got, slots, means, held, new_held, new_sums)
    assert moved >= swap.sum() // 2
    for a, b in zip(got, arrays, strict=True):
        assert np.array_equal(a, b)


def test_least_permutation_is_the_first_least_of_a_full_scan():
    """The pruned depth-first search against ``argmin`` over every permutation's sum,
    on random costs, costs with many ties and zero rows."""
    from mttbench.trackers.jmpd.partitions import permutations
    rng = np.random.default_rng(11)
    for h in range(1, 6):
        perms = permutations(h)
        scratch = (np.empty(h, np.int64), np.empty(h, bool), np.empty(h + 1, np.int64),
                   np.empty(h + 1))
        best = np.empty(h, np.int64)
        for trial in range(300):
            D = rng.random((h, h)) if trial % 3 == 0 else rng.integers(0, 3, (h, h)) * 0.1
            if trial % 5 == 0:
                D[rng.integers(h)] = 0.0
            costs = np.zeros(len(perms))
            for j in range(h):
                costs = costs + D[j, perms[:, j]]
            ap_kernels._least_permutation(D, h, best, *scratch)
            assert np.array_equal(best, perms[np.argmin(costs)])


def test_ndtr_shortcuts_equal_scipy():
    """The window's CDF shortcuts: ``ndtr`` is exactly 0 below ``NDTR_ZERO``, and
    ``ndtr(x) == 1 - ndtr(-x)`` bit for bit for ``x >= 1`` (scipy's ``erfc`` branch);
    both forms against scipy on dense samples around the thresholds and far beyond."""
    from scipy.special import ndtr
    rng = np.random.default_rng(12)
    below = np.r_[np.nextafter(ap_kernels.NDTR_ZERO, -np.inf), -37.70000001, -38.0, -1e300,
                  -np.inf, ap_kernels.NDTR_ZERO - rng.exponential(5.0, 20000)]
    above = np.r_[1.0, np.nextafter(1.0, 2.0), 37.0, 38.0, 1e300, np.inf,
                  1.0 + rng.exponential(3.0, 200000), rng.uniform(1.0, 1.001, 20000)]
    lower = np.r_[np.nextafter(ap_kernels.NDTR_ZERO, 0.0), -37.6, -1.0, -0.5, 0.0,
                  -rng.uniform(0.0, 37.7, 20000)]
    assert (ndtr(below) == 0.0).all()
    assert np.array_equal(ndtr(above), 1.0 - ndtr(-above))
    for x in np.r_[below, lower]:
        assert ap_kernels._ndtr_lower(x) == ndtr(x)
    for x in np.r_[above[:40000], rng.uniform(0.0, 1.0, 5000), 5e-324]:
        assert ap_kernels._ndtr_upper(x, ndtr(-x)) == ndtr(x)


def test_permuting_an_array_is_indexing_it_by_a_permutation():
    """The compiled step draws ``rng.permutation(N)`` and indexes the resampled
    ancestors by it where the numpy form calls ``rng.permutation(ancestors)``: the same
    array and the same stream after it (numpy's shuffle swaps by position only)."""
    for n in (1, 2, 3, 17, 300, 4001):
        for seed in range(4):
            ancestors = np.sort(np.random.default_rng(seed + 50).integers(0, n, n))
            direct, indexed = np.random.default_rng(seed), np.random.default_rng(seed)
            expected = direct.permutation(ancestors)
            assert np.array_equal(ancestors[indexed.permutation(n)], expected)
            assert np.array_equal(direct.random(3), indexed.random(3))


def test_place_gives_the_same_values_in_any_order_of_the_receivers(monkeypatch):
    """``place`` on the arguments of real steps (``default``: one cluster, two at
    times), its receivers in the caller's order (by ancestor for one cluster, else the
    particles' with prefetches), in particle order and in a random order."""
    from mttbench.trackers.jmpd import backend
    kernels = backend.compiled_ap_kernels()
    calls = []
    real = kernels.place

    def record(*args):
        calls.append([np.array(a, copy=True) if isinstance(a, np.ndarray) else a
                      for a in args])
        return real(*args)

    monkeypatch.setattr(kernels, "place", record)
    with use_backend("compiled"):
        list(play(scenarios.get("default"), JMPDAPTracker(n_particles=200), 0, n_steps=16))
    calls = [c for c in calls if c[0].shape[0] == 200]  # not the kernels' warm-up
    assert {c[0].shape[1] for c in calls} >= {1, 2}
    rng = np.random.default_rng(13)
    for args in calls:
        anc, order, prefetch = args[:3]
        n, n_clusters = anc.shape
        if n_clusters == 1:
            assert not prefetch and np.all(np.diff(anc[order, 0]) >= 0)
        else:
            assert prefetch and np.array_equal(order, np.arange(n))
        results = []
        for new_order, new_prefetch in ((order, prefetch), (np.arange(n), True),
                                        (rng.permutation(n), False)):
            out = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
            out[1], out[2] = new_order, new_prefetch
            real(*out)
            results.append(out[-4:])
        for other in results[1:]:
            for a, b in zip(results[0], other, strict=True):
                assert np.array_equal(a, b, equal_nan=True)


def test_gathered_slots_and_held_counts_equal_numpy():
    rng = np.random.default_rng(14)
    N, T = 301, 7
    pos, vel, vvar = (rng.normal(size=(N, T, 2)) for _ in range(3))
    valid = rng.random((N, T)) < 0.4
    idx = np.sort(rng.integers(0, N, N))
    out = [np.empty_like(a) for a in (pos, vel, vvar, valid)]
    ap_kernels.gather_slots(pos, vel, vvar, valid, idx, *out)
    for a, b in zip((pos, vel, vvar, valid), out, strict=True):
        assert np.array_equal(a[idx], b)
    assert np.array_equal(ap_kernels.held_per_particle(valid), valid.sum(axis=1))


def test_birth_decisions_equal_the_numpy_form():
    """The births' loop over the detected cells (``ap.JMPDAPTracker._births``, numpy
    form, restated here from its per-cell values) against the kernel: particles with and
    without a free slot, cells they occupy, no undetected target left (``pi = 0``),
    certain arrivals, and the numpy form's ``log1p`` where no slot is free."""
    rng = np.random.default_rng(15)
    N, D = 600, 7
    remaining = np.where(rng.random(N) < 0.2, 0.0, rng.uniform(0.0, 3.0, N))
    share = np.r_[0.0, 1.0, rng.random(D - 2) * 0.2]
    log_keep = np.log1p(-np.minimum(share, 1.0 - 1e-12))
    pi_arrival = np.r_[0.0, 0.3, 0.0, 1.0, rng.random(D - 4) * 0.1]
    lam = np.r_[1e-3, rng.lognormal(1.0, 1.5, D - 1)]
    has_slot, occupied = rng.random((N, D)) < 0.6, rng.random((N, D)) < 0.2
    uniforms = rng.random((N, D))

    left, born, log_ratio = remaining.copy(), np.zeros((N, D), bool), np.zeros(N)
    with np.errstate(invalid="ignore", divide="ignore"):
        for k in range(D):
            pi_init = -np.expm1(left * log_keep[k])
            pi = 1.0 - (1.0 - pi_init) * (1.0 - pi_arrival[k])
            z = 1.0 - pi + pi * lam[k]
            b = np.where(has_slot[:, k], pi * lam[k] / z, 0.0)
            born[:, k] = (uniforms[:, k] < b) & ~occupied[:, k]
            kept = np.log(z) - np.where(born[:, k], np.log(lam[k]), 0.0)
            log_ratio += np.where(occupied[:, k], 0.0, np.where(has_slot[:, k], kept,
                                                                  np.log1p(-pi)))
            initial = np.where(pi > 0.0, pi_init / pi, 0.0)
            left = np.maximum(left - np.where(born[:, k], initial, 0.0), 0.0)
    assert born.any() and (~has_slot & ~occupied).any()

    got_left, got_born, got_ratio = remaining.copy(), np.empty((N, D), bool), np.zeros(N)
    ap_kernels.birth_decisions(got_left, log_keep, pi_arrival, lam, np.log(lam), has_slot,
                               occupied, uniforms, got_born, got_ratio)
    assert np.array_equal(got_born, born)
    assert np.array_equal(got_ratio, log_ratio)
    assert np.array_equal(got_left, left)


@pytest.mark.parametrize("n_clusters", [1, 3, 7, 8, 10])
def test_recombined_log_pi_equals_numpy(n_clusters):
    rng = np.random.default_rng(16)
    N = 257
    log_pi = rng.normal(size=(N, n_clusters)) * 10.0 ** rng.integers(-6, 6, (N, n_clusters))
    log_pi[rng.random((N, n_clusters)) < 0.2] = 0.0
    anc = rng.integers(0, N, (N, n_clusters))
    got = np.empty(N)
    ap_kernels.recombined_log_pi(log_pi, anc, got)
    expected = -log_pi[anc, np.arange(n_clusters)[None, :]].sum(axis=1)
    assert np.array_equal(got, expected)
    assert np.array_equal(np.signbit(got), np.signbit(expected))


def test_clusters_equal_the_numpy_form():
    """``cluster_slots`` on random centres (a pair exactly at the distance included),
    with the links of holdings with exclusive, dependent, independent, empty and
    always-held slots, and without links, against :mod:`.partitions`."""
    from mttbench.trackers.jmpd import partitions
    rng = np.random.default_rng(17)
    for _ in range(60):
        N, T = int(rng.integers(1, 400)), int(rng.integers(1, 12))
        valid = rng.random((N, T)) < rng.random(T)
        if T >= 4:
            half = rng.random(N) < 0.5
            valid[:, 0], valid[:, 1] = half, ~half  # one target, two slots
            valid[:, 2] = valid[:, 3] & (rng.random(N) < 0.9)  # dependent
        if T >= 6:
            valid[:, 4], valid[:, 5] = False, True
        links = partitions.coupled_slots(valid)
        gamma = 2.5
        centres = rng.uniform(0.0, 8.0, (T, 2))
        if T >= 3:
            centres[2] = centres[1] + [gamma, 0.0]  # exactly at the distance: no link
        active = rng.random(T) < 0.8
        for given in (links, None):
            expected = partitions.cluster_slots(centres, active, gamma, given)
            members, sizes = np.empty(T, np.int64), np.empty(T, np.int64)
            n = ap_kernels.cluster_slots(centres, active, gamma,
                                         np.zeros((0, 0), bool) if given is None else given,
                                         members, sizes)
            starts = np.cumsum(sizes[:n]) - sizes[:n]
            got = [members[a:a + size] for a, size in zip(starts, sizes[:n], strict=True)]
            assert len(got) == len(expected)
            for a, b in zip(got, expected, strict=True):
                assert np.array_equal(a, b)

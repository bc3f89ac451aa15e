"""The simulator: sensor statistics, determinism, order-independence of looks, dynamics."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import stats

from mttbench import scenarios
from mttbench.scenarios.model import Dynamics, Grid, RayleighGridSensor
from mttbench.scenarios.simulator import simulate, simulate_truth


def _static_scenario(states, p_d=0.5, snr=1.0, n_steps=400, nx=4, ny=1):
    """Targets that never move (Q = 0, zero velocity) on a small grid."""
    base = scenarios.get("default")
    model = dataclasses.replace(
        base.model,
        grid=Grid(nx, ny, 1.0),
        dynamics=Dynamics(tau=1.0, q_matrix=tuple(tuple(0.0 for _ in range(4)) for _ in range(4))),
        birth_death=dataclasses.replace(base.model.birth_death, initial_states=tuple(states),
                                        n_random_initial=0, birth_rate=0.0),
        sensor=RayleighGridSensor(p_d=p_d, snr=snr, looks_per_step=nx * ny),
    )
    return dataclasses.replace(base, name="static-test", n_steps=n_steps, model=model)


def test_positive_fraction_matches_pd_of_count():
    """Cells holding T = 0, 1, 2 targets return 1 with frequency p_d(T).

    A low snr (1.0) makes p_f = 0.25 so the T = 0 case is testable. Each cell is looked
    at 3 times per step (repeats are independent looks), 400 steps -> 1200 Bernoulli
    draws per cell and seed; the check is a two-sided binomial test at level 1e-4 per
    cell, so a correct simulator fails it with probability < 1e-3 overall.
    """
    sc = _static_scenario([(1.5, 0, 0.5, 0), (2.5, 0, 0.5, 0), (2.6, 0, 0.4, 0)])
    sensor = sc.model.sensor
    totals = np.zeros(4)
    positives = np.zeros(4)
    for seed in range(2):
        run = simulate(sc, seed)
        cells = np.repeat(np.arange(4), 3)
        for k in range(sc.n_steps):
            looks = run.look(k, cells)
            positives += np.bincount(looks.cells[looks.returns], minlength=4)
            totals += np.bincount(looks.cells, minlength=4)
    counts = simulate(sc, 0).cell_counts(0)
    np.testing.assert_array_equal(counts, [0, 1, 2, 0])
    for c in range(4):
        p = float(sensor.detection_probability(counts[c]))
        pval = stats.binomtest(int(positives[c]), int(totals[c]), p).pvalue
        assert pval > 1e-4, (c, counts[c], positives[c] / totals[c], p)


def test_detection_probability_formula():
    s = RayleighGridSensor(p_d=0.5, snr=10.0)
    assert s.p_f == pytest.approx(0.5**11)
    assert s.p_f == pytest.approx(4.8828125e-4)
    np.testing.assert_allclose(s.detection_probability([0, 1, 2]),
                               [0.5**11, 0.5, 0.5 ** (11 / 21)])
    # log-likelihood ratio is exactly zero for empty cells and matches the definition
    llr = s.log_likelihood_ratio(np.array([True, False, True]), np.array([0, 2, 1]))
    assert llr[0] == 0.0
    assert llr[1] == pytest.approx(np.log(1 - 0.5 ** (11 / 21)) - np.log(1 - 0.5**11))
    assert llr[2] == pytest.approx(np.log(0.5) - np.log(0.5**11))


@pytest.mark.parametrize("name", ["default", "births", "paper"])
def test_same_seed_same_world(name):
    sc = scenarios.get(name)
    a, b = simulate(sc, 7), simulate(sc, 7)
    for k in range(sc.n_steps):
        np.testing.assert_array_equal(a.ids[k], b.ids[k])
        np.testing.assert_array_equal(a.states[k], b.states[k])
    cells = np.arange(sc.grid.n_cells)
    np.testing.assert_array_equal(a.look(3, cells).returns, b.look(3, cells).returns)
    c = simulate(sc, 8)
    assert not np.array_equal(a.states[-1], c.states[-1])


def test_look_order_and_subset_do_not_change_returns():
    """A look's answer depends only on (step, cell, repeat index), not on the other looks."""
    sc = _static_scenario([(0.5, 0, 0.5, 0), (1.5, 0, 0.5, 0)], snr=0.5, nx=6, ny=3)
    run = simulate(sc, 11)
    rng = np.random.default_rng(0)
    cells = rng.integers(0, sc.grid.n_cells, size=60)  # many repeats
    reference = run.look(5, cells).returns
    perm = rng.permutation(cells.size)
    # permuting the looks permutes the answers only where the repeat rank is kept:
    # compare per cell the sequence of answers in repeat order
    shuffled = run.look(5, cells[perm]).returns
    for c in np.unique(cells):
        ref_seq = reference[cells == c]
        shuf_seq = shuffled[cells[perm] == c]
        np.testing.assert_array_equal(np.sort(ref_seq), np.sort(shuf_seq))
    # a fresh run object (no cached rows) looking at one cell alone agrees with the full call
    fresh = simulate(sc, 11)
    first_cell = int(cells[0])
    alone = fresh.look(5, np.array([first_cell])).returns
    assert alone[0] == reference[0]


def test_repeated_looks_are_independent():
    """Repeats at one cell are distinct draws: with p_f = 0.5**1.1 about half disagree."""
    sc = _static_scenario([], p_d=0.5, snr=0.1, nx=1, ny=1, n_steps=500)
    run = simulate(sc, 3)
    pairs = np.array([run.look(k, np.array([0, 0])).returns for k in range(sc.n_steps)])
    p = sc.model.sensor.p_f
    disagree = np.mean(pairs[:, 0] != pairs[:, 1])
    expected = 2 * p * (1 - p)
    # binomial sd over 500 steps is ~0.022; 5 sd band
    assert abs(disagree - expected) < 5 * np.sqrt(expected * (1 - expected) / 500)


def test_reflect_keeps_targets_inside_and_die_removes_them():
    sc = scenarios.get("paper")  # jumps of several cells per step: many bounces
    _, states = simulate_truth(sc, 0)
    w, h = sc.grid.extent
    for s in states:
        assert np.all((s[:, 0] >= 0) & (s[:, 0] < w) & (s[:, 2] >= 0) & (s[:, 2] < h))
        assert len(s) == 3
    births = scenarios.get("births")
    ids, states = simulate_truth(births, 1)
    counts = [len(i) for i in ids]
    assert len(set(counts)) > 1  # the count changes
    for i in ids:
        assert len(np.unique(i)) == len(i)


def test_dynamics_moments_without_boundary():
    """With no boundary hit, one step of the truth has mean F x and covariance Q."""
    sc = scenarios.get("default")
    dyn = sc.model.dynamics
    x0 = np.array([6.0, 0.1, 6.0, -0.1])
    model = dataclasses.replace(
        sc.model,
        dynamics=Dynamics(tau=1.0, wna_intensity=0.01),
        birth_death=dataclasses.replace(sc.model.birth_death, initial_states=(tuple(x0),) * 4000),
    )
    big = dataclasses.replace(sc, n_steps=2, model=model)
    _, states = simulate_truth(big, 0)
    step = states[1]
    F, Q = model.dynamics.F, model.dynamics.Q
    # 4 standard errors per component
    assert np.all(np.abs(step.mean(axis=0) - F @ x0) < 4 * np.sqrt(np.diag(Q) / 4000))
    # sample covariance: standard error of entry ij is sqrt((Q_ii Q_jj + Q_ij^2) / n); 5 SE
    se = np.sqrt((np.outer(np.diag(Q), np.diag(Q)) + Q**2) / len(step))
    assert np.all(np.abs(np.cov(step.T) - Q) < 5 * se)
    assert dyn.F.shape == (4, 4)


def test_superposition_measurement_is_mean_plus_noise():
    sc = scenarios.get("superposition")
    run = simulate(sc, 0)
    H, R = sc.model.sensor.H, sc.model.sensor.R
    resid = np.array([run.measure(k).z - (run.states[k] @ H.T).mean(axis=0)
                      for k in range(sc.n_steps)])
    # 100 draws of N(0, 0.25 I): sample covariance within a loose chi-square band
    assert np.allclose(resid.mean(axis=0), 0, atol=4 * 0.5 / np.sqrt(100))
    var = resid.var(axis=0, ddof=1)
    lo, hi = stats.chi2.ppf([1e-4, 1 - 1e-4], 99) / 99
    assert np.all((var / R[0, 0] > lo) & (var / R[0, 0] < hi))
    np.testing.assert_array_equal(run.measure(4).z, simulate(sc, 0).measure(4).z)


def test_look_rejects_bad_cells():
    run = simulate(scenarios.get("default"), 0)
    with pytest.raises(ValueError, match="cell indices"):
        run.look(0, np.array([144]))
    with pytest.raises(ValueError, match="step"):
        run.look(100, np.array([0]))
    with pytest.raises(ValueError, match="seed"):
        simulate(scenarios.get("default"), -1)


# ============================================================ the rules, one by one
# Each rule of simulate_truth and Run.look is tested directly against an exact
# expectation (reflection, die, common random numbers) or a stated statistical band
# (births, survival). The statistical tests use fixed seeds, so they are deterministic;
# the false-failure probability stated with each is the chance that a correct simulator
# would fail on a random choice of seeds.

#: the simulator draws the process noise through chol(Q + 1e-15 I), so "Q = 0" still
#: moves a target by N(0, 1e-15) per component and step; after k <= 40 steps the
#: position error has sd 3.2e-8 * sqrt(k^3 / 3) < 8e-6 (velocity: 3.2e-8 sqrt(k) < 2.1e-7)
NOISE_POS_ATOL = 1e-4
NOISE_VEL_ATOL = 2e-6


#: 8 x 6 cells of 0.5: a 4 x 3 workspace
_RULES_GRID = Grid(8, 6, 0.5)


def _world(*, grid=_RULES_GRID, states=(), n_random=0, survival=1.0, birth_rate=0.0,
           birth_velocity_std=0.1, boundary="reflect", n_steps=40, p_d=0.5, snr=10.0,
           name="rules-test"):
    """A scenario with Q = 0 (see NOISE_POS_ATOL) and the given birth/death rules.

    The default grid is 8 x 6 cells of 0.5, so the workspace is 4 x 3: width and height
    differ, and a rule that mixes up the axes shows."""
    base = scenarios.get("default")
    model = dataclasses.replace(
        base.model,
        grid=grid,
        dynamics=Dynamics(tau=1.0, q_matrix=tuple(tuple(0.0 for _ in range(4)) for _ in range(4))),
        birth_death=dataclasses.replace(
            base.model.birth_death, initial_states=tuple(tuple(s) for s in states),
            n_random_initial=n_random, survival_probability=survival, birth_rate=birth_rate,
            birth_velocity_std=birth_velocity_std, boundary=boundary),
        sensor=RayleighGridSensor(p_d=p_d, snr=snr, looks_per_step=grid.n_cells),
    )
    return dataclasses.replace(base, name=name, n_steps=n_steps, model=model)


def _births_per_step(ids: list[np.ndarray]) -> np.ndarray:
    """Number of new target ids at each step ``k >= 1`` (ids are issued consecutively)."""
    seen = int(ids[0].max()) if len(ids[0]) else -1
    out = []
    for i in ids[1:]:
        new = i[i > seen]
        out.append(len(new))
        seen = max(seen, int(new.max())) if len(new) else seen
    return np.array(out)


def _poisson_two_sided_p(total: int, mean: float) -> float:
    """Exact two-sided p-value (twice the smaller tail) of ``total`` under Poisson(mean)."""
    return float(min(1.0, 2.0 * min(stats.poisson.cdf(total, mean),
                                    stats.poisson.sf(total - 1, mean))))


def test_births_are_poisson_in_mean_dispersion_and_distribution():
    """Births per step are Poisson(birth_rate), counted over 4 seeds x 500 steps.

    Survival 0 kills every target at the start of each step, so the targets of step k are
    exactly its births (this also checks that a newborn is not exposed to the survival
    draw of its own step). With lambda = 2 and n = 1996 steps:

    * mean: the total is Poisson(n lambda) exactly; exact two-sided test at 1e-6
      (a doubled rate puts the total ~60 sd away);
    * dispersion: the index of dispersion ``sum (x - xbar)^2 / xbar`` given the total is
      the Pearson statistic of a uniform multinomial, ~chi2(n - 1) (mean n - 1, variance
      2(n - 1)(1 - 1/total)); two-sided band at 1e-6 per side (a count with the right mean
      but twice the variance, such as ``2 * Poisson(lambda / 2)``, gives twice the
      statistic);
    * distribution: Pearson chi-square of the histogram (0..5 and >= 6) against the
      Poisson(2) probabilities, 6 degrees of freedom, at 1e-6.

    False-failure probability about 5e-6 in all (union bound over the four tails).
    """
    lam, n_steps, seeds = 2.0, 500, range(4)
    sc = _world(survival=0.0, birth_rate=lam, n_steps=n_steps)
    counts = []
    for seed in seeds:
        ids, _ = simulate_truth(sc, seed)
        got = _births_per_step(ids)
        # survival 0: everything alive at step k was born at step k
        np.testing.assert_array_equal(got, [len(i) for i in ids[1:]])
        counts.append(got)
    x = np.concatenate(counts)
    n = len(x)
    assert _poisson_two_sided_p(int(x.sum()), n * lam) > 1e-6, (x.mean(), lam)
    dispersion = float(((x - x.mean()) ** 2).sum() / x.mean())
    lo, hi = stats.chi2.ppf([1e-6, 1 - 1e-6], n - 1)
    assert lo < dispersion < hi, (dispersion, n - 1, lo, hi)
    observed = np.bincount(np.minimum(x, 6), minlength=7)
    expected = n * np.append(stats.poisson.pmf(np.arange(6), lam), stats.poisson.sf(5, lam))
    chi2 = float(((observed - expected) ** 2 / expected).sum())
    assert stats.chi2.sf(chi2, 6) > 1e-6, (observed, expected.round(1))


def test_births_of_the_births_preset_have_its_rate():
    """The preset's own rate (0.05 per step) over 2 seeds x 2000 steps: the number of new
    ids is Poisson(0.05 x 3998) = Poisson(199.9) given that births do not depend on the
    rest of the truth; exact two-sided test at 1e-6 (false failure 1e-6). A doubled rate
    gives a total near 400, 14 sd away."""
    sc = dataclasses.replace(scenarios.get("births"), n_steps=2000)
    total, n = 0, 0
    for seed in range(2):
        ids, _ = simulate_truth(sc, seed)
        births = _births_per_step(ids)
        total += int(births.sum())
        n += len(births)
    rate = sc.model.birth_death.birth_rate
    assert _poisson_two_sided_p(total, n * rate) > 1e-6, (total, n * rate)


def test_births_are_uniform_on_the_workspace_with_normal_velocities():
    """Newborn positions are uniform on [0, width) x [0, height) and velocities
    N(0, birth_velocity_std^2) per axis: four Kolmogorov-Smirnov tests on the ~4000 births
    of 2 seeds x 1000 steps (lambda = 2, survival 0), each at 1e-6 (false failure 4e-6).
    The workspace is 4 x 3, so drawing y on the width (or x on the height) fails."""
    sc = _world(survival=0.0, birth_rate=2.0, n_steps=1000, birth_velocity_std=0.3)
    born = np.concatenate([np.concatenate(simulate_truth(sc, seed)[1][1:])
                           for seed in range(2)])
    width, height = sc.grid.extent
    assert (width, height) == (4.0, 3.0)
    for column, dist in ((0, stats.uniform(0.0, width)), (2, stats.uniform(0.0, height)),
                         (1, stats.norm(0.0, 0.3)), (3, stats.norm(0.0, 0.3))):
        pval = stats.kstest(born[:, column], dist.cdf).pvalue
        assert pval > 1e-6, (column, pval)


@pytest.mark.parametrize("p_s", [0.9, 0.6])
def test_survival_is_binomial_per_step(p_s):
    """Each target survives each step independently with p_s: starting from 4000 targets
    at rest (Q = 0, reflect, no births), the survivors of step k given the n_{k-1} alive
    are Binomial(n_{k-1}, p_s). Exact two-sided binomial test per step at 1e-6 over 8
    steps (false failure < 1e-5); p_s squared (0.81, 0.36) is more than 10 sd away at every
    step. Survivors keep their ids and their (unmoved) states; nobody comes back."""
    start = [(0.5 + 3.0 * (i % 97) / 97, 0.0, 0.5 + 2.0 * (i // 97) / 42, 0.0)
             for i in range(4000)]
    sc = _world(states=start, survival=p_s, n_steps=9)
    ids, states = simulate_truth(sc, 3)
    for k in range(1, sc.n_steps):
        before, after = ids[k - 1], ids[k]
        assert np.all(np.isin(after, before))  # no new ids, no resurrection
        pval = stats.binomtest(len(after), len(before), p_s).pvalue
        assert pval > 1e-6, (k, len(after), len(before), p_s)
        # survivors are the same targets, where they were (rest, Q = 0)
        rows = np.searchsorted(before, after)
        np.testing.assert_allclose(states[k], states[k - 1][rows], atol=NOISE_POS_ATOL)


def _bounce(p: float, v: float, length: float) -> tuple[float, float]:
    """Reflect ``p`` into ``[0, length)`` one wall at a time, flipping ``v`` at each wall.

    An exact hit on the far wall counts as a bounce there and is kept just inside (the
    workspace is half-open)."""
    while p < 0.0 or p > length:
        p, v = (-p, -v) if p < 0.0 else (2.0 * length - p, -v)
    if p == length:
        p, v = math.nextafter(length, 0.0), -v
    return p, v


def _noise_free_paths(start, length_x, length_y, n_steps):
    """Reference truth of targets moving at constant velocity with walls at 0 and L:
    ``(n_steps, n, 4)`` states and ``(n_steps, n)`` "left the workspace during this step"
    (before reflection), by a plain loop over steps and targets."""
    out = np.empty((n_steps, len(start), 4))
    left = np.zeros((n_steps, len(start)), dtype=bool)
    for i, (px, vx, py, vy) in enumerate(start):
        out[0, i] = px, vx, py, vy
        for k in range(1, n_steps):
            px, py = px + vx, py + vy
            left[k, i] = not (0.0 <= px < length_x and 0.0 <= py < length_y)
            px, vx = _bounce(px, vx, length_x)
            py, vy = _bounce(py, vy, length_y)
            out[k, i] = px, vx, py, vy
    return out, left


#: one target per wall (+x, -x, +y, -y), a corner, one that crosses the workspace
#: several times per step and one at rest; workspace 4 x 3
_WALL_TARGETS = [(3.2, 0.3137, 1.01, 0.0519), (0.7, -0.1571, 2.03, -0.1093),
                 (2.0, 0.0213, 2.6, 0.1531), (1.3, 0.0727, 0.35, -0.2029),
                 (3.6, 0.3517, 2.55, 0.2683), (1.1, 9.7131, 1.7, -7.3179), (2.0, 0.0, 1.5, 0.0)]


def test_reflection_mirrors_position_and_velocity_at_the_bounce_step():
    """Q = 0 and known velocities: at every step the truth equals the plain bounce-by-bounce
    reference, so at the step of a bounce the position is mirrored in the wall it crossed and
    that velocity component changes sign, on both walls of both axes (the last but one
    target bounces about twice per step on each axis). Tolerances: NOISE_POS_ATOL and
    NOISE_VEL_ATOL (the 1e-15 regularisation of Q); the reference keeps every position at
    least 1e-3 from a wall, so the bounce steps themselves are exact."""
    n_steps = 40
    sc = _world(states=_WALL_TARGETS, n_steps=n_steps)
    width, height = sc.grid.extent
    want, _ = _noise_free_paths(_WALL_TARGETS, width, height, n_steps)
    # precondition: no reference position within 1e-3 of a wall after a move
    assert np.all(np.minimum(want[:, :, 0], width - want[:, :, 0]) > 1e-3)
    assert np.all(np.minimum(want[:, :, 2], height - want[:, :, 2]) > 1e-3)
    ids, states = simulate_truth(sc, 0)
    for k in range(n_steps):
        np.testing.assert_array_equal(ids[k], np.arange(len(_WALL_TARGETS)))
        np.testing.assert_allclose(states[k][:, [0, 2]], want[k][:, [0, 2]], rtol=0,
                                   atol=NOISE_POS_ATOL, err_msg=f"step {k}")
        np.testing.assert_allclose(states[k][:, [1, 3]], want[k][:, [1, 3]], rtol=0,
                                   atol=NOISE_VEL_ATOL, err_msg=f"step {k}")
    # every wall is hit: each velocity component of the first four targets changes sign
    flips = np.diff(np.sign(want[:, :4, [1, 3]]), axis=0) != 0
    assert flips[:, 0, 0].any() and flips[:, 1, 0].any()  # +x and -x walls
    assert flips[:, 2, 1].any() and flips[:, 3, 1].any()  # +y and -y walls


def test_die_removes_a_target_exactly_at_the_step_it_leaves():
    """Boundary "die", Q = 0: each target is present at step k iff the constant-velocity
    reference has stayed inside the 4 x 3 workspace up to k; the others are untouched.
    The +y target's path stays inside x < 4, so using the width for y keeps it alive."""
    n_steps = 40
    sc = _world(states=_WALL_TARGETS, boundary="die", n_steps=n_steps)
    width, height = sc.grid.extent
    want, left = _noise_free_paths(_WALL_TARGETS, width, height, n_steps)
    gone = np.cumsum(left, axis=0) > 0  # (n_steps, n)
    leave_step = np.where(gone.any(axis=0), gone.argmax(axis=0), n_steps)
    # the reference itself: the wall targets leave at steps 3, 5, 3, 2, 2 (+x, -x, +y, -y,
    # corner), the fast one at once, the one at rest never
    np.testing.assert_array_equal(leave_step, [3, 5, 3, 2, 2, 1, n_steps])
    ids, states = simulate_truth(sc, 0)
    for k in range(n_steps):
        alive = np.flatnonzero(~gone[k])
        np.testing.assert_array_equal(ids[k], alive, err_msg=f"step {k}")
        np.testing.assert_allclose(states[k], want[k][alive], rtol=0, atol=NOISE_POS_ATOL)


# ------------------------------------------------------- common random numbers
def _crn_scenario():
    """Two static targets on a 6 x 4 grid, p_d = 0.5 and snr = 0.1 so that p_f = 0.47 and
    p_d(1) = 0.5: every look is close to a fair coin, so a wrong uniform shows in about
    half of the looks."""
    return _world(grid=Grid(6, 4, 1.0), states=[(0.5, 0, 0.5, 0), (3.5, 0, 2.5, 0)],
                  snr=0.1, n_steps=60, name="crn-test")


def _answers_by_cell(cells: np.ndarray, returns: np.ndarray) -> dict[int, list[bool]]:
    """Per cell, the answers of its looks in the order they were made."""
    out: dict[int, list[bool]] = {}
    for c, z in zip(cells.tolist(), returns.tolist(), strict=True):
        out.setdefault(c, []).append(z)
    return out


def test_first_look_alone_equals_first_of_n_looks_per_cell():
    """Common random numbers per cell: the answer to the j-th look at a cell during step k
    is U[k, j, c] < p_d(T), whatever else the call looks at. For each of 60 steps, one
    call looks at every cell once (in a shuffled order) and another, on a fresh Run, looks
    at each cell 1 to 4 times, the looks of all cells interleaved in a random order; per
    cell the first answers must agree, and so must the j-th answers of any two calls that
    both make a j-th look. A rank rule that depends on how many looks a call makes at a
    cell (for example ranks reversed within a cell) changes about half of these answers."""
    sc = _crn_scenario()
    n_cells = sc.grid.n_cells
    rng = np.random.default_rng(5)
    once, many, again = simulate(sc, 2), simulate(sc, 2), simulate(sc, 2)
    compared = differing_calls = 0
    for k in range(sc.n_steps):
        single = rng.permutation(n_cells)
        ref = _answers_by_cell(single, once.look(k, single).returns)
        reps = rng.integers(1, 5, n_cells)
        multi = rng.permutation(np.repeat(np.arange(n_cells), reps))
        got = _answers_by_cell(multi, many.look(k, multi).returns)
        reps2 = rng.integers(1, 5, n_cells)
        multi2 = rng.permutation(np.repeat(np.arange(n_cells), reps2))
        got2 = _answers_by_cell(multi2, again.look(k, multi2).returns)
        for c in range(n_cells):
            assert got[c][0] == ref[c][0], (k, c)
            j = min(reps[c], reps2[c])
            assert got[c][:j] == got2[c][:j], (k, c, reps[c], reps2[c])
            compared += j
            differing_calls += reps[c] != reps2[c]
    # E[min(reps, reps2)] = 1.875 and P(reps != reps2) = 0.75 per (step, cell)
    assert compared > 1.7 * sc.n_steps * n_cells and differing_calls > 900
    # and the answers are not all equal: they carry information about each look
    frac = np.mean([once.look(k, np.arange(n_cells)).returns for k in range(20)])
    assert 0.35 < frac < 0.65  # p ~ 0.47-0.5 over 480 looks: sd 0.023


def test_look_answers_do_not_depend_on_the_call_history():
    """The same look pattern gives the same answers on a fresh Run, on a Run that has
    already looked at later steps and at more repeats, and within one Run when asked
    again (the uniforms of a step are cached, not redrawn)."""
    sc = _crn_scenario()
    rng = np.random.default_rng(8)
    pattern = rng.permutation(np.repeat(np.arange(sc.grid.n_cells), 2))
    fresh = simulate(sc, 4)
    want = [fresh.look(k, pattern).returns for k in range(10)]
    used = simulate(sc, 4)
    for k in range(9, -1, -1):  # later steps first, with more repeats first
        used.look(k, np.repeat(np.arange(sc.grid.n_cells), 5))
    for k in range(10):
        np.testing.assert_array_equal(used.look(k, pattern).returns, want[k])
        np.testing.assert_array_equal(fresh.look(k, pattern).returns, want[k])

"""A second method tried on `default`, and why it is not one: one single-target filter per
declared target on the same looks as the stored `bayes` reference, and the paired OSPA
difference between the two (docs/bayes.md, "`default`: a product of single-target filters
is no second method").

Usage: ``python docs/bayes_grid_product.py SCENARIO SEEDS [METHOD]``
(SEEDS as ``0:10`` or ``0,3,5``; METHOD ``grid:SPACING`` (default ``grid:1``) or
``pf:N[:SEED[:ESTIMATOR]]``, a bootstrap particle filter of N particles per target, particle
seed SEED, ESTIMATOR ``mean`` (default) or ``cut``).

**Why it is not the joint posterior.** The prior is a product (each declared target starts
at its own point, moves and survives independently), and a look at cell ``c`` depends only
on the number ``n`` of targets in ``c``, through the ratio ``r(n) = p(z | n) / p(z | 0)``.
The product of the targets' own filters uses ``r(1)^n`` for ``r(n)``: the same for
``n <= 1``, wrong only for two targets in one cell. That one term is not negligible: it
carries the explaining-away. After a detection in a cell where target A probably is, the
joint posterior keeps target B where it was (``r(2)`` is about ``r(1)``: the detection is
A's), while B's own filter weighs B's mass in that cell by ``r(1)`` against 1 and moves it
there (``r(1)^2`` against ``r(1)`` in the joint terms: the factor ``r(1) = p_d / p_f``, about
1,000 on `default`, is exactly the joint's denominator that the product drops). So a
product of even exact single-target filters is a worse filter than the joint one where the
targets' posteriors overlap, and no reference.

The single-target filters: ``grid-bayes`` (exact on its grid, but its linear split adds up
to ``h^2 / 4`` variance per step: on a scene with little process noise it is the filter of
a noisier model) and a bootstrap particle filter that samples the model exactly as the
simulator moves the truth (its own wall rule; ``docs/bayes_grid_pf.py``'s filter,
vectorised over the looks: each particle weighted by ``Lambda`` of its cell; systematic
resampling every step).

Estimate: per target, reported iff its existence is at least 0.5 (``grid-bayes``'s rule),
at the posterior mean given existence (``mean``) or (``cut``, particle filter only) at the
point that minimises the target's expected OSPA localisation cost ``E[min(|x - y|, c)^p]``
over the posterior (the candidates: the mean and 256 particles drawn from the posterior,
scored on 4,096 others), which OSPA favours over the mean where a posterior is wide.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np
from scipy import stats

from mttbench import scenarios
from mttbench.benchmarks.app import bayes
from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.metrics import ospa
from mttbench.benchmarks.engine.specs import PolicySpec
from mttbench.scenarios.simulator import _reflect as fold  # the truth's own wall rule
from mttbench.trackers.base import Estimate, Tracker
from mttbench.trackers.grid_bayes import GridBayesTracker
from mttbench.trackers.jmpd.resampling import systematic_resample
from mttbench.trackers.params import Param


class GridProduct(Tracker):
    """One ``grid-bayes`` per declared target (the module docstring)."""

    name = "grid-product"
    reference = True
    parameters = {"spacing": Param(float, 0.0, 4.0, low_open=True, doc="grid-bayes spacing")}

    def __init__(self, spacing: float = 1.0) -> None:
        self.spacing = spacing

    def unsupported_reason(self, model) -> str | None:
        bd = model.birth_death
        if bd.birth_rate > 0 or bd.n_random_initial:
            return "needs declared initial targets and no births"
        return None

    def reset(self, model, rng) -> None:
        bd = model.birth_death
        self._subs = []
        for state in bd.initial_states:
            one = dataclasses.replace(model, birth_death=dataclasses.replace(
                bd, initial_states=(tuple(state),)))
            sub = GridBayesTracker(spacing=self.spacing)
            sub.reset(one, rng)
            self._subs.append(sub)

    def predict(self) -> None:
        for sub in self._subs:
            sub.predict()

    def cell_count_distribution(self) -> np.ndarray:
        # the targets' Bernoullis per cell, convolved (independent targets)
        dist = np.ones((self._subs[0]._model.grid.n_cells, 1))
        for sub in self._subs:
            m = sub.cell_count_distribution()[:, 1:2]
            dist = (np.pad(dist, ((0, 0), (0, 1))) * (1.0 - m)
                    + np.pad(dist, ((0, 0), (1, 0))) * m)
        return dist

    def update(self, looks) -> None:
        for sub in self._subs:
            sub.update(looks)

    def estimate(self) -> Estimate:
        moments = [sub.posterior_moments() for sub in self._subs]
        held = [(m, c) for e, m, c in moments if e >= 0.5]
        count = float(sum(e for e, _, _ in moments))
        if not held:
            return Estimate(count, np.zeros((0, 4)), np.zeros((0, 4, 4)), np.zeros(0, np.int64))
        return Estimate(count, np.array([m for m, _ in held]), np.array([c for _, c in held]),
                        np.array([i for i, (e, _, _) in enumerate(moments) if e >= 0.5]))


class ParticleProduct(Tracker):
    """One bootstrap particle filter per declared target (the module docstring)."""

    name = "particle-product"
    reference = True
    parameters = {"n_particles": Param(int, 1, doc="particles per target"),
                  "particle_seed": Param(int, 0, doc="the filters' own seed"),
                  "estimator": Param(str, choices=("mean", "cut"), doc="the point estimate"),
                  "c": Param(float, 0.0, low_open=True, doc="OSPA cut-off"),
                  "p": Param(float, 1.0, doc="OSPA order")}

    def __init__(self, n_particles: int = 200_000, particle_seed: int = 0,
                 estimator: str = "mean", c: float = 2.0, p: float = 2.0) -> None:
        self.n_particles = n_particles
        self.particle_seed = particle_seed
        self.estimator, self.c, self.p = estimator, c, p

    def _cut_point(self, x: np.ndarray) -> np.ndarray:
        """The candidate of least expected ``min(d, c)^p`` over the posterior sample ``x``."""
        pick = self._rng.integers(len(x), size=256 + 4096)
        cand = np.vstack([x.mean(axis=0), x[pick[:256]]])
        sample = x[pick[256:]]
        d = np.hypot(cand[:, None, 0] - sample[None, :, 0], cand[:, None, 2] - sample[None, :, 2])
        return cand[np.argmin((np.minimum(d, self.c) ** self.p).mean(axis=1))]

    unsupported_reason = GridProduct.unsupported_reason

    def reset(self, model, rng) -> None:
        # the filters' own stream (not the loop's), so two particle seeds differ on one world
        self._rng = np.random.default_rng(np.random.SeedSequence(self.particle_seed))
        self._model, n = model, self.n_particles
        bd, dyn = model.birth_death, model.dynamics
        self._F, self._L = dyn.F, np.linalg.cholesky(dyn.Q + 1e-15 * np.eye(4))
        self._x = [np.tile(np.asarray(s, float), (n, 1)) for s in bd.initial_states]
        self._alive = [np.ones(n, dtype=bool) for _ in bd.initial_states]
        self._first = True
        sensor = model.sensor
        pd1, pf = float(sensor.detection_probability(1)), sensor.p_f
        self._lr = (np.log(pd1) - np.log(pf), np.log1p(-pd1) - np.log1p(-pf))

    def predict(self) -> None:
        if self._first:  # the simulator's step 0 holds the initial states, unmoved
            self._first = False
            return
        bd, (width, height) = self._model.birth_death, self._model.grid.extent
        for x, alive in zip(self._x, self._alive, strict=True):
            alive &= self._rng.random(len(x)) < bd.survival_probability
            x[:] = x @ self._F.T + self._rng.standard_normal(x.shape) @ self._L.T
            if bd.boundary == "reflect":
                fold(x[:, 0], x[:, 1], width)
                fold(x[:, 2], x[:, 3], height)
            else:
                alive &= (x[:, 0] >= 0) & (x[:, 0] < width) & (x[:, 2] >= 0) & (x[:, 2] < height)

    def cell_count_distribution(self) -> np.ndarray:
        raise NotImplementedError("a reference for fixed looks (raster) only")

    def update(self, looks) -> None:
        grid = self._model.grid
        lr = np.where(np.asarray(looks.returns, bool), *self._lr)
        log_lam = np.append(np.bincount(np.asarray(looks.cells, np.int64), weights=lr,
                                        minlength=grid.n_cells), 0.0)  # dead: index -1
        for i, (x, alive) in enumerate(zip(self._x, self._alive, strict=True)):
            cell = np.where(alive, grid.cell_of(x[:, 0], x[:, 2]), -1)
            logw = log_lam[cell]
            w = np.exp(logw - logw.max())
            idx = systematic_resample(w / w.sum(), self._rng.random())
            self._x[i], self._alive[i] = x[idx], alive[idx]

    def estimate(self) -> Estimate:
        states, covs, labels, count = [], [], [], 0.0
        for i, (x, alive) in enumerate(zip(self._x, self._alive, strict=True)):
            e = float(alive.mean())
            count += e
            if e >= 0.5:
                live = x[alive]
                states.append(live.mean(axis=0) if self.estimator == "mean"
                              else self._cut_point(live))
                covs.append(np.cov(x[alive].T))
                labels.append(i)
        if not states:
            return Estimate(count, np.zeros((0, 4)), np.zeros((0, 4, 4)), np.zeros(0, np.int64))
        return Estimate(count, np.array(states), np.array(covs), np.array(labels))


def make_filter(method: str, c: float = 2.0, p: float = 2.0) -> Tracker:
    kind, _, rest = method.partition(":")
    if kind == "grid":
        return GridProduct(float(rest or 1.0))
    if kind == "pf":
        n, _, rest = rest.partition(":")
        seed, _, estimator = rest.partition(":")
        return ParticleProduct(int(n or 200_000), int(seed or 0), estimator or "mean", c, p)
    raise SystemExit(f"unknown method {method!r}: grid:SPACING or pf:N[:SEED]")


def parse_seeds(text: str) -> list[int]:
    if ":" in text:
        lo, hi = (int(t) for t in text.split(":"))
        return list(range(lo, hi))
    return [int(t) for t in text.split(",")]


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__.strip().splitlines()[4], file=sys.stderr)
        return 2
    name, seeds = argv[0], parse_seeds(argv[1])
    method = argv[2] if len(argv) > 2 else "grid:1"
    sc = scenarios.get(name)
    ref = bayes.find(sc, PolicySpec.parse("raster"), None, seeds)
    if ref is None:
        raise SystemExit(f"no stored bayes reference of {name} (raster, its own looks) holds "
                         f"seeds {argv[1]}")
    rows, meta = ref.rows, ref.provenance
    c, p = meta["ospa_c"], meta["ospa_p"]
    per_seed, shared_steps = [], 0
    for seed in seeds:
        t0 = time.process_time()
        values = []
        for rec in play(sc, make_filter(method, c, p), seed, n_steps=meta["n_steps"]):
            values.append(ospa(rec.truth[:, [0, 2]], rec.estimate.states[:, [0, 2]],
                               c=c, p=p).total)
            cells = sc.model.grid.cell_of(rec.truth[:, 0], rec.truth[:, 2])
            shared_steps += len(cells) - len(np.unique(cells))
        ref = rows[rows.seed == seed].sort_values("step").ospa.to_numpy()
        if len(ref) != len(values):
            raise SystemExit(f"seed {seed}: the stored reference has {len(ref)} steps, "
                             f"this run {len(values)}")
        per_seed.append((seed, float(np.mean(values)), float(np.mean(ref)),
                         time.process_time() - t0))
        print(f"seed {seed}: {method} {per_seed[-1][1]:.3f}, bayes (jmpd-ap N = "
              f"{meta['n_reference']}) {per_seed[-1][2]:.3f}, {per_seed[-1][3]:.0f} CPU s",
              flush=True)
    g = np.array([r[1] for r in per_seed])
    b = np.array([r[2] for r in per_seed])
    d = g - b
    t = stats.t.ppf(0.975, len(d) - 1) if len(d) > 1 else float("nan")

    def half(x: np.ndarray) -> float:
        return t * x.std(ddof=1) / np.sqrt(len(x)) if len(x) > 1 else float("nan")

    print(f"{name}, seeds {argv[1]}, {method}: {g.mean():.3f} ± "
          f"{half(g):.3f}; bayes {b.mean():.3f} ± {half(b):.3f}; paired {method} - "
          f"bayes {d.mean():+.3f} ± {half(d):.3f}; target pairs sharing a cell, summed over "
          f"steps and seeds: {shared_steps}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

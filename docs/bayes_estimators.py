"""Point estimates read from the same `jmpd-ap` posterior, paired per step (docs/bayes.md).

    python docs/bayes_estimators.py SCENARIO N a:b

The ladder's tracker (`jmpd-ap:n_particles=N,init_fraction=1.0`) on seeds a..b-1, and the
GPF on the same worlds. At every step three estimates are read from the same particles:

* A, `jmpd-ap`'s own: the `round(mean held slots)` slots of largest held mass, each the
  mean of its holders;
* B, the majority rule: every slot held by more than half of the particles;
* C, A's slots at the coordinate-wise median of their holders (robust to holders that
  carry another target's label); `far`, the share of a reported slot's holders more than
  a cell from that median.

Prints per seed the mean OSPA (c = 2 cells, p = 2) of each with A's and the GPF's
localisation and cardinality parts and the mean reported counts, then the paired
differences B - A, C - A and GPF - A with their 95% t intervals.
"""
import sys

import numpy as np
from scipy import stats

from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.metrics import ospa
from mttbench.benchmarks.engine.specs import TrackerSpec, resolve_scenarios

name, n_particles = sys.argv[1], int(sys.argv[2])
seeds = range(*map(int, sys.argv[3].split(":")))
scenario = resolve_scenarios([name])[0]
cell = scenario.model.grid.cell_size
c = 2.0 * cell
XY = [0, 2]


def parts(o) -> tuple[float, float, float]:
    return o.total, o.localisation, o.cardinality


rows = []
for seed in seeds:
    tracker = TrackerSpec.parse(f"jmpd-ap:n_particles={n_particles},init_fraction=1.0").make()
    A, B, C, far, n_a, n_b = [], [], [], [], [], []
    for rec in play(scenario, tracker, seed):
        truth = rec.truth[:, XY]
        held = tracker.valid.sum(axis=0)
        top = np.flatnonzero(held / tracker.valid.shape[0] > 0.5)
        v = tracker.valid[..., None]
        majority = (tracker.pos[:, top] * v[:, top]).sum(axis=0) / held[top][:, None]
        medians = np.zeros((0, 2))
        for t in rec.estimate.labels:
            p = tracker.pos[tracker.valid[:, t], t]
            m = np.median(p, axis=0)
            medians = np.vstack([medians, m])
            far.append(np.mean(np.linalg.norm(p - m, axis=1) > cell))
        A.append(parts(ospa(truth, rec.estimate.states[:, XY], c)))
        B.append(ospa(truth, majority, c).total)
        C.append(ospa(truth, medians, c).total)
        n_a.append(len(rec.estimate.states))
        n_b.append(len(top))
    G = [parts(ospa(r.truth[:, XY], r.estimate.states[:, XY], c))
         for r in play(scenario, TrackerSpec.parse("gpf").make(), seed)]
    a, g = np.mean(A, axis=0), np.mean(G, axis=0)
    rows.append((a[0], np.mean(B), np.mean(C), g[0]))
    print(f"seed {seed}: A {a[0]:.3f} (loc {a[1]:.3f}, card {a[2]:.3f}) B {np.mean(B):.3f} "
          f"C {np.mean(C):.3f} GPF {g[0]:.3f} (loc {g[1]:.3f}, card {g[2]:.3f}); far "
          f"{np.mean(far):.3f}; counts A {np.mean(n_a):.2f} B {np.mean(n_b):.2f}", flush=True)
r = np.array(rows)
print(f"{name} N={n_particles}: means A {r[:, 0].mean():.3f} B {r[:, 1].mean():.3f} "
      f"C {r[:, 2].mean():.3f} GPF {r[:, 3].mean():.3f}")
for j, label in ((1, "B - A"), (2, "C - A"), (3, "GPF - A")):
    d = r[:, j] - r[:, 0]
    lo, hi = stats.t.interval(0.95, len(d) - 1, d.mean(), d.std(ddof=1) / np.sqrt(len(d)))
    print(f"{label} {d.mean():+.3f} [{lo:+.3f}, {hi:+.3f}]")

"""Two point estimates read from the same `jmpd-ap` posterior, paired per step (docs/bayes.md).

    python docs/bayes_estimators.py SCENARIO N a:b

The ladder's tracker (`jmpd-ap:n_particles=N,init_fraction=1.0`) on seeds a..b-1. At every
step two estimates are read from the same particles:

* A, `jmpd-ap`'s own: the `round(mean held slots)` slots of largest held mass;
* B, the majority rule: every slot held by more than half of the particles.

Prints per seed the mean OSPA (c = 2 cells, p = 2) of each and the mean reported counts,
then the paired difference B - A with its 95% t interval over the seeds.
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
c = 2.0 * scenario.model.grid.cell_size
XY = [0, 2]
rows = []
for seed in seeds:
    tracker = TrackerSpec.parse(f"jmpd-ap:n_particles={n_particles},init_fraction=1.0").make()
    own, majority, n_own, n_majority = [], [], [], []
    for rec in play(scenario, tracker, seed):
        held = tracker.valid.sum(axis=0)
        v = tracker.valid[..., None]
        top = np.flatnonzero(held / tracker.valid.shape[0] > 0.5)
        pos = (tracker.pos[:, top] * v[:, top]).sum(axis=0) / held[top][:, None]
        own.append(ospa(rec.truth[:, XY], rec.estimate.states[:, XY], c).total)
        majority.append(ospa(rec.truth[:, XY], pos, c).total)
        n_own.append(len(rec.estimate.states))
        n_majority.append(len(top))
    rows.append((np.mean(own), np.mean(majority)))
    print(f"seed {seed}: A {rows[-1][0]:.3f} B {rows[-1][1]:.3f}, counts A "
          f"{np.mean(n_own):.2f} B {np.mean(n_majority):.2f}", flush=True)
r = np.array(rows)
d = r[:, 1] - r[:, 0]
lo, hi = stats.t.interval(0.95, len(d) - 1, d.mean(), d.std(ddof=1) / np.sqrt(len(d)))
print(f"{name} N={n_particles}: A {r[:, 0].mean():.3f} B {r[:, 1].mean():.3f} "
      f"B - A {d.mean():+.3f} [{lo:+.3f}, {hi:+.3f}]")

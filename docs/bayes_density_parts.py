"""Where the converged reference loses to the GPF on a dense scene (docs/bayes.md).

    python docs/bayes_density_parts.py SCENARIO N a:b

The ladder's tracker (`jmpd-ap:n_particles=N,init_fraction=1.0`) on seeds a..b-1, and the
GPF on the same worlds. Per step: OSPA (c = 2 cells, p = 2) and its localisation and
cardinality parts for A, `jmpd-ap`'s own estimate (each reported slot the mean of its
holders), for C, the same slots at the coordinate-wise median of their holders (robust to
holders that carry another target's label), and for the GPF; `far`, the share of a reported
slot's holders more than a cell from that median. Prints per seed the run means, then the
paired differences C - A and GPF - A with their 95% t intervals.
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
    A, C, far, nA, ntrue = [], [], [], [], []
    for rec in play(scenario, tracker, seed):
        labels = rec.estimate.labels
        truth = rec.truth[:, XY]
        oa = ospa(truth, rec.estimate.states[:, XY], c)
        med = []
        for t in labels:
            h = tracker.valid[:, t]
            p = tracker.pos[h, t]
            m = np.median(p, axis=0)
            med.append(m)
            far.append(np.mean(np.linalg.norm(p - m, axis=1) > scenario.model.grid.cell_size))
        med = np.array(med).reshape(-1, 2)
        oc = ospa(truth, med, c)
        A.append((oa.total, oa.localisation, oa.cardinality))
        C.append((oc.total, oc.localisation, oc.cardinality))
        nA.append(len(labels))
        ntrue.append(len(truth))
    g = TrackerSpec.parse("gpf").make()
    G = []
    for rec in play(scenario, g, seed):
        og = ospa(rec.truth[:, XY], rec.estimate.states[:, XY], c)
        G.append((og.total, og.localisation, og.cardinality))
    A, C, G = map(lambda x: np.array(x).mean(axis=0), (A, C, G))
    rows.append((A[0], C[0], G[0]))
    print(f"seed {seed}: A {A.round(3)} C {C.round(3)} GPF {G.round(3)} far {np.mean(far):.3f} "
          f"count A {np.mean(nA):.2f} true {np.mean(ntrue):.2f}", flush=True)
r = np.array(rows)
for j, lab in ((1, "C - A"), (2, "GPF - A")):
    d = r[:, j] - r[:, 0]
    lo, hi = stats.t.interval(0.95, len(d) - 1, d.mean(), d.std(ddof=1) / np.sqrt(len(d)))
    print(f"{name} N={n_particles}: {lab} {d.mean():+.3f} [{lo:+.3f}, {hi:+.3f}]")
print("means A C GPF", r.mean(axis=0).round(3))

"""Slots that share a target, and targets no estimate holds, over a run (docs/bayes.md).

    python docs/bayes_coalescence.py SCENARIO TRACKER a:b [declared]

Per step, over seeds a..b-1: `orphans`, the true targets with no reported state within one
cell; `dup`, the reported states whose nearest true target is also another state's
nearest. Prints every fourth step's means and the means over steps 30-39. `declared`: each
seed's world starts from its own random initial states declared in the scenario (the
JMPD's `init_fraction=1.0` then starts its particles on them; the world's later draws
differ from the random start's).
"""
import sys
from dataclasses import replace

import numpy as np
from scipy.spatial.distance import cdist

from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.specs import TrackerSpec, resolve_scenarios
from mttbench.scenarios.simulator import simulate_truth

name, spec = sys.argv[1], sys.argv[2]
seeds = range(*map(int, sys.argv[3].split(":")))
base = resolve_scenarios([name])[0]
declared = sys.argv[4:] == ["declared"]
XY = [0, 2]
orphans, dup = {}, {}
for seed in seeds:
    scenario = base
    if declared:
        x0 = simulate_truth(base, seed)[1][0]
        bd = replace(base.model.birth_death, initial_states=tuple(map(tuple, x0)),
                     n_random_initial=0)
        scenario = replace(base, name=f"{name}-declared-{seed}",
                           model=replace(base.model, birth_death=bd))
    tracker = TrackerSpec.parse(spec).make()
    for k, rec in enumerate(play(scenario, tracker, seed)):
        est, truth = rec.estimate.states[:, XY], rec.truth[:, XY]
        o = d = 0
        if len(est) and len(truth):
            dist = cdist(truth, est)
            o = int(np.sum(dist.min(axis=1) > base.model.grid.cell_size))
            nearest = dist.argmin(axis=0)
            d = len(nearest) - len(np.unique(nearest))
        else:
            o = len(truth)
        orphans[k] = orphans.get(k, 0) + o
        dup[k] = dup.get(k, 0) + d
n = len(seeds)
for k in range(0, len(orphans), 4):
    print(f"step {k}: orphans {orphans[k] / n:.2f} dup {dup[k] / n:.2f}")
late = [k for k in orphans if 30 <= k < 40]
label = f"{name}{' declared' if declared else ''} {spec}"
print(f"{label} steps 30-39: orphans {sum(orphans[k] for k in late) / n / len(late):.2f} "
      f"dup {sum(dup[k] for k in late) / n / len(late):.2f}")

"""How often `jmpd-ap` samples every target of a scene jointly (docs/bayes.md).

    python docs/jmpd_ap_clusters.py SCENARIO N a:b

`jmpd-ap:n_particles=N,init_fraction=1.0` (the reference ladder's tracker) on seeds a..b-1.
Per seed: the mean OSPA (c = 2 cells, p = 2), the share of steps whose largest cluster
holds every active slot (all targets sampled as one joint state) and the mean number of
clusters per step.
"""
import sys

import numpy as np

from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.metrics import ospa
from mttbench.benchmarks.engine.specs import TrackerSpec, resolve_scenarios

name, n_particles = sys.argv[1], int(sys.argv[2])
seeds = range(*map(int, sys.argv[3].split(":")))
scenario = resolve_scenarios([name])[0]
c = 2.0 * scenario.model.grid.cell_size
for seed in seeds:
    tracker = TrackerSpec.parse(f"jmpd-ap:n_particles={n_particles},init_fraction=1.0").make()
    errors, joint, clusters = [], [], []
    for rec in play(scenario, tracker, seed):
        errors.append(ospa(rec.truth[:, [0, 2]], rec.estimate.states[:, [0, 2]], c).total)
        joint.append(tracker.n_clusters == 1 and tracker.largest_cluster > 1)
        clusters.append(tracker.n_clusters)
    print(f"{name} N={n_particles} seed {seed}: OSPA {np.mean(errors):.3f}, every target in "
          f"one cluster on {np.mean(joint):.2f} of the steps, {np.mean(clusters):.1f} "
          "clusters per step", flush=True)

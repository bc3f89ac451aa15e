"""Rows of ``run_job`` without the timings, to compare two versions of the code bit for bit
(docs/nonmyopic.md, "Sameness").

Usage: ``python docs/nonmyopic_sameness.py OUT.parquet [small|sparse]``; run it once
with this tree and once with another version importable first as ``mttbench`` (e.g. a
tree laid out as the installed package on ``PYTHONPATH``), then compare the two files
with ``pandas.DataFrame.equals``. ``small``: ``default``, ``crossing`` and ``births`` at
25 steps, seeds 0-1, trackers gpf, jmpd-ap (300 particles) and pmb under raster, random,
renyi, renyi with repeats, oracle and all at 24 looks. ``sparse``: ``large`` (8 steps)
and ``scale`` (5 steps, 250000 cells: the sparse gains), gpf and pmb under renyi, renyi
with repeats, random and oracle at the preset's looks.
"""

import dataclasses
import sys

import pandas as pd

from mttbench import scenarios
from mttbench.benchmarks.engine.loop import TIMING_COLUMNS, Job, run_job
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec

SETS = {
    "small": ([("default", 25), ("crossing", 25), ("births", 25)],
              ["gpf", "jmpd-ap:n_particles=300", "pmb"],
              ["raster", "random", "renyi", "renyi:repeats=true", "oracle", "all"], 24),
    "sparse": ([("large", 8), ("scale", 5)], ["gpf", "pmb"],
               ["renyi", "renyi:repeats=true", "random", "oracle"], None),
}

out, which = sys.argv[1], (sys.argv[2] if len(sys.argv) > 2 else "small")
presets, trackers, policies, looks = SETS[which]
frames = []
for preset, steps in presets:
    sc = dataclasses.replace(scenarios.get(preset), n_steps=steps)
    for tr in trackers:
        for pol in policies:
            for seed in (0, 1):
                job = Job(sc, TrackerSpec.parse(tr).validated(),
                          PolicySpec.parse(pol).validated(), looks, seed)
                frames.append(run_job(job).drop(columns=[*TIMING_COLUMNS, "peak_rss_mb"]))
table = pd.concat(frames, ignore_index=True)
table.to_parquet(out)
print(f"{len(table)} rows, {(table['status'] == 'ok').mean():.4f} ok -> {out}")

"""Policies head to head on one scenario, paired over seeds (docs/nonmyopic.md).

Usage::

    python docs/nonmyopic_explore.py SCENARIO TRACKER SEEDS POLICY [POLICY ...]
        [--looks M] [--name NAME] [--band WIDTH,SPEED]

``SCENARIO`` a preset name or a .toml path; ``TRACKER`` a spec (``gpf``,
``jmpd-ap:n_particles=500,init_fraction=0.1``); ``SEEDS`` ``a:b`` (seeds a..b-1); each
``POLICY`` a spec (``renyi``, ``lookahead:horizon=5``). ``--looks`` replaces the
sensor's looks per step, ``--name`` renames the scenario (the world is keyed on the
name: another name, other worlds), ``--band`` replaces the occlusions by one vertical
band of WIDTH columns moving SPEED cells per step over the whole run. Prints, per
policy, each seed's mean OSPA (c = 2, p = 2) over steps >= 10, their mean and median,
and the paired difference against the first policy with its 95% t interval.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
from scipy import stats

from mttbench import scenarios
from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.metrics import ospa
from mttbench.benchmarks.engine.policies import make_policy
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec
from mttbench.scenarios.model import Occlusion, Visibility
from mttbench.trackers import make as make_tracker

BURN_IN = 10


def run_error(sc, tracker_spec: TrackerSpec, policy_spec: PolicySpec, seed: int) -> float:
    tracker = make_tracker(tracker_spec.name, **tracker_spec.params)
    policy = make_policy(policy_spec.name, **policy_spec.params)
    errors = []
    for rec in play(sc, tracker, seed, policy=policy):
        est = rec.estimate.states
        est_xy = est[:, [0, 2]] if len(est) else np.zeros((0, 2))
        errors.append(ospa(rec.truth[:, [0, 2]], est_xy, 2.0, 2.0).total)
    return float(np.mean(errors[BURN_IN:]))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenario")
    ap.add_argument("tracker")
    ap.add_argument("seeds")
    ap.add_argument("policies", nargs="+")
    ap.add_argument("--looks", type=int)
    ap.add_argument("--name")
    ap.add_argument("--band")
    a = ap.parse_args()
    sc = scenarios.get(a.scenario)
    model = sc.model
    if a.looks is not None:
        model = dataclasses.replace(model, sensor=dataclasses.replace(model.sensor,
                                                                      looks_per_step=a.looks))
    if a.band:
        width, speed = a.band.split(",")
        band = Occlusion((0, int(width) - 1), (0, sc.grid.ny - 1), (0, sc.n_steps - 1),
                         velocity=(float(speed), 0.0))
        model = dataclasses.replace(model, visibility=Visibility((band,)))
    sc = dataclasses.replace(sc, model=model, name=a.name or sc.name)
    first, _, last = a.seeds.partition(":")
    seeds = range(int(first), int(last))
    tracker = TrackerSpec.parse(a.tracker).validated()
    specs = [PolicySpec.parse(p).validated() for p in a.policies]
    errors = {p.label: np.array([run_error(sc, tracker, p, s) for s in seeds]) for p in specs}
    print(f"{sc.name}, {tracker.label}, {model.sensor.looks_per_step} looks, seeds {a.seeds}")
    for label, e in errors.items():
        print(f"  {label}: mean {e.mean():.3f}, median {np.median(e):.3f}")
    base = errors[specs[0].label]
    for p in specs[1:]:
        d = errors[p.label] - base
        half = stats.t.ppf(0.975, d.size - 1) * d.std(ddof=1) / np.sqrt(d.size)
        print(f"  {p.label} - {specs[0].label}: {d.mean():+.3f} "
              f"[{d.mean() - half:+.3f}, {d.mean() + half:+.3f}]")


if __name__ == "__main__":
    main()

"""Policies head to head on one scenario, paired over seeds (docs/nonmyopic.md).

Usage::

    python docs/nonmyopic_explore.py SCENARIO TRACKER SEEDS POLICY [POLICY ...]
        [--looks M] [--name NAME] [--band WIDTH,SPEED] [--targets N] [--blind D]

``SCENARIO`` a preset name or a .toml path; ``TRACKER`` a spec (``gpf``,
``jmpd-ap:n_particles=500,init_fraction=0.1``); ``SEEDS`` ``a:b`` (seeds a..b-1); each
``POLICY`` a spec (``renyi``, ``lookahead:horizon=5``). ``--looks`` replaces the
sensor's looks per step, ``--name`` renames the scenario (the world is keyed on the
name: another name, other worlds), ``--band`` replaces the occlusions by one vertical
band of WIDTH columns moving SPEED cells per step over the whole run, ``--targets``
keeps the first N of the preset's targets followed by :data:`EXTRA_TARGETS` (one more
per quadrant in turn), ``--blind`` makes every occlusion last D steps from its first
(the quadrant cycle's period stays 10 steps). Prints, per policy, each seed's mean
OSPA (c = 2, p = 2) over steps >= 10, their mean and median, how often a target was
looked at just before its cell went blind (:func:`run_error`), and the paired
difference against the first policy with its 95% t interval.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
from scipy import stats

from mttbench import scenarios
from mttbench.benchmarks.engine.information import expected_gain
from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.metrics import ospa
from mttbench.benchmarks.engine.policies import Policy, make_policy
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec
from mttbench.scenarios.model import Occlusion, Visibility
from mttbench.trackers import make as make_tracker
from mttbench.trackers.cells import CellCounts

BURN_IN = 10
#: further targets for ``--targets``, ~0.1 cell/step, one per quadrant in turn
EXTRA_TARGETS = ((2.5, 0.06, 8.5, -0.08), (4.5, 0.05, 1.5, 0.08), (9.5, -0.07, 7.5, 0.05),
                 (10.5, -0.06, 4.5, -0.05), (1.5, 0.08, 10.5, -0.04), (3.5, -0.05, 4.5, 0.06),
                 (7.5, 0.07, 10.5, -0.05), (7.5, -0.04, 1.5, 0.07), (4.5, 0.05, 7.5, 0.05))


class RefreshOracle(Policy):
    """REFERENCE ONLY -- USES THE TRUTH (not registered). The looks ``renyi`` would make,
    except that the cells of the true targets that are visible now and blind at the
    next step come first (at most ``M``, at random if more): what a perfect "look at
    the target before it disappears" can gain over ``renyi``, an upper bound for any
    visibility value-to-go that only moves looks onto targets about to go blind."""

    name = "refresh-oracle"
    uses_truth = True
    uses_prediction = True

    def select(self, k, counts=None, truth_cells=None):
        P = counts.dense() if isinstance(counts, CellCounts) else np.asarray(counts, float)
        gain = expected_gain(P, self._model.sensor.detection_probability(
            np.arange(P.shape[1])), 0.5)
        gain[self.blocked_cells(k)] = -np.inf
        truth = np.unique(np.asarray(truth_cells, dtype=np.int64))
        truth = truth[(truth >= 0) & np.isin(truth, self._model.blocked_cells(k + 1))
                      & ~np.isin(truth, self.blocked_cells(k))]
        first = self._rng.permutation(truth)[:self._n_looks]
        gain[first] = np.inf
        return np.sort(np.argsort(-gain, kind="stable")[:self._n_looks]).astype(np.int64)


def make(policy_spec: PolicySpec) -> Policy:
    if policy_spec.name == RefreshOracle.name:
        return RefreshOracle()
    return make_policy(policy_spec.name, **policy_spec.params)


def parse(text: str) -> PolicySpec:
    if text == RefreshOracle.name:
        return PolicySpec(text, {})
    return PolicySpec.parse(text).validated()


def run_error(sc, tracker_spec: TrackerSpec, policy_spec: PolicySpec,
              seed: int) -> tuple[float, int, int]:
    """The run's mean OSPA over steps >= BURN_IN, and its refreshes before a blackout:
    of the (step, target) pairs whose target's cell is visible at the step and blind at
    the next (``chances``), those in which a look was made at the target's cell
    (``refreshed``). The truth is read here to diagnose, never by the policy."""
    tracker = make_tracker(tracker_spec.name, **tracker_spec.params)
    policy = make(policy_spec)
    errors, refreshed, chances = [], 0, 0
    for rec in play(sc, tracker, seed, policy=policy):
        est = rec.estimate.states
        est_xy = est[:, [0, 2]] if len(est) else np.zeros((0, 2))
        errors.append(ospa(rec.truth[:, [0, 2]], est_xy, 2.0, 2.0).total)
        if len(rec.truth):
            cells = sc.grid.cell_of(rec.truth[:, 0], rec.truth[:, 2])
            soon = np.isin(cells, sc.model.blocked_cells(rec.k + 1))
            soon &= ~np.isin(cells, sc.model.blocked_cells(rec.k))
            chances += int(soon.sum())
            refreshed += int(np.isin(cells[soon], rec.looks.cells).sum())
    return float(np.mean(errors[BURN_IN:])), refreshed, chances


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenario")
    ap.add_argument("tracker")
    ap.add_argument("seeds")
    ap.add_argument("policies", nargs="+")
    ap.add_argument("--looks", type=int)
    ap.add_argument("--name")
    ap.add_argument("--band")
    ap.add_argument("--targets", type=int)
    ap.add_argument("--blind", type=int)
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
    if a.targets is not None:
        states = (tuple(model.birth_death.initial_states) + EXTRA_TARGETS)[:a.targets]
        model = dataclasses.replace(model, birth_death=dataclasses.replace(
            model.birth_death, initial_states=states))
    if a.blind is not None:
        occ = tuple(dataclasses.replace(o, steps=(o.steps[0], o.steps[0] + a.blind - 1))
                    for o in model.visibility.occlusions)
        model = dataclasses.replace(model, visibility=Visibility(occ))
    sc = dataclasses.replace(sc, model=model, name=a.name or sc.name)
    first, _, last = a.seeds.partition(":")
    seeds = range(int(first), int(last))
    tracker = TrackerSpec.parse(a.tracker).validated()
    specs = [parse(p) for p in a.policies]
    runs = {p.label: [run_error(sc, tracker, p, s) for s in seeds] for p in specs}
    errors = {label: np.array([r[0] for r in rs]) for label, rs in runs.items()}
    blind = {o.steps[1] - o.steps[0] + 1 for o in model.visibility.occlusions}
    print(f"{sc.name}, {tracker.label}, {model.sensor.looks_per_step} looks, seeds {a.seeds}, "
          f"{len(model.birth_death.initial_states)} targets, blind {sorted(blind)} steps")
    for label, e in errors.items():
        hits, chances = (sum(r[i] for r in runs[label]) for i in (1, 2))
        print(f"  {label}: mean {e.mean():.3f}, median {np.median(e):.3f}, refreshed "
              f"before a blackout {hits}/{chances}")
    base = errors[specs[0].label]
    for p in specs[1:]:
        d = errors[p.label] - base
        half = stats.t.ppf(0.975, d.size - 1) * d.std(ddof=1) / np.sqrt(d.size)
        print(f"  {p.label} - {specs[0].label}: {d.mean():+.3f} "
              f"[{d.mean() - half:+.3f}, {d.mean() + half:+.3f}]")


if __name__ == "__main__":
    main()

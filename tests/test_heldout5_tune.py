"""Tune's per-trial sampler seeds: a study's trials, and the trials of studies seeded
differently, draw from distinct streams (the documented ``SeedSequence([seed, number])``:
no two (seed, number) pairs share a seed), and the same pair always gives the same one."""

from __future__ import annotations

import itertools

from mttbench.benchmarks.app.tune import trial_seed


def test_no_two_seed_and_trial_number_pairs_share_a_sampler_seed():
    pairs = list(itertools.product(range(25), range(25)))
    seeds = [trial_seed(s, n) for s, n in pairs]
    assert len(set(seeds)) == len(pairs)
    assert seeds == [trial_seed(s, n) for s, n in pairs]
    assert all(0 <= x < 2**32 for x in seeds)

"""JMPDTracker.unsupported_reason: a scenario whose expected target count exceeds
``t_max`` is refused (the rule is in the method's docstring)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mttbench import scenarios, trackers
from mttbench.scenarios.simulator import simulate_truth
from mttbench.trackers.jmpd import JMPDIPTracker, JMPDTracker
from mttbench.trackers.jmpd.tracker import default_t_max

BASE = scenarios.get("default")


def _scenario(n0: int, p_s: float, b: float, n_steps: int | None = None):
    """``default`` with ``n0`` random initial targets, survival ``p_s`` and birth rate ``b``."""
    bd = dataclasses.replace(BASE.model.birth_death, initial_states=(), n_random_initial=n0,
                             survival_probability=p_s, birth_rate=b)
    return dataclasses.replace(BASE, name="support-check",
                               model=dataclasses.replace(BASE.model, birth_death=bd),
                               n_steps=BASE.n_steps if n_steps is None else n_steps)


# (n0, p_s, b, peak expected count): the peak is the largest t_max refused + 1
CASES = [
    (4, 1.0, 0.0, 4),      # no births, no deaths: the initial count
    (4, 0.9, 0.01, 4),     # deaths: the count falls from 4 towards 0.1
    (0, 0.9, 0.5, 5),      # births: the count rises from 0 towards 0.5 / 0.1 = 5
    (2, 0.98, 0.05, 2.5),  # the `births` preset: stationary 2.5 above the initial 2
    (2, 1.0, 0.03, 5),     # p_s = 1 with births: 2 + 100 * 0.03 at the 100-step horizon
]


@pytest.mark.parametrize("n0, p_s, b, peak", CASES)
@pytest.mark.parametrize("cls", [JMPDTracker, JMPDIPTracker])
def test_refused_exactly_above_the_peak_expected_count(cls, n0, p_s, b, peak):
    model = _scenario(n0, p_s, b).model
    fits = int(np.ceil(peak))
    assert cls(t_max=fits).unsupported_reason(model) is None
    assert cls(t_max=fits + 3).unsupported_reason(model) is None
    reason = cls(t_max=fits - 1).unsupported_reason(model)
    assert isinstance(reason, str) and "\n" not in reason
    assert f"t_max = {fits - 1}" in reason and f"t_max >= {fits}" in reason


def test_large_preset_needs_t_max_25():
    """25 targets, no births or deaths: t_max = 5 is refused, 25 fits, and the default
    (t_max from the model) fits."""
    model = scenarios.get("large").model
    for name in ("jmpd", "jmpd-ip"):
        assert "expected target count 25" in trackers.make(name, t_max=5).unsupported_reason(
            model)
        assert trackers.make(name, t_max=25).unsupported_reason(model) is None
        assert trackers.make(name, t_max=24).unsupported_reason(model) is not None
        assert trackers.make(name).unsupported_reason(model) is None


def _poisson_quantile_by_summation(mean: float, q: float) -> int:
    """The smallest t with sum_{k <= t} e^-mean mean^k / k! >= q, by summing the pmf."""
    t, term = 0, math.exp(-mean)
    total = term
    while total < q:
        t += 1
        term *= mean / t
        total += term
    return t


@pytest.mark.parametrize("n0, p_s, b, peak", CASES + [(9, 1.0, 0.0, 9), (0, 0.99, 0.25, 25)])
def test_default_t_max_is_the_poisson_quantile_of_the_peak(n0, p_s, b, peak):
    """Without ``t_max`` a particle gets the 99% Poisson quantile of the expected peak
    (checked against the pmf summed by hand) and reset allocates that many slots."""
    sc = _scenario(n0, p_s, b)
    want = _poisson_quantile_by_summation(peak, 0.99)
    assert default_t_max(sc.model) == want
    tr = JMPDTracker(n_particles=20)
    assert tr.unsupported_reason(sc.model) is None
    tr.reset(sc.model, np.random.default_rng(0))
    assert tr.mask.shape == (20, want)
    assert JMPDTracker(n_particles=20, initial_count=want + 3)._slots(sc.model) == want + 3


@pytest.mark.parametrize("preset", ["default", "crossing", "births", "paper", "superposition"])
def test_default_jmpd_runs_the_small_presets(preset):
    model = scenarios.get(preset).model
    assert JMPDTracker().unsupported_reason(model) is None
    assert JMPDIPTracker().unsupported_reason(model) is None


def test_expected_count_formula_matches_the_simulator():
    """The rule's ``m(k) = n0 p_s^k + b (1 - p_s^k) / (1 - p_s)`` is the simulator's mean
    count: 400 worlds of n0 = 8, p_s = 0.9, b = 0.3 (falling from 8 to the stationary 3;
    reflecting walls, so no other deaths). Each mean is within 4 standard errors of m(k)
    (standard error from the sample's own spread; a false failure has probability
    ~1e-4 per step checked)."""
    n0, p_s, b, n_worlds, steps = 8, 0.9, 0.3, 400, (0, 3, 10, 39)
    sc = _scenario(n0, p_s, b, n_steps=40)
    counts = np.array([[len(s) for s in simulate_truth(sc, seed)[1]]
                       for seed in range(n_worlds)])  # (worlds, steps)
    for k in steps:
        m = n0 * p_s**k + b * (1 - p_s**k) / (1 - p_s)
        mean, se = counts[:, k].mean(), counts[:, k].std(ddof=1) / np.sqrt(n_worlds)
        assert abs(mean - m) <= 4 * max(se, 1e-12), (k, mean, m, se)

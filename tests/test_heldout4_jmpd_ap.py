"""jmpd-ap's lazy undetected-arrival intensity over several steps without a look: the
recurrence ``u <- p_s u + alpha`` per step (docstring step 6 of trackers/jmpd/ap.py),
iterated here step by step, against the tracker's closed form for gaps of 1 to 6 steps."""

from __future__ import annotations

import numpy as np
import pytest
from test_jmpd_ap import BIRTH_STD, _model, _tracker


@pytest.mark.parametrize("p_s", [1.0, 0.9, 0.5])
def test_undetected_arrivals_follow_the_survival_recurrence_over_several_steps(p_s):
    mu, nx = 0.6, 2
    alpha = mu / nx  # arrivals per cell and step
    model = _model(nx, birth_rate=mu, survival_probability=p_s, birth_velocity_std=BIRTH_STD)
    t = _tracker(model, 3, n_particles=8)
    t._k = 10
    u0 = np.array([0.0, 0.7, 2.0])
    for gap in range(1, 7):
        want = u0.copy()
        for _ in range(gap):
            want = p_s * want + alpha
        got = t._arrival_intensity(u0, np.full(3, 10 - gap))
        np.testing.assert_allclose(got, want, rtol=1e-12)

"""The shared Kalman helpers' gate (``mttbench.trackers.kalman.gate_d2``)."""

from __future__ import annotations

import numpy as np
import pytest

from mttbench.trackers import kalman


@pytest.mark.parametrize("p", [0.5, 0.9, 0.99, 0.999])
def test_gate_d2_is_the_chi_square_quantile(p):
    """Closed forms: with 2 degrees of freedom P(d^2 < g) = 1 - exp(-g/2); with 1, the
    squared standard normal, g = ndtri((1 + p) / 2)^2."""
    from scipy.special import ndtri

    assert kalman.gate_d2(p) == pytest.approx(-2.0 * np.log1p(-p), rel=1e-12)
    assert kalman.gate_d2(p, 1) == pytest.approx(ndtri((1.0 + p) / 2.0) ** 2, rel=1e-10)


def test_gate_d2_equals_scipy_stats_chi2_ppf_bit_for_bit():
    """The same numbers as ``scipy.stats.chi2.ppf`` (what the gate was), so no run moves."""
    from scipy.stats import chi2

    ps = np.r_[np.linspace(0.0, 1.0, 2001), 0.95, 0.99, 0.999, 0.9999, 1e-300]
    for dim in range(1, 7):
        gates = np.array([kalman.gate_d2(p, dim) for p in ps])
        np.testing.assert_array_equal(gates, chi2.ppf(ps, dim), err_msg=f"dim {dim}")

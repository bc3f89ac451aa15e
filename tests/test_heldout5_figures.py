"""The snapshot figure's 95% covariance ellipse, against an independent reference: the
ellipse's own boundary points put back into the Gaussian's Mahalanobis distance."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from mttbench.benchmarks.app import figures


@pytest.mark.parametrize(("cxx", "cxy", "cyy"), [
    (4.0, 0.0, 1.0), (1.0, 0.0, 4.0), (2.0, 1.2, 1.0), (1.0, -0.7, 3.0), (2.0, 1.9, 2.0)])
def test_the_snapshot_ellipse_is_the_gaussians_95_percent_contour(cxx, cxy, cyy):
    """Every point of the drawn ellipse lies at squared Mahalanobis distance
    chi2_{0.95, 2} from the mean under the given covariance."""
    P = np.array([[cxx, cxy], [cxy, cyy]])
    ell = figures._cov_ellipse(3.0, -1.0, cxx, cxy, cyy)
    theta = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    circle = np.stack([np.cos(theta), np.sin(theta)], axis=1)  # the patch's unit circle
    pts = ell.get_patch_transform().transform(circle)
    d = pts - np.array([3.0, -1.0])
    m2 = np.einsum("ij,jk,ik->i", d, np.linalg.inv(P), d)
    np.testing.assert_allclose(m2, stats.chi2.ppf(0.95, 2), rtol=1e-6)

"""The figures' statistics: the 95% band of the over-time figures and the snapshot's 95%
covariance ellipse, against independent references (scipy's t interval; the ellipse's
own boundary points put back into the Gaussian's Mahalanobis distance)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mttbench.benchmarks.app import figures


def test_the_over_time_band_is_scipys_t_interval_over_the_ok_seeds():
    """Per tracker and step: the mean over seeds of the ok rows with a finite value and
    the half-width of scipy's 95% t interval (sample sd); one seed: no band."""
    rng = np.random.default_rng(3)
    rows = []
    for seed in range(5):
        for step in range(3):
            for lab in ("a", "b"):
                rows.append({"scenario": "s", "tracker_label": lab, "seed": seed,
                             "step": step, "status": "ok", "ospa": rng.random()})
    df = pd.DataFrame(rows)
    df.loc[(df["tracker_label"] == "b") & (df["step"] == 2) & (df["seed"] > 0),
           "status"] = "error"
    df.loc[(df["tracker_label"] == "a") & (df["step"] == 1) & (df["seed"] == 4), "ospa"] = np.nan
    st = figures.step_stats(df, "ospa").set_index(["tracker_label", "step"])
    for (lab, step), g in df.groupby(["tracker_label", "step"]):
        v = g.loc[(g["status"] == "ok") & g["ospa"].notna(), "ospa"].to_numpy()
        row = st.loc[(lab, step)]
        assert row["n"] == len(v)
        assert row["mean"] == pytest.approx(v.mean(), rel=1e-12)
        if len(v) < 2:
            assert np.isnan(row["ci95"])
            continue
        lo, hi = stats.t.interval(0.95, len(v) - 1, loc=v.mean(), scale=stats.sem(v))
        assert row["ci95"] == pytest.approx((hi - lo) / 2, rel=1e-10)


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

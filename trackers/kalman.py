"""Kalman filter steps batched over a leading axis of components.

Means ``m (K, d)``, covariances ``P (K, d, d)``. Used by KF-NN and the GPF; the
equations are the textbook ones (paper Section III-B), written once here, with the
two helpers both trackers need for the state layout ``[px, vx, py, vy]``.
"""

from __future__ import annotations

import numpy as np

#: indices of ``px``, ``py`` in the state ``[px, vx, py, vy]``
POSITION = np.array([0, 2])
POSITION.flags.writeable = False


def position_marginal(m: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The position part of each state: means ``(K, 2)`` and covariances ``(K, 2, 2)`` (copies)."""
    # POSITION (0, 2) as slices: a copy by slicing costs half of one by fancy indexing
    return m[:, 0:3:2].copy(), P[:, 0:3:2, 0:3:2].copy()


def at_rest(positions: np.ndarray) -> np.ndarray:
    """States ``(n, 4)`` at ``positions (n, 2)`` (rows ``(px, py)``) with zero velocity."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    m = np.zeros((len(positions), 4))
    m[:, POSITION] = positions
    return m


def predict(m: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """``m <- F m``, ``P <- F P F^T + Q`` for every component. Shapes kept."""
    return m @ F.T, F @ P @ F.T + Q


def update(m: np.ndarray, P: np.ndarray, z: np.ndarray, H: np.ndarray, R: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Kalman update of each component with its own measurement.

    ``z (K, r)`` (one measurement per component), ``H (r, d)``, ``R (r, r)`` or
    ``(K, r, r)``. Returns the posterior ``m (K, d)``, ``P (K, d, d)`` (Joseph form,
    so it stays symmetric positive definite), the innovation ``y (K, r)`` and its
    covariance ``S (K, r, r)``.
    """
    # y = z - H m ; S = H P H^T + R ; K = P H^T S^-1
    y = z - m @ H.T
    PHt = P @ H.T
    S = H @ PHt + R
    gain = PHt @ inverse(S)
    m_post = m + (gain @ y[..., None])[..., 0]
    # Joseph form: (I - K H) P (I - K H)^T + K R K^T
    A = np.eye(P.shape[-1]) - gain @ H
    P_post = A @ P @ np.swapaxes(A, -1, -2) + gain @ R @ np.swapaxes(gain, -1, -2)
    P_post = 0.5 * (P_post + np.swapaxes(P_post, -1, -2))
    return m_post, P_post, y, S


def inverse(S: np.ndarray) -> np.ndarray:
    """``S^-1`` over leading axes; a 2x2 (a position covariance, the common case) by its
    closed form ``[[d, -b], [-c, a]] / (a d - b c)``, larger ones by ``numpy.linalg.inv``."""
    if S.shape[-1] != 2:
        return np.linalg.inv(S)
    a, b, c, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
    det = a * d - b * c
    out = np.empty(S.shape)
    out[..., 0, 0], out[..., 0, 1] = d / det, -b / det
    out[..., 1, 0], out[..., 1, 1] = -c / det, a / det
    return out


def gate_d2(probability: float, dim: int = 2) -> float:
    """The gate on the squared Mahalanobis distance that a ``dim``-dimensional Gaussian
    innovation passes with ``probability``: the chi-square quantile ``chi2.ppf(probability,
    dim)``, computed as scipy.stats does it, ``2 gammaincinv(dim / 2, probability)``, from
    scipy.special: importing scipy.stats costs every process that gates about 0.8 s."""
    from scipy.special import gammaincinv

    return float(2.0 * gammaincinv(dim / 2.0, probability))


def mahalanobis_sq(y: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``y^T S^-1 y`` over broadcast leading axes; ``y (..., r)``, ``S (..., r, r)``."""
    if S.shape[-1] == 2:  # closed form: (d y0^2 - (b + c) y0 y1 + a y1^2) / det
        a, b, c, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
        y0, y1 = y[..., 0], y[..., 1]
        return (d * y0 * y0 - (b + c) * y0 * y1 + a * y1 * y1) / (a * d - b * c)
    return np.einsum("...i,...i->...", y, np.linalg.solve(S, y[..., None])[..., 0])

"""The motion model's discretisation against an independent reference.

``Dynamics`` gives the nearly-constant-velocity model's ``F`` and, from a white-noise
acceleration intensity ``q``, its ``Q``. The reference is Van Loan's method (1978): with
the continuous model ``dx = A x dt + G dW``, ``E[dW dW^T] = q dt``, the matrix exponential
``expm([[-A, G q G^T], [0, A^T]] tau) = [[., M12], [0, M22]]`` gives ``F = M22^T`` and
``Q = M22^T M12``: the integral ``int_0^tau e^{A s} G q G^T e^{A^T s} ds`` computed by scipy,
no closed form of ours involved. Time steps other than 1 make every power of ``tau`` show.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from mttbench.scenarios.model import Dynamics


def _van_loan(tau: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """``(F, Q)`` of ``x = [px, vx, py, vy]`` with a white acceleration of intensity ``q`` on
    each axis, by Van Loan's matrix exponential."""
    A = np.zeros((4, 4))
    A[0, 1] = A[2, 3] = 1.0
    G = np.zeros((4, 2))
    G[1, 0] = G[3, 1] = 1.0
    big = np.zeros((8, 8))
    big[:4, :4] = -A
    big[:4, 4:] = G @ (q * np.eye(2)) @ G.T
    big[4:, 4:] = A.T
    E = expm(big * tau)
    F = E[4:, 4:].T
    return F, F @ E[:4, 4:]


@pytest.mark.parametrize("tau, q", [(0.5, 0.01), (1.0, 0.3), (2.0, 0.01), (3.7, 2.5)])
def test_transition_and_process_noise_equal_van_loans_integral(tau: float, q: float) -> None:
    dyn = Dynamics(tau=tau, wna_intensity=q)
    F, Q = _van_loan(tau, q)
    np.testing.assert_allclose(dyn.F, F, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(dyn.Q, Q, rtol=1e-10, atol=1e-14 * q)
    np.testing.assert_allclose(dyn.Q, dyn.Q.T, rtol=0, atol=0)

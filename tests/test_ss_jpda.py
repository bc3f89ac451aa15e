"""``ss-jpda`` (trackers/stonesoup/jpda.py): Stone Soup's JPDA with EHM, tracks by
existence from the model.

* The conformance kit (:func:`mttbench.testing.check_tracker`), one item per check.
* The association against references written here with numpy/scipy, independent of Stone
  Soup: one track and two detections in its gate (existence 1: the PDA posterior, through
  Stone Soup's JPDA; existence 0.6: JIPDA's existence and mixture, the tentative path); two
  confirmed tracks sharing two detections against brute-force enumeration of the joint
  association events.
* Initiation follows the model: a first detection's existence is the closed form of the
  undetected intensity against ``p_f``; it is reported on a clean sensor and not at
  ``p_f = 0.3``. No explosion at ``p_f = 0.3``: bounded tracks and count.
* Determinism across processes with different hash seeds.

Skipped (with the reason) when Stone Soup is not installed.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.stats import chi2, multivariate_normal

from mttbench import testing
from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.specs import TrackerSpec, resolve_scenarios
from mttbench.scenarios.model import Looks
from mttbench.scenarios.spec import get as get_scenario
from mttbench.trackers.stonesoup.jpda import StoneSoupJPDA

pytest.importorskip("stonesoup", minversion="1.9",
                    reason="needs the stonesoup extra: pip install 'mttbench[stonesoup]'")

#: one tolerance for the closed-form comparisons (absolute, on states and probabilities)
TOL = 1e-9
H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])


@testing.parametrize_with_checks([StoneSoupJPDA])
def test_conformance_kit(tracker_class, check, kit):
    kit.run(tracker_class, check)  # check(tracker_class), once per session (tests/conftest.py)


# ------------------------------------------------------------------ references
def _started(tracker: StoneSoupJPDA, m, P, r, confirmed):
    """``tracker`` on ``default``'s model with the given tracks at step 0, predicted to
    step 1; returns the model."""
    model = get_scenario("default").model
    tracker.reset(model, np.random.default_rng(0))
    tracker.predict()
    tracker.set_tracks(m, P, r, confirmed)
    tracker.predict()
    return model


def _block(ix: int, iy: int, nx: int = 12) -> np.ndarray:
    """The 3x3 cells around cell ``(ix, iy)``, sorted."""
    return np.sort([(iy + dy) * nx + ix + dx for dy in (-1, 0, 1) for dx in (-1, 0, 1)])


def _jipda_reference(m, P, r, z, model, p_g):
    """One track ``(m (4,), P (4, 4))`` of existence ``r``, detections ``z (D, 2)`` all in
    its gate, every cell of its mass looked at once: JIPDA (PDA when ``r = 1``) by hand.
    Returns the posterior existence, mean and covariance."""
    F, Q = model.dynamics.F, model.dynamics.Q
    p_f = model.sensor.p_f
    p_d = (model.sensor.p_d - p_f) / (1 - p_f)  # a target's detection beside the clutter
    kappa = p_f / model.grid.cell_size ** 2
    R = model.grid.cell_size ** 2 / 12 * np.eye(2)
    mp, Pp = F @ m, F @ P @ F.T + Q
    S = H @ Pp @ H.T + R
    K = Pp @ H.T @ np.linalg.inv(S)
    nu = z - H @ mp
    like = np.array([multivariate_normal(H @ mp, S).pdf(zi) for zi in z])
    w = np.r_[1 - r * p_d * p_g, r * p_d * like / kappa]
    b = w / w.sum()
    r_post = 1 - b[0] * (1 - r) / (1 - r * p_d * p_g)
    c = np.r_[b[0] * r * (1 - p_d * p_g) / (1 - r * p_d * p_g), b[1:]] / r_post
    inno = c[1:] @ nu
    mean = mp + K @ inno
    spread = sum(ci * np.outer(v, v) for ci, v in zip(c[1:], nu, strict=True))
    cov = (c[0] * Pp + (1 - c[0]) * (Pp - K @ S @ K.T)
           + K @ (spread - np.outer(inno, inno)) @ K.T)
    return r_post, mean, cov


# A track well inside cell (6, 6): its predicted mass is in that cell to 1e-11, so its
# detection probability is p_d; detections at the centres of cells (6, 6) and (7, 6), both
# within the 0.9999 gate.
M0 = np.array([6.4, 0.02, 6.55, -0.01])
P0 = np.diag([0.05**2, 0.01**2, 0.05**2, 0.01**2])
P_GATE = 0.9999


@pytest.mark.parametrize("r, confirmed", [(1.0, True), (0.6, False)])
def test_one_track_two_detections_equals_pda_by_hand(r, confirmed):
    tracker = StoneSoupJPDA(gate_probability=P_GATE)
    model = _started(tracker, M0, P0, [r], [confirmed])
    cells = _block(6, 6)
    returns = np.isin(cells, [6 * 12 + 6, 6 * 12 + 7])
    tracker.update(Looks(cells, returns))
    z = np.array([[6.5, 6.5], [7.5, 6.5]])
    r_ref, mean_ref, cov_ref = _jipda_reference(M0, P0, r, z, model, P_GATE)
    track = tracker._tracks[0]
    np.testing.assert_allclose(np.asarray(track.state.state_vector, float).ravel(), mean_ref,
                               atol=TOL, rtol=0)
    np.testing.assert_allclose(np.asarray(track.state.covar, float), cov_ref, atol=TOL, rtol=0)
    assert tracker.existence[0] == pytest.approx(r_ref, abs=TOL)
    # the reference is not trivial: both detections carry weight, the mean moved
    assert np.linalg.norm(mean_ref - model.dynamics.F @ M0) > 1e-3


def test_two_tracks_sharing_detections_equal_enumeration():
    """Two confirmed tracks (existence 1) and two detections in both gates: Stone Soup's
    JPDA (EHM) marginals, through the PDA update, against every joint event written out."""
    m = np.array([[6.45, 0.0, 6.5, 0.0], [7.4, 0.0, 6.55, 0.0]])
    P = np.stack([np.diag([0.05**2, 0.01**2, 0.05**2, 0.01**2])] * 2)
    tracker = StoneSoupJPDA(gate_probability=P_GATE)
    model = _started(tracker, m, P, [1.0, 1.0], [True, True])
    cells = np.union1d(_block(6, 6), _block(7, 6))
    returns = np.isin(cells, [6 * 12 + 6, 6 * 12 + 7])
    tracker.update(Looks(cells, returns))

    F, Q = model.dynamics.F, model.dynamics.Q
    p_f = model.sensor.p_f
    p_d = (model.sensor.p_d - p_f) / (1 - p_f)  # a target's detection beside the clutter
    R = np.eye(2) / 12
    z = np.array([[6.5, 6.5], [7.5, 6.5]])
    preds = [(F @ mi, F @ Pi @ F.T + Q) for mi, Pi in zip(m, P, strict=True)]
    gate = chi2.ppf(P_GATE, 2)
    lik = np.zeros((2, 2))
    for t, (mp, Pp) in enumerate(preds):
        S = H @ Pp @ H.T + R
        for j in range(2):
            v = z[j] - H @ mp
            assert v @ np.linalg.solve(S, v) <= gate  # both in both gates
            lik[t, j] = p_d * multivariate_normal(H @ mp, S).pdf(z[j]) / p_f
    # joint events: each track takes no detection (-1) or one, no detection twice
    marg = np.zeros((2, 3))  # [missed, z0, z1] per track
    for a in itertools.product((-1, 0, 1), repeat=2):
        if a[0] >= 0 and a[0] == a[1]:
            continue
        w = np.prod([(1 - p_d * P_GATE) if a[t] < 0 else lik[t, a[t]] for t in range(2)])
        for t in range(2):
            marg[t, a[t] + 1] += w
    marg /= marg.sum(axis=1, keepdims=True)
    for t, (mp, Pp) in enumerate(preds):
        S = H @ Pp @ H.T + R
        K = Pp @ H.T @ np.linalg.inv(S)
        nu = z - H @ mp
        inno = marg[t, 1:] @ nu
        spread = sum(b * np.outer(v, v) for b, v in zip(marg[t, 1:], nu, strict=True))
        cov = (marg[t, 0] * Pp + (1 - marg[t, 0]) * (Pp - K @ S @ K.T)
               + K @ (spread - np.outer(inno, inno)) @ K.T)
        state = tracker._tracks[t].state
        np.testing.assert_allclose(np.asarray(state.state_vector, float).ravel(),
                                   mp + K @ inno, atol=TOL, rtol=0)
        np.testing.assert_allclose(np.asarray(state.covar, float), cov, atol=TOL, rtol=0)
    assert np.allclose(tracker.existence[:2], 1.0, atol=TOL)
    # mutual exclusion matters here: the marginals differ from two independent PDAs
    solo = np.c_[np.full(2, 1 - p_d * P_GATE), lik]
    solo /= solo.sum(axis=1, keepdims=True)
    assert np.abs(solo - marg).max() > 1e-3


# ------------------------------------------------------------------ initiation, deletion
@pytest.mark.parametrize("snr, reported", [(10.0, True), (0.737, False)])
def test_first_detection_existence_from_the_model(snr, reported):
    """A detection with no track: existence ``(1 - e^{-x}) / (1 - (1 - p_f) e^{-x})``,
    ``x = lambda p_d`` (lambda the model's initial count over the grid, survival 1, no
    births on ``default``); reported (a count of 1) only where that is at least 0.5."""
    model = get_scenario("default").model
    model = dataclasses.replace(model, sensor=dataclasses.replace(model.sensor, snr=snr))
    tracker = StoneSoupJPDA()
    tracker.reset(model, np.random.default_rng(0))
    tracker.predict()
    tracker.update(Looks(np.array([30, 31]), np.array([True, False])))
    bd, p_d, p_f = model.birth_death, model.sensor.p_d, model.sensor.p_f
    lam = bd.initial_count_mean / model.grid.n_cells
    x = lam * p_d
    expected = (1 - np.exp(-x)) / (1 - (1 - p_f) * np.exp(-x))
    assert tracker.existence == pytest.approx([expected], abs=TOL)
    est = tracker.estimate()
    assert bool(expected >= 0.5) is reported
    assert est.count == (1.0 if reported else 0.0)


def test_heavy_clutter_is_bounded():
    """p_f = 0.3 (envelope point env-pf-0.3, 3 targets): the kept tracks never exceed
    max_tracks and the reported count stays within the envelope's band's upper edge
    (1.5 x true + 2), over the second half of two runs."""
    sc = resolve_scenarios(["env-pf-0.3"])[0]
    assert sc.model.sensor.p_f == pytest.approx(0.3, rel=1e-2)
    for seed in (0, 1):
        tracker = TrackerSpec.parse("ss-jpda").make()
        counts, true = [], []
        for rec in play(sc, tracker, seed):
            assert len(tracker._tracks) <= tracker.max_tracks
            if rec.k >= sc.n_steps // 2:
                counts.append(rec.estimate.count)
                true.append(len(rec.truth))
        assert np.mean(counts) <= 1.5 * np.mean(true) + 2


def test_parameter_conflict_is_refused():
    from mttbench.trackers.params import ParameterError
    with pytest.raises(ParameterError, match="lost_track_probability"):
        StoneSoupJPDA.validate_params({"false_track_probability": 0.5,
                                       "lost_track_probability": 0.6})


_RUN = """
import hashlib, numpy as np
from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.policies import make_policy
from mttbench.benchmarks.engine.specs import TrackerSpec, resolve_scenarios
h = hashlib.sha256()
for name, policy in (("env-pf-0.1", "raster"), ("default", "renyi")):
    sc = resolve_scenarios([name])[0]
    tracker = TrackerSpec.parse("ss-jpda").make()
    for rec in play(sc, tracker, 3, policy=make_policy(policy), n_steps=15):
        e = rec.estimate
        for a in (e.states, e.covariances, e.labels, tracker.existence):
            h.update(np.ascontiguousarray(a).tobytes())
print(h.hexdigest())
"""


def test_two_processes_give_identical_numbers():
    """Stone Soup hashes detections and tracks by identity and strings with a salted hash:
    the same runs (clutter under raster; renyi, which reads P_c(t)) in two processes with
    different hash seeds give the same states, covariances, labels and existences."""
    out = []
    for seed in ("1", "2"):
        env = {**os.environ, "PYTHONHASHSEED": seed}
        res = subprocess.run([sys.executable, "-c", _RUN], env=env, capture_output=True,
                             text=True, timeout=300, check=True)
        out.append(res.stdout.strip().splitlines()[-1])
    assert out[0] == out[1] and len(out[0]) == 64

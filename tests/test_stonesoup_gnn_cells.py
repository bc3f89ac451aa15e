"""ss-gnn's gate to the detection's cell and its labels that follow a target
(trackers/stonesoup/gnn_cells.py).

* ``cell_distance`` against a second method: scipy's bounded minimiser (L-BFGS-B) of
  the quadratic over the box, on random Gaussians and boxes.
* The adapter's Stone Soup measure is that distance under ``S - R``, and a track whose
  target crossed into the next cell takes the detection there, which Stone Soup's
  ``Mahalanobis`` on the centre under ``S`` puts beyond the gate.
* ``LabelKeeper``: a replacement track within the gate keeps the label, one beyond it
  does not, labels never repeat within a step, and a released label expires.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from mttbench import trackers
from mttbench.scenarios.model import Looks
from mttbench.scenarios.spec import get as get_scenario
from mttbench.trackers.stonesoup.gnn_cells import LabelKeeper, cell_distance

#: scipy's minimiser stops at its own tolerance; the closed form is exact
TOL = 1e-6


@pytest.fixture
def stonesoup_installed():
    pytest.importorskip("stonesoup", minversion="1.9",
                        reason="needs the stonesoup extra: pip install 'mttbench[stonesoup]'")


def _reference(mu, P, lo, hi) -> float:
    A = np.linalg.inv(P)
    best = np.inf
    for x0 in (np.clip(mu, lo, hi), 0.5 * (lo + hi), lo, hi):
        res = minimize(lambda x: (x - mu) @ A @ (x - mu), x0, jac=lambda x: 2 * A @ (x - mu),
                       method="L-BFGS-B", bounds=list(zip(lo, hi, strict=True)),
                       options={"ftol": 1e-15, "gtol": 1e-12})
        best = min(best, res.fun)
    return float(np.sqrt(max(best, 0.0)))


def test_cell_distance_is_the_bounded_minimum_of_the_quadratic():
    rng = np.random.default_rng(7)
    inside = 0
    for _ in range(200):
        L = rng.normal(size=(2, 2))
        P = L @ L.T + 0.01 * np.eye(2)
        mu = rng.normal(0.0, 1.5, 2)
        lo = rng.normal(0.0, 1.0, 2)
        hi = lo + rng.uniform(0.2, 2.0, 2)
        got = cell_distance(*mu, *P.ravel(), *lo, *hi)
        assert got == pytest.approx(_reference(mu, P, lo, hi), abs=TOL)
        inside += got == 0.0
    assert 0 < inside < 200  # both branches ran


def _hypothesis_beside(tracker, model):
    """A track at 3/4 of cell (6, 6) on both axes (position variance 0.03, nearly known
    velocity 0) and one detection in the diagonal neighbour (7, 7): the hypothesiser's
    hypothesis for it (None when gated out), and the detection."""
    from stonesoup.types.state import GaussianState
    from stonesoup.types.track import Track

    from mttbench.trackers.stonesoup import peers as sp

    grid = model.grid
    tracker.reset(model, np.random.default_rng(0))
    tracker.predict()
    t0 = sp.EPOCH
    track = Track([GaussianState(np.array([[6.75], [0.0], [6.75], [0.0]]),
                                 np.diag([0.03, 1e-4, 0.03, 1e-4]), timestamp=t0)])
    every = np.arange(grid.n_cells)
    dets, _, _ = tracker._detections(Looks(every, every == int(grid.cell_of(7.5, 7.5))))
    hyps = tracker._associator.hypothesiser.hypothesise(track, dets, dets[0].timestamp)
    detected = [h for h in hyps if h]
    return (detected[0] if detected else None), dets[0]


def test_the_gate_reads_the_detections_cell(stonesoup_installed):
    """A target near the corner of its cell crosses into the diagonal neighbour: that
    cell's centre lies 3.1 from the track's predicted measurement under ``S`` (Stone
    Soup's Mahalanobis, ``gate_to="centre"``: gated out at 3); its nearest point lies 2.0
    away under ``S - R``, the distance recomputed here with scipy's minimiser."""
    model = get_scenario("default").model
    cell = trackers.make("ss-gnn", association="distance")
    hyp, det = _hypothesis_beside(cell, model)
    assert hyp is not None
    mp = hyp.measurement_prediction
    mu = np.ravel(mp.state_vector)
    S = np.asarray(mp.covar, float)
    P = S - model.grid.cell_size ** 2 / 12 * np.eye(2)
    z = np.ravel(det.state_vector)
    want = _reference(mu, P, z - 0.5, z + 0.5)
    assert hyp.distance == pytest.approx(want, abs=TOL) and want < cell.gate
    d = z - mu
    assert np.sqrt(d @ np.linalg.solve(S, d)) > cell.gate  # the centre under S: gated out
    centre = trackers.make("ss-gnn", association="distance", gate_to="centre")
    hyp, _ = _hypothesis_beside(centre, model)
    assert hyp is None


def _keeper() -> LabelKeeper:
    F = np.eye(4)
    F[0, 1] = F[2, 3] = 1.0
    keeper = LabelKeeper(F, 1e-3 * np.eye(4), gate=3.0)
    keeper.horizon = 3
    return keeper


def _state(x: float, y: float, sd: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    return np.array([x, 0.0, y, 0.0]), np.diag([sd * sd, 0.01, sd * sd, 0.01])


def _labels(keeper, reported: dict[str, tuple[float, float]]) -> dict[str, int]:
    ids = list(reported)
    m, P = zip(*(_state(*reported[i]) for i in ids), strict=True) if ids else ((), ())
    out = keeper.labels(ids, np.array(m).reshape(-1, 4), np.array(P).reshape(-1, 4, 4))
    assert len(set(out.tolist())) == len(out)
    return dict(zip(ids, out.tolist(), strict=True))


def test_a_replacement_within_the_gate_keeps_the_targets_label():
    keeper = _keeper()
    first = _labels(keeper, {"a": (1.0, 1.0), "far": (8.0, 8.0)})
    # "a" no longer reported; "b" beside it (distance 0.5 / sqrt(2 * 0.09) = 1.2 < 3)
    now = _labels(keeper, {"b": (1.5, 1.0), "far": (8.0, 8.0)})
    assert now == {"b": first["a"], "far": first["far"]}
    # "a" reported again beside "far": its label went on with the target, it takes a new one
    again = _labels(keeper, {"b": (1.5, 1.0), "far": (8.0, 8.0), "a": (1.0, 1.0)})
    assert again["a"] not in first.values() and again["b"] == first["a"]


def test_a_track_beyond_the_gate_gets_a_new_label():
    keeper = _keeper()
    first = _labels(keeper, {"a": (1.0, 1.0)})
    # 2 cells away: 2 / sqrt(2 * 0.09) = 4.7 > 3
    now = _labels(keeper, {"b": (3.0, 1.0)})
    assert now["b"] != first["a"]


def test_a_released_label_expires_after_the_horizon():
    keeper = _keeper()
    first = _labels(keeper, {"a": (1.0, 1.0)})
    for _ in range(keeper.horizon):  # released at the first, kept for 3 steps
        _labels(keeper, {})
    assert _labels(keeper, {"b": (1.0, 1.0)})["b"] != first["a"]
    keeper = _keeper()
    first = _labels(keeper, {"a": (1.0, 1.0)})
    for _ in range(keeper.horizon - 1):
        _labels(keeper, {})
    assert _labels(keeper, {"b": (1.0, 1.0)})["b"] == first["a"]

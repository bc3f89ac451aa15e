"""What the author of a tracker written outside mttbench puts in their own tests.

Two trackers are defined here, in the test file, and never registered, as an outside
package's would be:

* ``WrappedKFNN`` -- a trivially correct example: it wraps the project's KF-NN
  (:class:`mttbench.trackers.kfnn.KFNNTracker`) under another name, the way an
  adapter to another library's tracker looks. It passes the whole kit, tracking
  checks included.
* ``OneTargetGridFilter`` -- a small tracker of its own: a Bernoulli filter on the
  cells (existence probability ``r`` and a histogram over the cells) for at most one
  target. It passes every check but one, and declares that one with the reason in
  ``conformance_exceptions``, which is how a tracker that legitimately cannot pass a
  check says so.

The kit is used both ways: ``parametrize_with_checks`` for one test item per check
(ids like ``wrapped-kfnn-check_params``), and ``check_tracker`` in one test.
"""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

from mttbench import trackers
from mttbench.scenarios.model import Looks, RayleighGridSensor, TrackingModel
from mttbench.testing import check_tracker, parametrize_with_checks
from mttbench.trackers.base import Estimate, Tracker
from mttbench.trackers.kfnn import KFNNTracker


class WrappedKFNN(Tracker):
    """KF-NN behind a wrapper (an adapter): one parameter passed through, the rest
    delegated. Parameters are stored unchanged; the inner tracker is built in ``reset``."""

    name = "wrapped-kfnn"
    summary = "the project's KF-NN behind a wrapper (example of an outside tracker)"

    def __init__(self, lost_track_probability: float = 0.1) -> None:
        self.lost_track_probability = lost_track_probability

    def unsupported_reason(self, model: TrackingModel) -> str | None:
        return KFNNTracker().unsupported_reason(model)

    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        self._inner = KFNNTracker(lost_track_probability=self.lost_track_probability)
        self._inner.reset(model, rng)

    def predict(self) -> None:
        self._inner.predict()

    def cell_count_distribution(self) -> np.ndarray:
        return self._inner.cell_count_distribution()

    def update(self, looks: Looks) -> None:
        self._inner.update(looks)

    def estimate(self) -> Estimate:
        return self._inner.estimate()


class OneTargetGridFilter(Tracker):
    """Bernoulli filter on the grid cells for at most one target.

    State: existence probability ``r`` and ``p (n_cells,)``, the target's cell given
    that it exists. Predict: ``r <- p_b (1 - r) + p_s r`` with ``p_b = 1 - exp(-birth
    rate)``; a newborn is uniform over the cells; the position spreads to each of the
    four neighbouring cells with probability ``spread`` per step (reflecting at the
    edges). Update with the grid likelihood ratio ``l_c(1)`` of the looks at each cell:
    ``L_c = prod l_c(1)``, ``r <- r s / (1 - r + r s)`` with ``s = sum_c p_c L_c``,
    ``p <- p L / s``. Estimate: count ``r``; the centre of the most probable cell when
    ``r >= 0.5``. Every step costs O(cells), which is fine for an example.
    """

    name = "one-target-grid"
    summary = "Bernoulli filter over the grid cells for at most one target (example)"
    conformance_exceptions = {
        "check_tracks_two_targets": "models at most one target, by design",
    }

    def __init__(self, spread: float = 0.05) -> None:
        self.spread = spread

    def unsupported_reason(self, model: TrackingModel) -> str | None:
        if not isinstance(model.sensor, RayleighGridSensor):
            return "a histogram over grid cells needs the grid (Rayleigh) sensor"
        return None

    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        if not 0.0 <= self.spread <= 0.25:
            raise ValueError(f"spread must be in [0, 0.25], got {self.spread}")
        self._model, self._grid, self._sensor = model, model.grid, model.sensor
        bd = model.birth_death
        self._p_s, self._p_b = bd.survival_probability, -np.expm1(-bd.birth_rate)
        self._r = min(bd.initial_count_mean, 1.0)
        self._p = np.full(model.grid.n_cells, 1.0 / model.grid.n_cells)

    def predict(self) -> None:
        grid, a = self._grid, self.spread
        p = self._p.reshape(grid.ny, grid.nx)
        # each neighbour gets a; at an edge the move is refused (stays): reflection
        up, down = np.vstack([p[1:], p[-1:]]), np.vstack([p[:1], p[:-1]])
        left, right = np.hstack([p[:, 1:], p[:, -1:]]), np.hstack([p[:, :1], p[:, :-1]])
        moved = (1.0 - 4.0 * a) * p + a * (up + down + left + right)
        survived = self._p_s * self._r
        born = self._p_b * (1.0 - self._r)
        r = survived + born
        mix = (survived * moved.reshape(-1) + born / grid.n_cells) / r if r > 0 else self._p
        self._r, self._p = r, mix / mix.sum()

    def cell_count_distribution(self) -> np.ndarray:
        occupied = self._r * self._p
        return np.stack([1.0 - occupied, occupied], axis=1)

    def update(self, looks: Looks) -> None:
        if len(looks) == 0:
            return
        llr = self._sensor.log_likelihood_ratio(looks.returns, 1)  # (L,) log l_c(1)
        log_l = np.bincount(looks.cells, weights=llr, minlength=self._grid.n_cells)
        log_post = np.log(np.maximum(self._p, 1e-300)) + log_l
        log_s = float(logsumexp(log_post))  # log sum_c p_c L_c
        if 0.0 < self._r < 1.0:
            self._r = 1.0 / (1.0 + (1.0 - self._r) / self._r * np.exp(-log_s))
        self._p = np.exp(log_post - log_s)

    def estimate(self) -> Estimate:
        if self._r < 0.5:
            return Estimate(float(self._r), np.zeros((0, 4)))
        cx, cy = self._grid.cell_centers(np.array([int(np.argmax(self._p))]))[0]
        return Estimate(float(self._r), np.array([[cx, 0.0, cy, 0.0]]))


def test_the_examples_are_not_registered():
    assert not {"wrapped-kfnn", "one-target-grid"} & set(trackers.available())


@parametrize_with_checks([WrappedKFNN, OneTargetGridFilter])
def test_outside_tracker_conforms(tracker_class, check):
    check(tracker_class)


def test_check_tracker_in_one_call():
    assert check_tracker(WrappedKFNN) == {}
    skipped = check_tracker(OneTargetGridFilter, checks=["check_declarations",
                                                         "check_tracks_one_target",
                                                         "check_tracks_two_targets"])
    assert skipped == {"check_tracks_two_targets":
                       "one-target-grid declares: models at most one target, by design"}

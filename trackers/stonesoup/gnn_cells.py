"""What ``ss-gnn`` reads from the cell geometry: the gate's distance to a detection's cell.

A positive look says that a target is somewhere in the cell, not at its centre: the
detection stands for the whole square. The distance that gates and ranks a detection is
therefore the Mahalanobis distance, under the track's predicted **position** covariance
``P`` (``S - R``: the quantisation noise ``R = cell_size^2 / 12 I`` is the cell itself, not
added to it), from the predicted mean ``mu`` to the nearest point of the cell ``[lo, hi]``::

    d(mu, P, cell) = min over x in cell of sqrt((x - mu)^T P^-1 (x - mu))

0 when ``mu`` lies in the cell. With Stone Soup's ``Mahalanobis`` on the cell centre under
``S``, a track whose target had crossed into the next cell found that cell's centre about
``1 / sqrt(S)`` = 3 to 3.5 away (sd of ``S`` 0.29-0.33 cells) and beyond the gate 3, so the
detection started a new track at the cell centre, which then won every later assignment
(docs/stonesoup.md, "An independent GNN from the exported files").
"""

from __future__ import annotations

import math

import numpy as np


def cell_distance(mx: float, my: float, p00: float, p01: float, p10: float, p11: float,
                  lox: float, loy: float, hix: float, hiy: float) -> float:
    """``min_{x in [lo, hi]} sqrt((x - mu)^T P^-1 (x - mu))`` for ``mu = (mx, my)``, ``P =
    [[p00, p01], [p10, p11]]`` positive definite and the box ``lox <= x <= hix``, ``loy <=
    y <= hiy``, on Python floats (the gate calls it once per track and detection, where
    numpy arrays of two entries cost more than the arithmetic).

    Exact: 0 inside the box; outside, the minimum of a convex quadratic over a box lies on
    its boundary, and on each of the four edges (one coordinate fixed) the minimiser of the
    one-dimensional quadratic in the other is ``mu_o - A_fo d_f / A_oo`` (``A = P^-1``,
    ``d_f`` the fixed coordinate's offset), clipped to the edge."""
    if lox <= mx <= hix and loy <= my <= hiy:
        return 0.0
    det = p00 * p11 - p01 * p10
    a00, a01, a10, a11 = p11 / det, -p01 / det, -p10 / det, p00 / det
    best = math.inf
    for ex in (lox, hix):  # x fixed on a vertical edge, y free
        dx = ex - mx
        dy = min(max(my - a01 * dx / a11, loy), hiy) - my
        best = min(best, (dx * a00 + dy * a10) * dx + (dx * a01 + dy * a11) * dy)
    for ey in (loy, hiy):  # y fixed on a horizontal edge, x free
        dy = ey - my
        dx = min(max(mx - a10 * dy / a00, lox), hix) - mx
        best = min(best, (dx * a00 + dy * a10) * dx + (dx * a01 + dy * a11) * dy)
    return math.sqrt(max(best, 0.0))


class LabelKeeper:
    """Labels that follow a target rather than a Stone Soup track (``ss-gnn``'s output).

    The GNN reports the ``round(sum r)`` tracks of largest existence; when a target's
    track is replaced (a second track started beside it, or it was deleted and the
    target's next detection started a new one) the reported set swaps one track for the
    other and the label would change with it. Here a label belongs to a reported target:
    when a track the output reported at the step before is no longer reported, its label
    is **released** with that track's last state, predicted on with ``F``, ``Q``; a track
    reported for the first time (or whose label was handed on) takes the released label
    whose predicted position is nearest within the gate, the Mahalanobis distance between
    the two position estimates under the sum of their covariances,
    ``sqrt(d^T (P_i + P_l)^-1 d) < gate`` (both Gaussians describe the same target when
    the gate cannot tell them apart), else a new label. A released label expires after
    ``horizon`` steps (the step deleter's count: a target unseen that long is presumed
    lost). Labels stay unique within a step: a label handed on leaves its former track,
    which takes a released or a new label if it is reported again.

    ``labels(ids, m (n, 4), P (n, 4, 4))`` is called once per step with the reported tracks
    (in output order) and returns their labels ``(n,)``."""

    def __init__(self, F: np.ndarray, Q: np.ndarray, gate: float) -> None:
        self._F, self._Q, self._gate = F, Q, gate
        self.horizon = 2**31 - 1
        self._label_of: dict[str, int] = {}  # track id -> its label
        self._owner: dict[int, str] = {}  # label -> the track holding it
        self._shown: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # last step's reports
        self._released: dict[int, list] = {}  # label -> [mean (4,), cov (4, 4), age]
        self._next = 0

    def labels(self, ids: list[str], m: np.ndarray, P: np.ndarray) -> np.ndarray:
        from .. import kalman

        now = set(ids)
        for lab, state in self._shown.items():  # reported before, not now: released
            if self._owner.get(lab) not in now:
                self._released[lab] = [*state, 0]
        if self._released:  # one step on: predicted, aged, expired
            keys = list(self._released)
            mr, Pr = kalman.predict(np.array([self._released[k][0] for k in keys]),
                                    np.array([self._released[k][1] for k in keys]),
                                    self._F, self._Q)
            self._released = {k: [mr[i], Pr[i], self._released[k][2] + 1]
                              for i, k in enumerate(keys)
                              if self._released[k][2] + 1 <= self.horizon}
        out = np.zeros(len(ids), dtype=np.int64)
        pos = [0, 2]
        for i, tid in enumerate(ids):
            lab = self._label_of.get(tid)
            if lab is None or self._owner.get(lab) != tid:
                lab = self._claim(m[i][pos], P[i][np.ix_(pos, pos)])
                self._label_of[tid] = lab
                self._owner[lab] = tid
            self._released.pop(lab, None)
            out[i] = lab
        self._shown = {int(lab): (m[i].copy(), P[i].copy()) for i, lab in enumerate(out)}
        return out

    def _claim(self, mean_xy: np.ndarray, cov_xy: np.ndarray) -> int:
        """The released label nearest within the gate (removed from the pool), else a new
        one."""
        best, chosen = self._gate, None
        for lab, (mr, Pr, _) in self._released.items():
            d = mean_xy - mr[[0, 2]]
            S = cov_xy + Pr[np.ix_([0, 2], [0, 2])]
            dist = math.sqrt(float(d @ np.linalg.solve(S, d)))
            if dist < best:
                best, chosen = dist, lab
        if chosen is None:
            chosen, self._next = self._next, self._next + 1
        else:
            del self._released[chosen]
        return chosen

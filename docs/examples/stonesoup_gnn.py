"""A Stone Soup GNN tracker driven from `mttbench export`'s files alone, scored by `mttbench score`.

Written from docs/world_format.md and the model card, as a check of the in-process
``ss-gnn``: Stone Soup's ``KalmanPredictor`` / ``KalmanUpdater``, a ``PDAHypothesiser`` per
track (prediction, measurement prediction, gate), ``GNNWith2DAssignment``,
``SimpleMeasurementInitiator`` and ``CovarianceBasedDeleter``. Around them an existence
probability ``r`` per track (IPDA-style; Musicki, Evans & Stankovic 1994), every number from
the model card. Per step ``k`` of ``steps.csv`` (every step, those without a positive look
included):

* detections: one per positive cell, at its centre, ``R = cell_size^2 / 12 I`` (the
  Kalman update's quantisation noise);
* the looks' likelihood ratio of a track present against absent, from the cell sensor:
  ``L = 1 + sum_c m_c (l_c - 1)``, ``m_c`` the predicted position Gaussian's mass in cell
  ``c`` (a product of per-axis masses: the x-y covariance is dropped, zero when ``F``,
  ``Q`` and ``R`` act per axis; under a ``reflect`` boundary conditioned on the
  workspace), ``l_c = ((1 - p_d) / (1 - p_f))^n_c`` for a cell looked at ``n_c`` times
  with no positive look, ``q1 / q0`` for the track's assigned detection's cell (``q1 = 1 -
  (1 - p_d)^n_c``, ``q0 = 1 - (1 - p_f)^n_c``: the cell positive with a target and
  without), 1 elsewhere (cells not looked at, and positive cells the track did not take).
  So a track not looked at keeps its existence, and a look that finds nothing lowers it;
* association: ``GNNWith2DAssignment`` maximises the product of the hypotheses' weights,
  relative to every detection being clutter: a miss ``1 - r + r L``, detection ``z`` in
  cell ``c`` (within the hypothesiser's gate ``P_G``, ``--gate``) ``(1 - r + r L_z) /
  (1 + u_c (q1 / q0 - 1))``, the denominator the weight of leaving ``z`` to clutter or a
  new target (``u_c`` below). This replaces the ``PDAHypothesiser``'s own weights, ``r
  P_D g(z) / kappa`` with ``g`` the Gaussian density of the cell centre: that treats the
  quantisation as Gaussian noise with thin tails, so a target crossing into the next cell
  costs its track most of its existence (docs/stonesoup.md);
* existence: ``r <- p_s r`` at the prediction, ``r <- r L / (1 - r + r L)`` at the update;
* a detection no track takes starts a track (``SimpleMeasurementInitiator``: position at
  the detection with covariance ``R``, velocity 0 with the model's birth sd) of existence
  ``r0 = u q1 / (u q1 + (1 - u) q0)``: the probability that the positive cell holds a new
  target rather than only clutter, ``u_c = 1 - exp(-mu_c)``, ``mu_c`` the untracked
  targets expected in the cell: the initial count spread over the grid, ``p_s mu +
  birth_rate / n`` per step, ``(1 - P)^n_c`` after the looks at the cell (``P = (p_d -
  p_f) / (1 - p_f)``), plus the existence of each deleted track at its cell; on a model
  without arrivals also the model's expected count ``p_s^k n0`` that neither the tracks
  nor ``mu`` hold, spread over the grid (as the GM-PHD example's births);
* deleted: ``r < --prune``, a position sd over ``--max-sd`` cells (Stone Soup's
  ``CovarianceBasedDeleter`` on the position trace), and under a ``die`` boundary a
  predicted mean outside the workspace.

Estimate: the tracks with ``r >= 0.5`` (labelled by track), the count ``sum r``. Nothing is
read from the truth files, and the declared initial states are not used (only their
number, as the in-process trackers but ``jmpd-ap``).

    python docs/examples/stonesoup_gnn.py WORLD_DIR [WORLD_DIR ...]
    mttbench score EXPORT_DIR --estimates stonesoup_gnn.csv --name gnn-files

Writes ``stonesoup_gnn.csv`` (``step, x, y, label, count``) into each world folder.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import norm
from stonesoup.base import Property
from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
from stonesoup.deleter.error import CovarianceBasedDeleter
from stonesoup.hypothesiser import Hypothesiser
from stonesoup.hypothesiser.probability import PDAHypothesiser
from stonesoup.initiator.simple import SimpleMeasurementInitiator
from stonesoup.models.measurement.linear import LinearGaussian
from stonesoup.models.transition.linear import LinearGaussianTimeInvariantTransitionModel
from stonesoup.predictor.kalman import KalmanPredictor
from stonesoup.types.detection import Detection
from stonesoup.types.multihypothesis import MultipleHypothesis
from stonesoup.types.numeric import Probability
from stonesoup.types.state import GaussianState
from stonesoup.types.track import Track
from stonesoup.updater.kalman import KalmanUpdater

EPOCH = datetime.datetime(1970, 1, 1)  # the files' time: seconds after the Unix epoch
OUT_NAME = "stonesoup_gnn.csv"


class CellPDA(Hypothesiser):
    """Stone Soup's ``PDAHypothesiser`` (prediction, measurement prediction, gate ``P_G``)
    with each hypothesis weighed by the cell sensor's likelihood (module docstring)."""

    predictor: KalmanPredictor = Property()
    updater: KalmanUpdater = Property()
    prob_gate: float = Property()
    weights: dict = Property(doc="track -> (r, L of the negative looks, cell masses)")
    step: dict = Property(doc="this step's cell_of (detection id -> cell), pos_excess, "
                              "new_or_clutter (per cell)")

    def hypothesise(self, track, detections, timestamp, **kwargs):
        r, base, mass = self.weights[track]
        cell_of, excess, alone = (self.step[k] for k in ("cell_of", "pos_excess",
                                                         "new_or_clutter"))
        gated = PDAHypothesiser(
            self.predictor, self.updater, clutter_spatial_density=1.0, prob_detect=0.5,
            prob_gate=self.prob_gate, normalise=False,
        ).hypothesise(track, detections, timestamp, **kwargs)
        for h in gated:
            if h:  # detection in cell c, against leaving it to clutter or a new target
                c = cell_of[id(h.measurement)]
                h.probability = Probability((1 - r + r * (base + mass[c] * excess[c])) / alone[c])
            else:
                h.probability = Probability(1 - r + r * base)
        return MultipleHypothesis(list(gated), normalise=False)


def by_step(path: Path) -> dict[int, pd.DataFrame]:
    table = pd.read_csv(path)
    return {int(k): g for k, g in table.groupby("step")}


def cell_masses(mean: np.ndarray, covar: np.ndarray, s: float, nx: int, ny: int) -> np.ndarray:
    """The position Gaussian's mass in each cell, ``(ny, nx)`` (flat index ``iy nx + ix``)."""
    sx, sy = np.sqrt(covar[0, 0]), np.sqrt(covar[2, 2])
    mx = np.diff(norm.cdf(np.arange(nx + 1) * s, mean[0], sx))
    my = np.diff(norm.cdf(np.arange(ny + 1) * s, mean[2], sy))
    return np.outer(my, mx)


def run_world(world: Path, gate: float = 0.99, prune: float = 1e-2,
              max_sd: float = 5.0) -> int:
    """Track one world; writes ``world / OUT_NAME`` and returns the steps written."""
    card = json.loads((world / "model_card.json").read_text())
    grid, sensor, targets = card["grid"], card["sensor"], card["targets"]
    s, nx, ny, n = grid["cell_size"], grid["nx"], grid["ny"], grid["n_cells"]
    F, Q = np.array(card["dynamics"]["F"]), np.array(card["dynamics"]["Q"])
    p_d, p_f = sensor["p_d"], sensor["p_f"]
    P = (p_d - p_f) / (1 - p_f)
    p_s, b = targets["survival_probability"], targets["birth_rate"]
    n0 = len(targets["initial_states"]) + targets["n_random_initial"]
    sv = targets["birth_velocity_std"]
    die = targets["boundary"] == "die"

    measurement = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=s * s / 12 * np.eye(2))
    predictor = KalmanPredictor(LinearGaussianTimeInvariantTransitionModel(
        transition_matrix=F, covariance_matrix=Q))
    updater = KalmanUpdater(measurement)
    weights: dict[Track, tuple] = {}
    step_context: dict = {}
    associator = GNNWith2DAssignment(CellPDA(predictor, updater, gate, weights, step_context))
    initiator = SimpleMeasurementInitiator(
        GaussianState(np.zeros((4, 1)), np.diag([0.0, sv * sv, 0.0, sv * sv])), measurement)
    too_wide = CovarianceBasedDeleter(covar_trace_thresh=2 * (max_sd * s) ** 2, mapping=[0, 2])

    steps = pd.read_csv(world / "steps.csv")
    dets, misses = by_step(world / "stonesoup_detections.csv"), by_step(
        world / "stonesoup_misses.csv")
    mu = np.full(n, n0 / n)  # untracked targets per cell (dense: a small example)
    expected = float(n0)
    tracks: list[Track] = []
    r: list[float] = []
    labels: list[int] = []
    next_label = 0
    rows = []
    for k, seconds in zip(steps["step"], steps["time"], strict=True):  # every step
        t = EPOCH + datetime.timedelta(seconds=float(seconds))
        mu = p_s * mu + b / n
        expected = p_s * expected + b
        pos, neg = dets.get(int(k)), misses.get(int(k))
        looks = np.zeros(n, int)  # looks per cell this step
        for table in (pos, neg):
            if table is not None:
                np.add.at(looks, table["cell"].to_numpy(int), 1)
        positive = np.zeros(n, bool)
        if pos is not None:
            positive[pos["cell"].to_numpy(int)] = True
        q1, q0 = 1 - (1 - p_d) ** looks, 1 - (1 - p_f) ** looks  # a cell positive: target, none
        with np.errstate(invalid="ignore", divide="ignore"):
            pos_excess = np.where(positive, q1 / q0 - 1, 0.0)
        neg_excess = np.where((looks > 0) & ~positive, ((1 - p_d) / (1 - p_f)) ** looks - 1, 0.0)

        # predict; survival; a mean leaving a `die` workspace is a target gone
        kept_t, kept_r, kept_l, masses = [], [], [], []
        for track, ri, lab in zip(tracks, r, labels, strict=True):
            pred = predictor.predict(track, timestamp=t)
            m = np.asarray(pred.state_vector, float).ravel()
            if die and not (0 <= m[0] < nx * s and 0 <= m[2] < ny * s):
                continue
            mass = cell_masses(m, np.asarray(pred.covar, float), s, nx, ny).ravel()
            if not die and mass.sum() > 0:
                mass /= mass.sum()  # reflected targets stay in the workspace
            kept_t.append(track)
            kept_r.append(p_s * ri)
            kept_l.append(lab)
            masses.append(mass)
        tracks, r, labels = kept_t, kept_r, kept_l

        # the prior of a new target at each positive cell: untracked targets expected there
        spare = max(0.0, expected - sum(r) - mu.sum()) / n if b == 0 else 0.0
        u = 1 - np.exp(-(mu + spare))
        new_or_clutter = 1 + u * pos_excess  # a detection left to no track, against clutter
        detections, cell_of = [], {}
        if pos is not None:
            for cell, x, y in pos.drop_duplicates("cell")[["cell", "x", "y"]].itertuples(
                    index=False):
                det = Detection(np.array([[x], [y]]), timestamp=t, measurement_model=measurement)
                detections.append(det)
                cell_of[id(det)] = int(cell)
        weights.clear()
        step_context.update(cell_of=cell_of, pos_excess=pos_excess,
                            new_or_clutter=new_or_clutter)
        base = {}
        for track, ri, mass in zip(tracks, r, masses, strict=True):
            if mass[looks > 0].sum() <= 1e-12:
                continue  # not looked at: no evidence, kept out of the association
            base[id(track)] = 1 + float(mass @ neg_excess)
            weights[track] = (ri, base[id(track)], mass)
        looked = [track for track in tracks if track in weights]
        hyps = associator.associate(looked, detections, t) if looked and detections else {}
        taken = set()
        for i, (track, mass) in enumerate(zip(tracks, masses, strict=True)):
            if id(track) not in base:  # not looked at: the prediction
                track.append(predictor.predict(track, timestamp=t))
                continue
            h = hyps.get(track)
            lik = base[id(track)]  # L: the looks' likelihood ratio, target present vs absent
            if h:  # assigned a detection
                c = cell_of[id(h.measurement)]
                taken.add(id(h.measurement))
                lik += mass[c] * pos_excess[c]
                track.append(updater.update(h))
            else:
                track.append(predictor.predict(track, timestamp=t))
            r[i] = r[i] * lik / (1 - r[i] + r[i] * lik)

        # new tracks from the detections no track took
        for det in detections:
            if id(det) in taken:
                continue
            c = cell_of[id(det)]
            (track,) = initiator.initiate({det}, t)
            tracks.append(track)
            r.append(u[c] * q1[c] / (u[c] * q1[c] + (1 - u[c]) * q0[c]))
            labels.append(next_label)
            next_label += 1
        mu *= (1 - P) ** looks

        # delete, returning a track's existence to the undetected intensity at its cell
        kept_t, kept_r, kept_l = [], [], []
        for track, ri, lab in zip(tracks, r, labels, strict=True):
            if ri >= prune and not too_wide.check_for_deletion(track):
                kept_t.append(track)
                kept_r.append(ri)
                kept_l.append(lab)
                continue
            m = np.asarray(track.state_vector, float).ravel()
            ix, iy = int(m[0] // s), int(m[2] // s)
            if 0 <= ix < nx and 0 <= iy < ny:
                mu[iy * nx + ix] += ri
        tracks, r, labels = kept_t, kept_r, kept_l

        count = float(sum(r))
        out = [(track, lab) for track, ri, lab in zip(tracks, r, labels, strict=True)
               if ri >= 0.5]
        for track, lab in out:
            m = np.asarray(track.state_vector, float).ravel()
            rows.append([int(k), m[0], m[2], lab, count])
        if not out:
            rows.append([int(k), "", "", "", count])  # a count-only row
    with open(world / OUT_NAME, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "x", "y", "label", "count"])
        w.writerows(rows)
    return len(steps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("worlds", nargs="+", type=Path, help="world folders of mttbench export")
    ap.add_argument("--gate", type=float, default=0.99,
                    help="gate probability P_G of the PDA hypothesiser (default 0.99)")
    ap.add_argument("--prune", type=float, default=1e-2,
                    help="delete a track below this existence (default 0.01)")
    ap.add_argument("--max-sd", type=float, default=5.0,
                    help="delete a track whose position sd exceeds this many cells (default 5)")
    args = ap.parse_args()
    for world in args.worlds:
        if (world / "model_card.json").is_file():
            print(f"{world}: {run_world(world, args.gate, args.prune, args.max_sd)} steps")


if __name__ == "__main__":
    main()

"""A Stone Soup GNN tracker driven from `mttbench export`'s files alone, scored by `mttbench score`.

Written from docs/world_format.md and the model card, as a check of the in-process
``ss-gnn``: Stone Soup's ``KalmanPredictor`` / ``KalmanUpdater``, a ``PDAHypothesiser`` per
track, ``GNNWith2DAssignment``, ``SimpleMeasurementInitiator`` and
``CovarianceBasedDeleter``; the track management around them is an existence probability
per track (IPDA, Musicki, Evans & Stankovic 1994), every number from the model card.

Per step ``k`` of ``steps.csv`` (every step, those without a positive look included):

* detections: one per positive cell, at its centre, ``R = cell_size^2 / 12 I``;
  clutter density ``kappa = p_f / cell_size^2``;
* a track's detection probability is ``P_D = sum_c m_c (1 - (1 - P)^n_c)`` over the cells
  looked at this step (``n_c`` looks; ``P = (p_d - p_f) / (1 - p_f)``, the target's share of
  a positive look with clutter modelled apart), ``m_c`` the predicted position Gaussian's
  mass in cell ``c`` (a product of the per-axis masses: the x-y covariance is dropped,
  zero when ``F``, ``Q`` and ``R`` act per axis). So a track not looked at has ``P_D = 0``
  and keeps its existence, and a look that finds nothing lowers it;
* association: ``GNNWith2DAssignment`` maximises the product of the ``PDAHypothesiser``
  weights with ``prob_detect = r P_D``: ``1 - r P_D P_G`` for a miss, ``r P_D g(z) /
  kappa`` for detection ``z`` in the gate (``P_G``, ``--gate``); ``g`` the predicted
  measurement density;
* existence (IPDA with the assigned detection only): ``r+ = r (1 - d) / (1 - r d)``,
  ``d = P_D P_G - P_D g(z) / kappa`` with a detection, ``d = P_D P_G`` without; survival
  ``r <- p_s r`` at the prediction;
* a detection no track takes starts a track (``SimpleMeasurementInitiator``: position at
  the detection with covariance ``R``, velocity 0 with the model's birth sd) of existence
  ``r0 = u q1 / (u q1 + (1 - u) q0)``: the probability that the positive cell holds a new
  target rather than only clutter, ``u = 1 - exp(-mu_c)`` for ``mu_c`` untracked targets
  expected in the cell, ``q1 = 1 - (1 - p_d)^n_c`` and ``q0 = 1 - (1 - p_f)^n_c`` the
  chances its looks fire with and without one;
* ``mu_c``: an undetected intensity per cell, the initial count spread over the grid,
  ``p_s mu + birth_rate / n`` per step, ``(1 - P)^n_c`` after the looks at the cell, plus
  the existence of each deleted track at its cell; on a model without arrivals the
  prior also gets the model's expected count ``p_s^k n0`` that neither the tracks nor
  ``mu`` hold, spread over the grid (as the GM-PHD example's births);
* deleted: ``r < --prune``, a position sd over ``--max-sd`` cells (Stone Soup's
  ``CovarianceBasedDeleter`` on the position trace), and under a ``die`` boundary a
  predicted mean outside the workspace. ``reflect`` is not modelled.

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
from stonesoup.types.state import GaussianState
from stonesoup.types.track import Track
from stonesoup.updater.kalman import KalmanUpdater

EPOCH = datetime.datetime(1970, 1, 1)  # the files' time: seconds after the Unix epoch
OUT_NAME = "stonesoup_gnn.csv"


class PerTrackPDA(Hypothesiser):
    """A ``PDAHypothesiser`` whose ``prob_detect`` is the track's own ``r P_D``."""

    predictor: KalmanPredictor = Property()
    updater: KalmanUpdater = Property()
    clutter_spatial_density: float = Property()
    prob_gate: float = Property()
    prob_detect: dict = Property(doc="track -> r P_D for this step")

    def hypothesise(self, track, detections, timestamp, **kwargs):
        return PDAHypothesiser(
            self.predictor, self.updater, clutter_spatial_density=self.clutter_spatial_density,
            prob_detect=self.prob_detect[track], prob_gate=self.prob_gate,
        ).hypothesise(track, detections, timestamp, **kwargs)


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
    kappa = p_f / (s * s)
    p_s, b = targets["survival_probability"], targets["birth_rate"]
    n0 = len(targets["initial_states"]) + targets["n_random_initial"]
    sv = targets["birth_velocity_std"]
    die = targets["boundary"] == "die"

    measurement = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=s * s / 12 * np.eye(2))
    predictor = KalmanPredictor(LinearGaussianTimeInvariantTransitionModel(
        transition_matrix=F, covariance_matrix=Q))
    updater = KalmanUpdater(measurement)
    prob_detect: dict[Track, float] = {}
    associator = GNNWith2DAssignment(PerTrackPDA(predictor, updater, kappa, gate, prob_detect))
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
        p_cell = (1 - (1 - P) ** looks).reshape(ny, nx)

        # predict; survival; a mean leaving a `die` workspace is a target gone
        kept_t, kept_r, kept_l, predicted = [], [], [], []
        for track, ri, lab in zip(tracks, r, labels, strict=True):
            pred = predictor.predict(track, timestamp=t)
            m = np.asarray(pred.state_vector, float).ravel()
            if die and not (0 <= m[0] < nx * s and 0 <= m[2] < ny * s):
                continue
            kept_t.append(track)
            kept_r.append(p_s * ri)
            kept_l.append(lab)
            predicted.append(pred)
        tracks, r, labels = kept_t, kept_r, kept_l
        p_det = [float((cell_masses(np.asarray(pr.state_vector, float).ravel(),
                                    np.asarray(pr.covar, float), s, nx, ny) * p_cell).sum())
                 for pr in predicted]

        detections = []
        if pos is not None:
            for x, y in pos.drop_duplicates("cell")[["x", "y"]].itertuples(index=False):
                detections.append(Detection(np.array([[x], [y]]), timestamp=t,
                                            measurement_model=measurement))
        looked = [i for i, pd_i in enumerate(p_det) if pd_i > 0]
        prob_detect.clear()
        for i in looked:
            prob_detect[tracks[i]] = r[i] * p_det[i]
        hyps = associator.associate([tracks[i] for i in looked], detections, t) if looked else {}
        taken = set()
        for i, (track, pred) in enumerate(zip(tracks, predicted, strict=True)):
            h = hyps.get(track)
            if h is None:  # not looked at: the prediction
                track.append(pred)
                continue
            d = p_det[i] * gate
            if h:  # assigned a detection
                taken.add(id(h.measurement))
                g_over_kappa = float(h.probability) / (r[i] * p_det[i])  # r P_D g / kappa
                d -= p_det[i] * g_over_kappa
                track.append(updater.update(h))
            else:
                track.append(h.prediction)
            r[i] = r[i] * (1 - d) / (1 - r[i] * d)

        # new tracks from the detections no track took
        spare = max(0.0, expected - sum(r) - mu.sum()) / n if b == 0 else 0.0
        for det in detections:
            if id(det) in taken:
                continue
            x, y = np.asarray(det.state_vector, float).ravel()
            cell = int(min(y // s, ny - 1) * nx + min(x // s, nx - 1))
            u = 1 - np.exp(-(mu[cell] + spare))
            q1, q0 = 1 - (1 - p_d) ** looks[cell], 1 - (1 - p_f) ** looks[cell]
            (track,) = initiator.initiate({det}, t)
            tracks.append(track)
            r.append(u * q1 / (u * q1 + (1 - u) * q0))
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

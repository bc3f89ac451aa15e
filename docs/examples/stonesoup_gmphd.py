"""A Stone Soup GM-PHD driven from `mttbench export`'s files alone, scored by `mttbench score`.

The loop a tracker from outside needs on these worlds (docs/world_format.md, "Driving an
outside tracker"):

* it runs over every step ``0 .. n_steps - 1`` of ``steps.csv`` at that step's ``time``,
  not over the scans of Stone Soup's CSV reader, which has no scan for a step without a
  positive look (most steps of the presets): a loop over the scans would predict a gap of
  several steps as one;
* it reads the negative looks (``stonesoup_misses.csv``): a component whose predicted mean
  lies in a cell looked at this step is updated with detection probability ``P = (p_d -
  p_f) / (1 - p_f)`` (the cell sensor as a point detector with independent clutter,
  ``kappa = p_f / cell_size^2`` in a looked cell), so a look that finds nothing multiplies
  its weight by ``1 - P``; a component in a cell not looked at keeps its weight (``P =
  0``: no look, no evidence), where one ``prob_detection`` for every component would
  erase targets the sensor never looked for.

Births: a component at the centre of each positive cell (position variance
``cell_size^2 / 12``, velocity 0 with the model's birth sd, stated one step earlier so the
prediction moves it as it moves every component), weighing the targets expected in that
cell and not yet held: an undetected intensity per cell (the initial count over the grid,
``p_s lambda + birth_rate / n`` per step, ``1 - P`` per look at the cell) plus, on a model
without arrivals, the part of its expected count ``p_s^k n0`` that neither the mixture nor
the intensity holds, spread over the grid. Stone Soup's ``GaussianMixtureReducer`` prunes
and merges. Estimate: the components above ``--extraction`` (0.5), the count the sum of
the weights. One look per cell and step is assumed (the raster and random policies below
one look per cell); with more, a cell's ``P`` would be ``1 - (1 - P)^n``.

    python docs/examples/stonesoup_gmphd.py WORLD_DIR [WORLD_DIR ...]
    mttbench score EXPORT_DIR --estimates stonesoup_gmphd.csv --name ss-gmphd-files

Writes ``stonesoup_gmphd.csv`` (``step, x, y, count``) into each world folder.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
from pathlib import Path

import numpy as np
import pandas as pd
from stonesoup.hypothesiser.distance import DistanceHypothesiser
from stonesoup.hypothesiser.gaussianmixture import GaussianMixtureHypothesiser
from stonesoup.measures import Mahalanobis
from stonesoup.mixturereducer.gaussianmixture import GaussianMixtureReducer
from stonesoup.models.measurement.linear import LinearGaussian
from stonesoup.models.transition.linear import LinearGaussianTimeInvariantTransitionModel
from stonesoup.predictor.kalman import KalmanPredictor
from stonesoup.types.detection import Detection
from stonesoup.types.state import TaggedWeightedGaussianState
from stonesoup.updater.kalman import KalmanUpdater
from stonesoup.updater.pointprocess import PHDUpdater

EPOCH = datetime.datetime(1970, 1, 1)  # the files' time: seconds after the Unix epoch
OUT_NAME = "stonesoup_gmphd.csv"


def by_step(path: Path) -> dict[int, pd.DataFrame]:
    table = pd.read_csv(path)
    return {int(k): g for k, g in table.groupby("step")}


def run_world(world: Path, extraction: float = 0.5, gate: float = 5.0) -> int:
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
    kalman = KalmanUpdater(measurement)
    hypothesiser = GaussianMixtureHypothesiser(
        DistanceHypothesiser(predictor, kalman, Mahalanobis(), missed_distance=gate),
        order_by_detection=True)
    phd = PHDUpdater(kalman, clutter_spatial_density=p_f / (s * s), prob_detection=P,
                     prob_survival=p_s)
    reducer = GaussianMixtureReducer(prune_threshold=1e-5, merge_threshold=9.0,
                                     max_number_components=100)
    birth_cov = np.diag([s * s / 12, sv * sv, s * s / 12, sv * sv])

    steps = pd.read_csv(world / "steps.csv")
    dets, misses = by_step(world / "stonesoup_detections.csv"), by_step(
        world / "stonesoup_misses.csv")
    lam = np.full(n, n0 / n)  # untracked targets per cell (a dense array: a small example)
    expected = float(n0)
    mixture: list[TaggedWeightedGaussianState] = []
    rows = []
    for k, seconds in zip(steps["step"], steps["time"], strict=True):  # every step
        t = EPOCH + datetime.timedelta(seconds=float(seconds))
        before = t - datetime.timedelta(seconds=card["dynamics"]["tau"])
        lam = p_s * lam + b / n
        expected = p_s * expected + b
        pos, neg = dets.get(int(k)), misses.get(int(k))
        looked = set()
        for table in (pos, neg):
            if table is not None:
                looked |= set(table["cell"].astype(int))
        # the predicted mean's cell decides whether a component was looked at
        means = np.array([F @ np.asarray(c.state_vector, float).ravel() for c in mixture])
        means = means.reshape(-1, 4)
        inside = ((means[:, 0] >= 0) & (means[:, 0] < nx * s) & (means[:, 2] >= 0)
                  & (means[:, 2] < ny * s))
        cells = (np.clip(np.floor(means[:, 2] / s), 0, ny - 1) * nx
                 + np.clip(np.floor(means[:, 0] / s), 0, nx - 1)).astype(int)
        seen = [c for c, ok, cell in zip(mixture, inside, cells, strict=True)
                if (ok or not die) and cell in looked]
        unseen = [c for c, ok, cell in zip(mixture, inside, cells, strict=True)
                  if (ok or not die) and cell not in looked]
        detections, births = set(), []
        held = p_s * sum(float(c.weight) for c in mixture)
        spare = max(0.0, expected - held - lam.sum()) / n if b == 0 else 0.0
        if pos is not None:
            for cell, x, y in pos[["cell", "x", "y"]].drop_duplicates("cell").itertuples(
                    index=False):
                detections.add(Detection(np.array([[x], [y]]), timestamp=t,
                                         measurement_model=measurement))
                births.append(TaggedWeightedGaussianState(
                    np.array([[x], [0.0], [y], [0.0]]), birth_cov, weight=lam[cell] + spare,
                    tag="birth", timestamp=before))
        updated = []
        if seen or births:
            hyps = hypothesiser.hypothesise(seen + births, detections, t)
            updated = list(phd.update(hyps).components)
        for c in unseen:  # not looked at: survival only
            pred = predictor.predict(c, timestamp=t)
            updated.append(TaggedWeightedGaussianState(
                pred.state_vector, pred.covar, weight=p_s * float(c.weight), tag=c.tag,
                timestamp=t))
        mixture = list(reducer.reduce(updated)) if updated else []
        for cell in looked:  # a look at the cell misses a target there with 1 - P
            lam[cell] *= 1 - P
        count = sum(float(c.weight) for c in mixture)
        kept = [c for c in mixture if float(c.weight) > extraction]
        for c in kept:
            rows.append([int(k), float(c.state_vector[0, 0]), float(c.state_vector[2, 0]),
                         count])
        if not kept:
            rows.append([int(k), "", "", count])  # a count-only row
    with open(world / OUT_NAME, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["step", "x", "y", "count"])
        out.writerows(rows)
    return len(steps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("worlds", nargs="+", type=Path, help="world folders of mttbench export")
    ap.add_argument("--extraction", type=float, default=0.5,
                    help="report the components above this weight (default 0.5)")
    args = ap.parse_args()
    for world in args.worlds:
        if (world / "model_card.json").is_file():
            print(f"{world}: {run_world(world, args.extraction)} steps")


if __name__ == "__main__":
    main()

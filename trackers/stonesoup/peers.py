"""Stone Soup's trackers as peers behind the :class:`~mttbench.trackers.base.Tracker`
interface: ``ss-gnn`` (global nearest neighbour) and ``ss-gmphd`` (Gaussian-mixture PHD).

An optional extra (``pip install 'mttbench[stonesoup]'``, Stone Soup >= 1.9). This module
imports without it: Stone Soup is imported on the first :meth:`reset`, and
:meth:`unsupported_reason` answers ``needs the stonesoup extra: ...`` when it is missing,
so a run gets an ``unsupported`` row, ``mttbench trackers`` says so and the default
``mttbench compare`` leaves the peers out. The trackers are Stone Soup's components
driven step by step by the adapter (the predictor, updater, hypothesiser, associator,
initiator, deleter and reducer named below, unchanged); the adapter only converts the
model and the looks and fixes the order of whatever Stone Soup iterates. docs/stonesoup.md
has the mapping, the measurements and the commands.

Model (both peers)
    Transition: ``LinearGaussianTimeInvariantTransitionModel(F, Q)`` with the scenario's
    ``F`` and ``Q`` (:class:`~mttbench.scenarios.model.Dynamics`): the same matrices for
    the white-noise-acceleration ``Q`` (what Stone Soup's ``ConstantVelocity`` builds per
    axis) and for an explicit ``Q`` (the paper's), which ``ConstantVelocity`` cannot
    express. Step ``k`` is at ``EPOCH + k tau`` seconds; every prediction spans one step.
    Measurement: ``LinearGaussian`` on ``(px, py)`` with ``R = cell_size^2 / 12 I``.
    The targets' reflection at the walls is not modelled (as in KF-NN); under the ``die``
    boundary a track (GNN) or component (GM-PHD) whose mean leaves the workspace is dropped.

Detections
    As KF-NN (:mod:`~mttbench.trackers.kfnn`): each cell with at least one positive look
    in the step is one ``Detection`` at its centre (repeated positive looks at a cell see
    the same targets and are one detection), in increasing cell order.

Detection probability and clutter (GM-PHD; the GNN's distance association uses neither)
    Stone Soup 1.9's ``PHDUpdater`` takes one ``prob_detection`` and one
    ``clutter_spatial_density`` per update, so both are the **per-step average over the
    looked cells**: ``p = mean_c (1 - (1 - P)^n_c)`` and ``kappa = mean_c (1 - (1 -
    p_f)^n_c) / cell_size^2`` over the cells looked ``n_c >= 1`` times (``p_f`` the
    sensor's false-alarm probability; ``P = (p_d - p_f) / (1 - p_f)`` the detection of a
    target beside independent clutter, :func:`target_detection_probability`: a point
    detector with clutter sees a target's cell positive with ``1 - (1 - P)(1 - p_f) =
    p_d``, as the cell sensor does; ``p_d`` itself would count the clutter's share twice).
    What follows the looks **per look** is where the update applies: a component whose
    predicted mean lies in a cell not looked at has detection probability 0, so it does
    not enter Stone Soup's update and keeps its predicted weight (times ``p_s``). That
    is the exact GM-PHD update for ``p_D(x) = p`` in looked cells and 0 elsewhere,
    evaluated at each component's mean.

Determinism
    Stone Soup iterates sets of detections and tracks (ordered by object identity, so by
    memory address) and the GM-PHD reducer emits components in the order of a set of
    random tags (string hashes, salted per process), so the same run would give different
    numbers in different processes. The adapter passes detections as lists in cell order, keeps
    tracks in a list ordered by the detection that started them (step, cell), runs the
    GNN through :class:`OrderedGNN` (sorts tracks and detections before Stone Soup's
    assignment, also inside the initiator), gives components deterministic tags and
    sorts the reduced mixture by (weight, mean, covariance) after every update. No number
    is perturbed. tests/test_stonesoup_peers.py runs the same run in two processes with
    different hash seeds and requires identical outputs.

``ss-gnn``
    By default (``association="existence"``) the tracks carry their existence and the
    hypotheses are weighed by it (the paragraph after this one); ``association="distance"``
    is Stone Soup's distance GNN with an initiator and deleters, as follows.
    ``GNNWith2DAssignment`` over a ``DistanceHypothesiser`` (``missed_distance = gate``)
    whose measure is the Mahalanobis distance from the predicted position to the nearest
    point of the detection's cell under the predicted position covariance ``S - R``
    (``gate_to="cell"``, :func:`~mttbench.trackers.stonesoup.gnn_cells.cell_distance`:
    a positive look puts the target anywhere in the cell, so a target crossing into the
    next cell stays in its track's gate; ``"centre"``: Stone Soup's ``Mahalanobis`` to the
    cell centre under ``S``), ``KalmanPredictor``/``KalmanUpdater``, a
    ``MultiMeasurementInitiator`` (``min_points`` updates confirm a holding track; its
    ``SimpleMeasurementInitiator`` puts the position at the detection with covariance
    ``R`` and the velocity at 0 with sd ``velocity_scale`` times the model's birth
    velocity sd) and two deleters, either of which deletes a track, confirmed or holding
    (Stone Soup's ``CompositeDeleter``): an ``UpdateTimeStepsDeleter`` (after
    ``max_steps_without_update`` steps without an update) and the adapter's
    ``ScoreDeleter``, Blackman's track score on Stone Soup's ``Deleter`` interface with
    KF-NN's cell likelihood ratio (each step adds ``log(1 + sum_c m_c (r_c - 1))``,
    ``m_c`` the predicted position Gaussian's mass in cell ``c``, over the negative looked
    cells and an update's detection cell, ``r_c`` the cell's ratio of one target against
    none: ``p_d / p_f`` per positive look, ``(1 - p_d) / (1 - p_f)`` per negative;
    :func:`~mttbench.trackers.cell_evidence.cell_evidence`); deleted ``log((1 - alpha) / beta)``
    below its highest score, a drop raised by ``log(rate / f)`` for a track tested more
    often than the model's look budget spread evenly would, as KF-NN's
    (:mod:`~mttbench.trackers.kfnn`). Not Blackman's point score ``log(p_d g(z) cell^2 /
    p_f)`` (``g`` the innovation's Gaussian density at the cell centre): it treats the
    quantisation as Gaussian noise with thin tails and deletes tracks of present targets
    that cross a cell edge; nor a count of updates, which keeps tracks that live on
    clutter (docs/stonesoup.md). The counts come
    from the model as a careful user would set them, with KF-NN's error rates
    (:mod:`~mttbench.trackers.kfnn`): ``min_points`` is the fewest detections ``n`` whose
    likelihood ratio ``(p_d / p_f) ** n`` times the prior odds of the model's target
    density reaches ``(1 - alpha) / alpha``; ``max_steps_without_update`` is the fewest
    steps after which a target still there has gone undetected with probability below
    ``beta``, at ``p_d f`` detections per step, ``f`` the looked share of the grid (its
    mean over the steps so far; the model's look budget before the first). At ``p_f =
    5e-4`` and raster 24 of 144 cells: one point and 27 steps; every cell looked at: 4
    steps; ``p_d = 0.9, p_f = 0.31`` and 20% of the cells: 7 points and 12 steps.
    Existence: ``r = sigmoid(L0 + log(p_d / p_f) + L)``, the birth detection, the score
    deleter's ``L`` and ``L0 = log(exp(lambda_c) - 1)``, the prior log-odds of an untracked
    target in the birth cell ``c`` (``lambda_c`` the undetected intensity below, before the
    step's looks, plus on a model without arrivals the share of its expected count that
    neither the tracks' ``sum r`` nor ``lambda`` holds, as ``ss-gmphd``'s births), for
    confirmed and holding tracks alike. A detection where the looks
    have already found nothing, or beside a held target, is most likely clutter: with the
    model's whole density as the prior every clutter detection would start near ``r = 1/2``
    at ``p_f = 0.01`` (docs/stonesoup.md).
    Estimate: the ``round(sum r)`` tracks of largest ``r``, confirmed or holding (count
    ``sum r``), as KF-NN and pmb (Stone Soup's own output, the confirmed tracks, reports
    nothing where a detection is worth too little to confirm within the run;
    docs/stonesoup.md). Labels follow the target (``labels="target"``,
    :class:`~mttbench.trackers.stonesoup.gnn_cells.LabelKeeper`): a track no longer
    reported releases its label, and a track reported for the first time takes the
    released label whose predicted position lies nearest within the gate (position
    Mahalanobis distance under the summed covariances), for ``max_steps_without_update``
    steps; ``"track"``: one label per Stone Soup track.
    ``P_c(t)``: each track is a target in its predicted position Gaussian, present with
    probability ``r``, plus KF-NN's undetected Poisson intensity per cell for targets
    not yet tracked (a :class:`~mttbench.trackers.cells.CellField`), to which a deleted
    track's ``r`` returns over its Gaussian's cells (recycling, Williams 2012, as pmb and
    ss-jpda; a track leaving the workspace under ``die`` is not recycled); per cell the
    count is Poisson-binomial (:func:`~mttbench.trackers.cells.bernoulli_cell_counts` of
    :func:`~mttbench.trackers.cells.gaussian_cell_mass_sparse`: the cells within 6 sd of
    each track).
    ``association="existence"`` (:mod:`~mttbench.trackers.stonesoup.gnn_existence`, the
    equations there): each track carries its existence ``r`` (``p_s r`` at the prediction,
    Bayes' rule on the cell likelihood ratio of the step's looks at the update); the
    hypotheses are weighed by ``r`` and that ratio, the missed detection by the negative
    looks at the track's predicted mass, a detection against leaving it to clutter or a
    new target; ``GNNWith2DAssignment`` maximises the product of the weights (distance
    hypotheses of ``-log w``, within the same gate); every detection no track takes
    starts a track (``SimpleMeasurementInitiator``, the prior above) of existence ``u r_z
    / (u r_z + 1 - u)``, ``u = 1 - exp(-lambda)`` of its cell; a track is deleted when
    ``r < existence_threshold`` or its position variance (trace) exceeds the uniform's
    over the workspace, ``(width^2 + height^2) / 12`` (it says less than the prior), and
    its ``r`` is recycled. No initiator points, step or score deleter. Estimate as
    above, the ``round(sum r)`` tracks of largest ``r`` (``r >= 1/2``, the file GNN's
    rule, measured worse on OSPA; docs/stonesoup.md).

``ss-gmphd``
    ``PHDUpdater`` over a ``GaussianMixtureHypothesiser`` (a ``DistanceHypothesiser`` with
    ``Mahalanobis`` gate ``gate``, ordered by detection), ``KalmanPredictor``/
    ``KalmanUpdater``, ``prob_survival = p_s`` of the model, and a
    ``GaussianMixtureReducer`` (prune below ``prune_threshold``, merge within squared
    Mahalanobis ``merge_threshold``, keep at most ``max_components``). Births: Stone
    Soup's tracker adds one broad birth component each step; one Gaussian cannot be
    uniform over the grid (its mass at a corner is 5% of the centre's), so the adapter
    adds a birth component (tag ``birth``) at the centre of every cell with a detection
    (measurement-driven births, Ristic, Clark, Vo and Vo 2012), its weight ``birth_scale``
    times the untracked targets expected in that cell before its looks: ``lambda_c + max(0,
    E[N_k] - p_s sum w - sum lambda) / n``, ``lambda_c`` the undetected intensity below and
    ``E[N_k] = p_s^k n0`` the expected count of a model without arrivals (the second term is
    0 on a model with arrivals, :meth:`_StoneSoupPeer._spare`). The first term is the PHD's
    own: where looks have found nothing, or a component already holds the target, a
    detection is most likely clutter (with the model's whole density ``(initial count +
    birth_rate) / n`` a clutter detection at ``p_f = 0.055`` would keep 0.36, above the
    extraction threshold). The second returns the part of the model's count that neither the
    mixture nor ``lambda`` holds: the Gaussian likelihood of a cell detection has thin
    tails, so a component loses its weight when its target crosses into the next cell, and
    on a model without arrivals ``lambda`` alone would never give it back
    (docs/stonesoup.md; with arrivals, births feed ``lambda``). Position variance
    ``cell_size^2 / 12``, velocity 0
    with sd ``birth_velocity_scale`` times the model's birth velocity sd. A birth
    component far from every detection would only be missed and dropped, so leaving it
    out changes nothing but the denominators of detections in a neighbouring cell
    (``q`` of a Gaussian a cell away). Estimate: the components with weight above
    ``extraction_threshold``; count = the sum of the weights (``count="sum"``) or its
    rounding (``"round"``). ``P_c(t)``: Poisson with the cell's predicted intensity mass
    ``sum_i p_s w_i m_ic + lambda_c``, ``lambda_c`` KF-NN's undetected intensity (the
    initial count over the grid, ``p_s lambda + birth_rate / n`` per step, ``(1 - p_d) /
    (1 - p_f)`` per look; the components' masses within 6 sd, the undetected intensity alone in
    every cell outside them). Cost: Stone Soup's update makes a
    hypothesis object per (component, detection) pair, so a step costs about
    ``max_components`` times the detections; ``max_components`` (default 100) and
    ``prune_threshold`` (searched from 1e-6 up) bound it in heavy clutter.

Cost per step (the adapter's part)
    Nothing per cell of the grid: the looks are counted per looked cell, ``P_c(t)`` is a
    :class:`~mttbench.trackers.cells.CellCounts` (rows of their own near tracks or
    components and, for the GNN, at the cells looked at so far), the GNN's untracked
    intensity a :class:`~mttbench.trackers.cells.CellField` (its predict ``O(cells looked
    at so far)``). The GM-PHD's ``P_c(t)`` sums the components' masses per cell in
    component order where the dense product summed them by matrix product: equal to
    round-off.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import importlib.util
import math
import re
from importlib import metadata
from types import SimpleNamespace
from typing import Any, ClassVar

import numpy as np
from scipy.special import expit

from ...scenarios.model import Looks, RayleighGridSensor, TrackingModel
from .. import kalman
from ..base import (
    BOX_CELLS,
    LOOKED_CELL_BYTES,
    LOOKED_CELL_S,
    Estimate,
    ResourceTerms,
    Tracker,
    gaussian_boxes,
    param_number,
    register,
)
from ..cell_evidence import (
    cell_evidence,
    drop_raise,
    look_ratios,
    looked_log_ratios,
    target_prior_logodds,
)
from ..cells import (
    CellCounts,
    CellField,
    bernoulli_cell_counts,
    gaussian_cell_mass_sparse,
    untracked_probabilities,
)
from ..params import Budget, Param, Search
from ..pmb.ppp import recycle
from . import gnn_existence as ge
from .gnn_cells import LabelKeeper, cell_distance

#: the one-line reason when Stone Soup is missing (run rows, ``mttbench trackers``)
EXTRA_HINT = "needs the stonesoup extra: pip install 'mttbench[stonesoup]'"
MIN_VERSION = (1, 9)
#: count columns of P_c: 0, 1, 2 and "3 or more"
N_COUNTS = 4
#: per target and step of Stone Soup's peers (Python objects per track and detection):
#: ss-gmphd 210 ms per step with 25 targets on 12x12, ss-gnn 26 ms
PEER_TARGET_S = 1e-2
#: the score deleter's entry of a track it has not scored yet (a holding track just born)
_UNSCORED = (0.0,)
#: the timestamp of step 0 (Stone Soup needs datetimes; only differences matter)
EPOCH = datetime.datetime(2000, 1, 1)
#: the kit's checks that run the tracker (skipped, with EXTRA_HINT, when Stone Soup is
#: missing; the declaration, parameter and superposition checks still run)
_RUNNING_CHECKS = (
    "check_runs_200_steps", "check_deterministic", "check_reset_no_state_leak",
    "check_zero_targets", "check_step_without_looks", "check_count_distribution_on_large",
    "check_tracks_one_target", "check_tracks_two_targets",
)


# ------------------------------------------------------------------ the optional extra
def missing_extra() -> str | None:
    """None when Stone Soup >= 1.9 is installed, else the one-line reason (a pip hint).

    Looks the package up without importing it (``mttbench trackers`` stays fast); a
    ``None`` entry in ``sys.modules`` counts as missing (how tests simulate it)."""
    try:
        spec = importlib.util.find_spec("stonesoup")
    except (ImportError, ValueError):
        spec = None
    if spec is None:
        return EXTRA_HINT
    try:
        version = metadata.version("stonesoup")
    except metadata.PackageNotFoundError:
        return None  # importable but without metadata (a source checkout): let it run
    parts = tuple(int(x) for x in re.findall(r"\d+", version)[:2])
    if parts < MIN_VERSION:
        return (f"needs stonesoup >= {'.'.join(map(str, MIN_VERSION))} (found {version}): "
                "pip install 'mttbench[stonesoup]'")
    return None


def _import_stonesoup() -> SimpleNamespace:
    """Stone Soup's classes used here, and :class:`OrderedGNN` (built on them)."""
    from stonesoup.base import Property
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.deleter.base import Deleter
    from stonesoup.deleter.multi import CompositeDeleter
    from stonesoup.deleter.time import UpdateTimeStepsDeleter
    from stonesoup.hypothesiser.base import Hypothesiser
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.gaussianmixture import GaussianMixtureHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator, SimpleMeasurementInitiator
    from stonesoup.measures import Mahalanobis, Measure
    from stonesoup.mixturereducer.gaussianmixture import GaussianMixtureReducer
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import LinearGaussianTimeInvariantTransitionModel
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.detection import Detection, MissedDetection
    from stonesoup.types.hypothesis import SingleDistanceHypothesis
    from stonesoup.types.multihypothesis import MultipleHypothesis
    from stonesoup.types.state import GaussianState, TaggedWeightedGaussianState
    from stonesoup.types.update import Update
    from stonesoup.updater.kalman import KalmanUpdater
    from stonesoup.updater.pointprocess import PHDUpdater

    class OrderedGNN(GNNWith2DAssignment):
        """Stone Soup's GNN with its inputs in a fixed order: tracks by the detection that
        started them, detections by cell (Stone Soup passes sets, whose order follows
        memory addresses, and its assignment breaks exact ties by that order)."""

        def associate(self, tracks, detections, timestamp, **kwargs):
            return super().associate(sorted(tracks, key=track_key),
                                     sorted(detections, key=detection_key), timestamp,
                                     **kwargs)

    class CellMahalanobis(Measure):
        """The Mahalanobis distance from a track's predicted position to the nearest point
        of the detection's cell, under the predicted position covariance ``S - R``
        (:func:`~mttbench.trackers.stonesoup.gnn_cells.cell_distance`): the detection
        stands for the whole cell, whose quantisation ``R`` is then not added again."""

        cell_size: float = Property(doc="the grid's cell side")
        noise_var: float = Property(doc="R's diagonal, cell_size^2 / 12")

        def __call__(self, state1, state2):
            (mx,), (my,) = state1.state_vector.tolist()
            (p00, p01), (p10, p11) = state1.covar.tolist()
            (zx,), (zy,) = state2.state_vector.tolist()
            r, half = self.noise_var, 0.5 * self.cell_size
            return cell_distance(mx, my, p00 - r, p01, p10, p11 - r, zx - half, zy - half,
                                 zx + half, zy + half)

    class ExistenceHypothesiser(Hypothesiser):
        """Per track, a missed-detection hypothesis and one per detection within the gate
        (``measure`` of the measurement prediction and the detection at most ``gate``, as
        Stone Soup's ``DistanceHypothesiser``), each a ``SingleDistanceHypothesis`` of
        distance ``-log w``: ``w`` the weight :attr:`weigh` gives it (``weigh(track,
        detection or None)``, set by the adapter each step;
        :mod:`~mttbench.trackers.stonesoup.gnn_existence`). ``GNNWith2DAssignment`` then
        maximises the product of the weights."""

        predictor: KalmanPredictor = Property()
        updater: KalmanUpdater = Property()
        measure: Measure = Property()
        gate: float = Property()

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.weigh = None

        def hypothesise(self, track, detections, timestamp, **kwargs):
            prediction = self.predictor.predict(track, timestamp=timestamp)
            hyps = [SingleDistanceHypothesis(
                prediction, MissedDetection(timestamp=timestamp),
                distance=-math.log(self.weigh(track, None)))]
            for det in detections:
                mp = self.updater.predict_measurement(
                    prediction, measurement_model=det.measurement_model)
                if self.measure(mp, det) > self.gate:
                    continue
                hyps.append(SingleDistanceHypothesis(
                    prediction, det, distance=-math.log(self.weigh(track, det)),
                    measurement_prediction=mp))
            return MultipleHypothesis(hyps)

    class ScoreDeleter(Deleter):
        """A track-score deleter on Stone Soup's interface (Blackman and Popoli 1999, ch.
        6.2, with KF-NN's cell-exact ratio): each step a track's log-likelihood ratio of
        "target" against "false track" moves by ``log(1 + sum_c m_c (r_c - 1))``
        (:func:`~mttbench.trackers.cell_evidence.cell_evidence` through :attr:`evidence`, set by the
        adapter each step): ``m_c`` its predicted position Gaussian's mass in cell ``c``,
        ``c`` over the negative looked cells and, for an update, its detection's cell,
        ``r_c`` the cell's ratio of one target against none. The track is deleted when its
        score falls ``drop + max(0, log(rate / f))`` below the highest it has reached:
        ``f`` the model's looks per step over the cells (:attr:`budget_share`), ``rate =
        (tested + 1) / (steps + 1 / f)``, ``tested`` the sum of the masses ``m_c`` its
        looks tested (the test restarts at every new peak, so a track tested more often
        than the budget spread evenly would test it is deleted while present more often
        per step)."""

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.drop = math.inf
            self.budget_share = 1.0  # the model's looks per step over the grid's cells
            #: callable(mean_xy (2,), cov_xy (2, 2), hit cell or None) -> (gain, tested)
            self.evidence = None
            self.scores: dict[str, list] = {}  # track id -> [L, max L, time of L, ...]

        def check_for_deletion(self, track, **kwargs):
            # a new track's score starts at 0 at its first state; the states since the
            # last check are scored in order (a track promoted by the initiator is first
            # checked one step later, after an update)
            # [L, highest L, time of L, tested mass, steps scored]
            entry = self.scores.setdefault(track.id,
                                           [0.0, 0.0, track.states[0].timestamp, 0.0, 0])
            fresh = []
            for state in reversed(track.states):
                if state.timestamp <= entry[2]:
                    break
                fresh.append(state)
            for state in reversed(fresh):
                if isinstance(state, Update):
                    prior, hit = state.hypothesis.prediction, state.hypothesis.measurement
                    cell = hit.metadata["cell"]
                else:
                    prior, cell = state, None
                m = np.asarray(prior.mean, dtype=float).ravel()[[0, 2]]
                P = np.asarray(prior.covar, dtype=float)[np.ix_([0, 2], [0, 2])]
                step, tested = self.evidence(m, P, cell)
                entry[0] += step
                entry[1] = max(entry[1], entry[0])
                entry[2] = state.timestamp
                entry[3] += tested
                entry[4] += 1
            return entry[0] <= entry[1] - self.drop - drop_raise(entry[3], entry[4],
                                                                 self.budget_share)

    return SimpleNamespace(
        GNNWith2DAssignment=GNNWith2DAssignment, UpdateTimeStepsDeleter=UpdateTimeStepsDeleter,
        ScoreDeleter=ScoreDeleter, CompositeDeleter=CompositeDeleter,
        DistanceHypothesiser=DistanceHypothesiser, CellMahalanobis=CellMahalanobis,
        GaussianMixtureHypothesiser=GaussianMixtureHypothesiser,
        MultiMeasurementInitiator=MultiMeasurementInitiator, Mahalanobis=Mahalanobis,
        GaussianMixtureReducer=GaussianMixtureReducer, LinearGaussian=LinearGaussian,
        LinearGaussianTimeInvariantTransitionModel=LinearGaussianTimeInvariantTransitionModel,
        KalmanPredictor=KalmanPredictor, Detection=Detection, GaussianState=GaussianState,
        TaggedWeightedGaussianState=TaggedWeightedGaussianState, KalmanUpdater=KalmanUpdater,
        PHDUpdater=PHDUpdater, OrderedGNN=OrderedGNN, ExistenceHypothesiser=ExistenceHypothesiser,
        SimpleMeasurementInitiator=SimpleMeasurementInitiator)


@functools.cache
def stonesoup() -> SimpleNamespace:
    """The Stone Soup classes, imported once; ``ImportError`` naming the extra if missing."""
    reason = missing_extra()
    if reason:
        raise ImportError(reason)
    try:
        return _import_stonesoup()
    except ImportError as exc:
        raise ImportError(f"{EXTRA_HINT} ({exc})") from exc


def target_detection_probability(p_d: float, p_f: float) -> float:
    """The cell sensor as a point-detection model with independent clutter: a look at a
    target's cell is positive with ``p_d``, which such a model writes as ``1 - (1 - P_D)(1 -
    p_f)``, so ``P_D = (p_d - p_f) / (1 - p_f)``; a miss is then ``(1 - p_d) / (1 - p_f)``
    times as likely with the target as without, as on the cell sensor. Using ``p_d`` itself
    counts the clutter's share of a positive look twice (0.5 for 0.29 at ``p_d = 0.5, p_f
    = 0.3``; equal to 1e-3 at the presets' ``p_f``)."""
    return (p_d - p_f) / (1.0 - p_f)


def detection_key(detection: Any) -> tuple[datetime.datetime, int]:
    """``(timestamp, cell)`` of a detection made by :meth:`_StoneSoupPeer._detections`."""
    return detection.timestamp, detection.metadata["cell"]


def track_key(track: Any) -> tuple[datetime.datetime, int]:
    """The key of the detection that started ``track`` (its first state's)."""
    return detection_key(track.states[0].hypothesis.measurement)


def poisson_counts(lam: np.ndarray, n_counts: int) -> np.ndarray:
    """Per cell, Poisson(``lam_c``) counts ``0 .. n_counts - 2`` and "``n_counts - 1`` or
    more": ``(len(lam), n_counts)``, rows summing to 1."""
    lam = np.maximum(np.asarray(lam, dtype=float), 0.0)
    t = np.arange(n_counts - 1)
    from scipy.stats import poisson  # here: scipy.stats costs most commands 0.8 s to import

    pmf = poisson.pmf(t[None, :], lam[:, None])
    return np.column_stack([pmf, np.maximum(1.0 - pmf.sum(axis=1), 0.0)])


def _exceptions(own: dict[str, str]) -> dict[str, str]:
    """The kit's checks a peer skips: every running check when Stone Soup is missing (at
    import), else ``own``."""
    return dict.fromkeys(_RUNNING_CHECKS, EXTRA_HINT) if missing_extra() else own


# ------------------------------------------------------------------ the shared adapter
class _StoneSoupPeer(Tracker):
    """What both peers share: the extra, the model conversion, the detections."""

    conformance_exceptions: ClassVar[dict[str, str]] = _exceptions({})

    @staticmethod
    def missing_extra() -> str | None:
        """None when the optional extra this tracker needs is installed, else why not
        (``mttbench trackers`` and the default ``mttbench compare`` read it)."""
        return missing_extra()

    def unsupported_reason(self, model: TrackingModel) -> str | None:
        missing = missing_extra()
        if missing:
            return missing
        if not isinstance(model.sensor, RayleighGridSensor):
            return ("Stone Soup's peers take point detections from the grid sensor; the "
                    "superposition sensor reports only the mean of all targets")
        return None

    def _reset_common(self, model: TrackingModel) -> SimpleNamespace:
        reason = self.unsupported_reason(model)
        if reason:
            raise ValueError(reason)
        self.validate_params(self.get_params())  # the declaration (built directly)
        ss = stonesoup()
        self._model, self._grid = model, model.grid
        self._F, self._Q = model.dynamics.F, model.dynamics.Q
        s = model.grid.cell_size
        self._r_var = s * s / 12.0
        self._transition = ss.LinearGaussianTimeInvariantTransitionModel(
            transition_matrix=self._F, covariance_matrix=self._Q)
        self._measurement = ss.LinearGaussian(ndim_state=4, mapping=(0, 2),
                                              noise_covar=self._r_var * np.eye(2))
        self._predictor = ss.KalmanPredictor(self._transition)
        self._updater = ss.KalmanUpdater(self._measurement)
        self._k = -1  # the step being processed (predict moves it on)
        return ss

    def _time(self, k: int) -> datetime.datetime:
        return EPOCH + datetime.timedelta(seconds=k * self._model.dynamics.tau)

    def _detections(self, looks: Looks) -> tuple[list[Any], np.ndarray, np.ndarray]:
        """One ``Detection`` per positive cell at its centre, in cell order; the looked
        cells (sorted) and the looks at each."""
        ss = stonesoup()
        cells = np.asarray(looks.cells, dtype=np.int64)
        looked, n_looks = np.unique(cells, return_counts=True)
        det_cells = np.unique(cells[np.asarray(looks.returns, bool)])
        t = self._time(self._k)
        dets = [ss.Detection(np.array([[x], [y]]), timestamp=t,
                             measurement_model=self._measurement, metadata={"cell": int(c)})
                for c, (x, y) in zip(det_cells, self._grid.cell_centers(det_cells), strict=True)]
        return dets, looked, n_looks

    def _spare(self, held: float) -> float:
        """Per cell, the model's expected count that neither the tracker's own targets
        (``held``) nor the undetected intensity holds, ``max(0, E[N_k] - held - sum
        lambda) / n``, on a model without arrivals (its count is the initial one, thinned
        by ``p_s``); 0 on a model with arrivals, whose ``E[N_k]`` from ``p_s`` alone would
        ignore the targets that leave under ``die``, and whose ``lambda`` is fed by births."""
        if self._birth_per_cell > 0.0:
            return 0.0
        held += self._undetected.total()
        return max(0.0, self._expected - held) / self._grid.n_cells

    def _inside(self, m: np.ndarray) -> np.ndarray:
        """``(K,)`` True where the means ``m (K, 4)`` lie in the workspace (``die``:
        outside is dead), all True under ``reflect``."""
        if self._model.birth_death.boundary != "die":
            return np.ones(len(m), dtype=bool)
        width, height = self._grid.extent
        return (m[:, 0] >= 0) & (m[:, 0] < width) & (m[:, 2] >= 0) & (m[:, 2] < height)

    def _cells_of(self, m: np.ndarray) -> np.ndarray:
        """Cell of each mean ``m (K, 4)``, outside means clipped to the nearest edge cell."""
        g = self._grid
        ix = np.clip(np.floor(m[:, 0] / g.cell_size), 0, g.nx - 1).astype(np.int64)
        iy = np.clip(np.floor(m[:, 2] / g.cell_size), 0, g.ny - 1).astype(np.int64)
        return iy * g.nx + ix

    @classmethod
    def resource_terms(cls, params, model, looks_per_step, targets) -> ResourceTerms:
        """Python objects per target; ``P_c(t)`` from ``2 T + 16`` Gaussians' boxes."""
        return ResourceTerms(target_seconds=PEER_TARGET_S,
                             prediction_entries=gaussian_boxes(targets) * BOX_CELLS,
                             prediction_counts=float(N_COUNTS))


def _mean_cov(state: Any) -> tuple[np.ndarray, np.ndarray]:
    return (np.asarray(state.state_vector, dtype=float).reshape(4),
            np.asarray(state.covar, dtype=float).reshape(4, 4))


def _sorted(comps: list[Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Weights ``(K,)``, means ``(K, 4)`` and covariances ``(K, 4, 4)`` of Stone Soup's
    weighted Gaussians, and the order of (weight descending, mean, covariance): a fixed
    order whatever the order they came in."""
    K = len(comps)
    w = np.array([float(c.weight) for c in comps]).reshape(K)
    m, P = np.zeros((K, 4)), np.zeros((K, 4, 4))
    for i, c in enumerate(comps):
        m[i], P[i] = _mean_cov(c)
    keys = np.column_stack([-w, m, P.reshape(K, 16)])
    return w, m, P, np.lexsort(keys.T[::-1])


# ======================================================================== GNN
@register
class StoneSoupGNN(_StoneSoupPeer):
    """Stone Soup's GNN tracker (module docstring)."""

    name = "ss-gnn"
    summary = ("Stone Soup's GNN (2-D assignment over hypotheses weighed by existence and "
               "the cell likelihood, Kalman, deletion by existence) on cell detections; "
               "optional extra")
    parameters: ClassVar[dict[str, Param]] = {
        "gate": Param(float, 0, low_open=True, search=Search(1.5, 6.0),
                      doc="Mahalanobis distance (not squared) beyond which a detection is "
                          "not a hypothesis (Stone Soup's missed_distance)"),
        "gate_to": Param(choices=("cell", "centre"), search=Search(choices=("cell", "centre")),
                         doc="the gate's distance: to the detection's cell under the "
                             "predicted position covariance, or to its centre under S "
                             "(Stone Soup's Mahalanobis)"),
        "labels": Param(choices=("target", "track"), search=Search(choices=("target", "track")),
                        doc="a reported label follows the target (a track reported for "
                            "the first time takes a released label within the gate) or "
                            "the Stone Soup track"),
        "false_track_probability": Param(
            float, 0, 1, low_open=True, high_open=True, search=Search(1e-6, 0.1, log=True),
            doc="alpha: min_points is the fewest detections that make the posterior "
                "probability of a false track at most alpha"),
        "lost_track_probability": Param(
            float, 0, 1, low_open=True, high_open=True, search=Search(1e-3, 0.5, log=True),
            doc="beta: max_steps_without_update is the fewest steps a present target "
                "stays undetected with probability below beta"),
        "velocity_scale": Param(float, 0, low_open=True, search=Search(0.5, 2.0, log=True),
                                doc="velocity sd of a new track, in multiples of the "
                                    "model's birth velocity sd"),
        "association": Param(choices=("distance", "existence"),
                             search=Search(choices=("distance", "existence")),
                             doc="hypotheses weighed by the gate's distance (with the "
                                 "initiator's points and the step and score deleters) or "
                                 "by existence and the cell likelihood (every free "
                                 "detection a track, deleted below existence_threshold)"),
        "existence_threshold": Param(
            float, 0, 1, low_open=True, high_open=True, search=Search(1e-3, 0.1, log=True),
            doc="association=existence: a track whose existence falls below this is "
                "deleted (its r returns to the untracked targets)"),
    }
    #: no budget: one track per target, nothing to trade
    budget: ClassVar[dict[str, Budget]] = {}

    def __init__(self, gate: float = 3.0, gate_to: str = "cell", labels: str = "target",
                 false_track_probability: float = 0.1, lost_track_probability: float = 0.1,
                 velocity_scale: float = 1.0, association: str = "existence",
                 existence_threshold: float = 0.01) -> None:
        self.association = association
        self.existence_threshold = existence_threshold
        self.gate = gate
        self.gate_to = gate_to
        self.labels = labels
        self.false_track_probability = false_track_probability
        self.lost_track_probability = lost_track_probability
        self.velocity_scale = velocity_scale

    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        """Stone Soup's components; no tracks; KF-NN's undetected intensity."""
        ss = self._reset_common(model)
        self._rng = rng  # unused: the tracker is deterministic
        measure = (ss.CellMahalanobis(cell_size=model.grid.cell_size, noise_var=self._r_var)
                   if self.gate_to == "cell" else ss.Mahalanobis())
        if self.association == "existence":
            hypothesiser = ss.ExistenceHypothesiser(self._predictor, self._updater,
                                                    measure=measure, gate=self.gate)
            hypothesiser.weigh = self._weigh
        else:
            hypothesiser = ss.DistanceHypothesiser(self._predictor, self._updater,
                                                   measure=measure, missed_distance=self.gate)
        self._associator = ss.OrderedGNN(hypothesiser)
        sensor = model.sensor
        self._looked_share = [min(1.0, sensor.looks_per_step / model.grid.n_cells)]
        self._time_deleter = ss.UpdateTimeStepsDeleter(
            time_steps_since_update=self.steps_without_update(self._looked_share[0]))
        score = self._score_deleter = ss.ScoreDeleter()
        score.drop = math.log1p(-self.false_track_probability) - math.log(
            self.lost_track_probability)  # |T1|, Wald's lower threshold
        score.evidence = self._evidence
        score.budget_share = min(1.0, sensor.looks_per_step / model.grid.n_cells)
        self._log_pos, self._log_neg, self._miss = look_ratios(sensor)
        self._step_looks = looked_log_ratios(np.zeros(0, np.int64), np.zeros(0, bool),
                                             self._log_pos, self._log_neg)
        self._deleter = ss.CompositeDeleter([self._time_deleter, score], intersect=False)
        sv2 = (self.velocity_scale * model.birth_death.birth_velocity_std) ** 2
        prior = ss.GaussianState(np.zeros((4, 1)), np.diag([0.0, sv2, 0.0, sv2]),
                                 timestamp=self._time(-1))
        self._starter = ss.SimpleMeasurementInitiator(prior, self._measurement)
        self._initiator = ss.MultiMeasurementInitiator(
            prior_state=prior, deleter=self._deleter, data_associator=self._associator,
            updater=self._updater, measurement_model=self._measurement,
            min_points=self.min_points(self._log_pos))
        self._tracks: list[Any] = []  # confirmed, in track_key order
        #: a track's label (the estimate's), by its Stone Soup id: numbered in the order
        #: the tracks are first reported (so deterministic), kept for the track's life
        #: (labels="track"); with labels="target" the LabelKeeper's
        self._track_labels: dict[str, int] = {}
        self._label_keeper = LabelKeeper(self._F, self._Q, self.gate)
        bd = model.birth_death
        n = model.grid.n_cells
        self._p_s, self._birth_per_cell = bd.survival_probability, bd.birth_rate / n
        self._undetected = CellField(n, bd.initial_count_mean / n)
        self._expected = bd.initial_count_mean  # the model's expected count, E[N_k]
        # a track's existence: sigmoid(prior log-odds + its birth detection + its score),
        # the prior that of an untracked target in its birth cell (by Stone Soup track id)
        self._prior_logodds: dict[str, float] = {}
        # association="existence": each track's existence r (by Stone Soup track id) and
        # this step's terms of its hypotheses' weights (gnn_existence)
        self._r: dict[str, float] = {}
        self._weights_now: dict[str, tuple] = {}
        self._dets_now: dict[int, tuple[float, float]] = {}
        extent = np.asarray(model.grid.extent, dtype=float)
        #: a track whose position variance (trace) exceeds the uniform's over the
        #: workspace says less than the prior about where its target is: deleted
        self._max_trace = float(extent @ extent) / 12.0

    def min_points(self, per_hit: float) -> int:
        """The fewest detections ``n`` with ``L0 + n per_hit >= log((1 - alpha) / alpha)``,
        ``per_hit = log(p_d / p_f)`` a detection's log ratio, ``L0`` the prior log-odds of
        the model's target density per cell."""
        alpha = self.false_track_probability
        prior = target_prior_logodds(self._model)
        if prior == -math.inf:
            return 2**31 - 1  # a model without targets: nothing is ever confirmed
        need = math.log1p(-alpha) - math.log(alpha) - prior
        return max(1, math.ceil(need / per_hit - 1e-12))

    def steps_without_update(self, looked_share: float) -> int:
        """The fewest steps ``s`` with ``(1 - p_d f) ** s <= beta``: a target still there
        has gone that long undetected with probability at most ``beta``."""
        miss = 1.0 - self._model.sensor.p_d * min(max(looked_share, 0.0), 1.0)
        if miss <= 0.0:
            return 1
        if miss >= 1.0:
            return 2**31 - 1  # nothing is looked at: never deleted for want of updates
        return max(1, math.ceil(math.log(self.lost_track_probability) / math.log(miss)
                                - 1e-12))

    def _evidence(self, mean_xy: np.ndarray, cov_xy: np.ndarray, hit_cell: int | None
                  ) -> tuple[float, float]:
        """One track's score gain from this step's looks and the mass they tested
        (:func:`~mttbench.trackers.cell_evidence.cell_evidence`; ``hit_cell`` its detection's)."""
        looked, _, det_cells, log_r = self._step_looks
        rows = np.zeros(0 if hit_cell is None else 1, dtype=np.int64)
        gain, tested = cell_evidence(self._grid, mean_xy[None], cov_xy[None], looked, log_r,
                                     det_cells, rows, np.full(len(rows), hit_cell or 0))
        return float(gain[0]), float(tested[0])

    def predict(self) -> None:
        """The next step (Stone Soup predicts inside the association); the undetected
        intensity ``p_s lambda + b / n``."""
        self._k += 1
        self._undetected.affine(self._p_s, self._birth_per_cell)
        self._expected = self._p_s * self._expected + self._birth_per_cell * self._grid.n_cells
        for tid in self._r:  # association="existence": survival
            self._r[tid] *= self._p_s

    def _predicted(self, tracks: list[Any]) -> tuple[np.ndarray, np.ndarray]:
        """Predicted means ``(K, 4)`` and covariances of ``tracks`` (``F``, ``Q``)."""
        m = np.zeros((len(tracks), 4))
        P = np.zeros((len(tracks), 4, 4))
        for i, tr in enumerate(tracks):
            m[i], P[i] = _mean_cov(tr.state)
        return kalman.predict(m, P, self._F, self._Q)

    def cell_count_distribution(self) -> CellCounts:
        """Poisson-binomial of the tracks (existence ``r``, :meth:`_existence`) in
        their predicted Gaussians (within 6 sd), and of the untracked targets."""
        tracks = self._tracks + sorted(self._initiator.holding_tracks, key=track_key)
        m, P = self._predicted(tracks)
        comp, cells, mass = gaussian_cell_mass_sparse(self._grid,
                                                      *kalman.position_marginal(m, P))
        exist = self._existence(tracks)
        return bernoulli_cell_counts(self._grid.n_cells, N_COUNTS, cells, mass * exist[comp],
                                     *untracked_probabilities(self._undetected))

    def update(self, looks: Looks) -> None:
        """Stone Soup's GNN step: associate, update or coast, delete, initiate."""
        dets, looked, n_looks = self._detections(looks)
        self._step_looks = looked_log_ratios(looks.cells, looks.returns, self._log_pos,
                                             self._log_neg)
        t = self._time(self._k)
        # the deleter follows the share of the grid looked at per step so far
        if self._k == 0:
            self._looked_share = []
        self._looked_share.append(len(looked) / self._grid.n_cells)
        self._time_deleter.time_steps_since_update = self.steps_without_update(
            float(np.mean(self._looked_share)))
        self._label_keeper.horizon = self._time_deleter.time_steps_since_update
        if self.association == "existence":
            self._update_existence(dets, looked, n_looks, t)
            return
        used = set()
        dropped: list[Any] = []  # deleted inside the workspace: recycled
        if self._tracks:
            assoc = self._associator.associate(self._tracks, dets, t)
            for track in self._tracks:
                hyp = assoc[track]
                if hyp:
                    track.append(self._updater.update(hyp))
                    used.add(hyp.measurement)
                else:
                    track.append(hyp.prediction)
            dead = self._deleter.delete_tracks(set(self._tracks))
            m = np.array([_mean_cov(tr.state)[0] for tr in self._tracks]).reshape(-1, 4)
            inside = self._inside(m)
            dropped += [tr for tr, ok in zip(self._tracks, inside, strict=True)
                        if ok and tr in dead]
            for tr, ok in zip(self._tracks, inside, strict=True):
                if not ok:  # left the workspace under die: gone, not recycled
                    self._score_deleter.scores.pop(tr.id, None)
                    self._prior_logodds.pop(tr.id, None)
            self._tracks = [tr for tr, ok in zip(self._tracks, inside, strict=True)
                            if ok and tr not in dead]
        holding = set(self._initiator.holding_tracks)
        new = self._initiator.initiate({d for d in dets if d not in used}, t)
        for track in new:  # promoted by the initiator before its deleter scored this step
            self._score_deleter.check_for_deletion(track)
        born = [tr for tr in [*self._initiator.holding_tracks, *new]
                if tr.id not in self._prior_logodds]
        if born:  # the untracked targets in the birth cell, before this step's looks:
            # lambda_c and the model's expected count the tracks and lambda do not hold
            kept = [tr for tr in [*self._tracks, *self._initiator.holding_tracks, *new]
                    if tr.id in self._prior_logodds]
            spare = self._spare(float(self._existence(kept).sum()))
            lam = spare + self._undetected.at(
                [tr.states[0].hypothesis.measurement.metadata["cell"] for tr in born])
            with np.errstate(divide="ignore"):
                prior = np.log(np.expm1(lam))  # log-odds of 1 - exp(-lambda)
            self._prior_logodds.update(zip((tr.id for tr in born), prior.tolist(),
                                           strict=True))
        self._tracks += sorted(new, key=track_key)
        dropped += sorted(holding - self._initiator.holding_tracks - set(new), key=track_key)
        self._undetected.multiply(looked, self._miss ** n_looks)
        self._recycle(dropped)

    def _weigh(self, track: Any, detection: Any | None) -> float:
        """The weight of ``track`` taking ``detection`` (None: none) this step
        (:mod:`~mttbench.trackers.stonesoup.gnn_existence`)."""
        r, lik0, mean_xy, cov_xy = self._weights_now[track.id]
        if detection is None:
            return ge.miss_weight(r, lik0)
        cell = detection.metadata["cell"]
        ratio, u = self._dets_now[cell]
        return ge.detection_weight(r, lik0, ge.cell_mass(self._grid, mean_xy, cov_xy, cell),
                                   ratio, u)

    def _update_existence(self, dets: list[Any], looked: np.ndarray, n_looks: np.ndarray,
                          t: datetime.datetime) -> None:
        """``association="existence"``: weigh, associate, update ``r`` by Bayes, start a
        track at every free detection, delete below ``existence_threshold`` (or wider than
        the workspace), recycling the deleted ``r`` (module docstring; gnn_existence)."""
        tracks = self._tracks
        m, P = self._predicted(tracks)
        inside = self._inside(m)
        for tr, ok in zip(tracks, inside, strict=True):
            if not ok:  # left the workspace under die: gone, not recycled
                del self._r[tr.id]
        tracks = [tr for tr, ok in zip(tracks, inside, strict=True) if ok]
        m, P = m[inside], P[inside]
        mean_xy, cov_xy = kalman.position_marginal(m, P)
        _, _, det_cells, log_r = self._step_looks
        lik0 = np.exp(cell_evidence(self._grid, mean_xy, cov_xy, looked, log_r, det_cells,
                                    np.zeros(0, np.int64), np.zeros(0, np.int64))[0])
        r = np.array([self._r[tr.id] for tr in tracks])
        # the untracked targets in each detection's cell before this step's looks
        cells = np.array([d.metadata["cell"] for d in dets], dtype=np.int64)
        lam = self._undetected.at(cells) + self._spare(float(r.sum()))
        log_ratio = log_r[np.searchsorted(looked, cells)]
        self._dets_now = dict(zip(cells.tolist(), zip(np.exp(log_ratio).tolist(),
                                                      (-np.expm1(-lam)).tolist(),
                                                      strict=True), strict=True))
        self._weights_now = {tr.id: (float(r[i]), float(lik0[i]), mean_xy[i], cov_xy[i])
                             for i, tr in enumerate(tracks)}
        assoc = self._associator.associate(tracks, dets, t) if tracks else {}
        used = set()
        lik = lik0.copy()
        for i, tr in enumerate(tracks):
            hyp = assoc[tr]
            if hyp:
                cell = hyp.measurement.metadata["cell"]
                ratio, _ = self._dets_now[cell]
                lik[i] += ge.cell_mass(self._grid, mean_xy[i], cov_xy[i], cell) * (ratio - 1.0)
                tr.append(self._updater.update(hyp))
                used.add(cell)
            else:
                tr.append(hyp.prediction)
        r = ge.existence_update(r, lik)
        for tr, ri in zip(tracks, r, strict=True):
            self._r[tr.id] = float(ri)
        # every free detection starts a track (in cell order)
        r0 = ge.birth_existence(lam, log_ratio)
        for det, r0_z in zip(dets, r0, strict=True):
            if det.metadata["cell"] in used:
                continue
            (track,) = self._starter.initiate([det], t)
            tracks.append(track)
            self._r[track.id] = float(r0_z)
        self._undetected.multiply(looked, self._miss ** n_looks)
        dead = [tr for tr in tracks if self._r[tr.id] < self.existence_threshold
                or np.trace(_mean_cov(tr.state)[1][np.ix_([0, 2], [0, 2])]) > self._max_trace]
        if dead:
            m_d, P_d = zip(*(_mean_cov(tr.state) for tr in dead), strict=True)
            recycle(self._undetected, self._grid, np.array([self._r.pop(tr.id) for tr in dead]),
                    np.array(m_d), np.array(P_d))
        gone = {tr.id for tr in dead}
        self._tracks = [tr for tr in tracks if tr.id not in gone]

    def _recycle(self, tracks: list[Any]) -> None:
        """Deleted tracks' existence back into the undetected intensity over their
        position Gaussians (Williams 2012's recycling, as pmb and ss-jpda): ``lambda_c +=
        r m_c``. Their scores are brought up to this step first (the composite deleter stops
        at the first deleter that deletes)."""
        if not tracks:
            return
        for track in tracks:
            self._score_deleter.check_for_deletion(track)
        r = self._existence(tracks)
        for track in tracks:
            del self._score_deleter.scores[track.id]
            self._prior_logodds.pop(track.id, None)
        m, P = zip(*(_mean_cov(tr.state) for tr in tracks), strict=True)
        recycle(self._undetected, self._grid, r, np.array(m), np.array(P))

    def _existence(self, tracks: list[Any]) -> np.ndarray:
        """``sigmoid(L0 + log(p_d / p_f) + L)`` per track: ``L0 = log(exp(lambda_c) -
        1)``, the prior log-odds of an untracked target in its birth cell ``c`` (the
        undetected intensity there at its birth), its birth detection and the score
        deleter's ``L`` (current for every track after :meth:`update`; 0 for a holding
        track born this step)."""
        if self.association == "existence":
            return np.array([self._r[tr.id] for tr in tracks], dtype=float)
        scores = self._score_deleter.scores
        prior = np.array([self._prior_logodds[tr.id] for tr in tracks])
        return expit(prior + self._log_pos
                     + np.array([scores.get(tr.id, _UNSCORED)[0] for tr in tracks]))

    def estimate(self) -> Estimate:
        """The ``round(sum r)`` tracks of largest existence ``r``, confirmed or holding:
        count ``sum r``, states ``(n, 4)``, covariances ``(n, 4, 4)`` and labels: per
        target (:class:`~mttbench.trackers.stonesoup.gnn_cells.LabelKeeper`, the default)
        or per Stone Soup track."""
        tracks = self._tracks + sorted(self._initiator.holding_tracks, key=track_key)
        r = self._existence(tracks)
        total = float(r.sum())
        keep = np.sort(np.argsort(-r, kind="stable")[:min(int(round(total)), len(r))])
        tracks = [tracks[i] for i in keep]
        n = len(tracks)
        m, P = np.zeros((n, 4)), np.zeros((n, 4, 4))
        labels = np.zeros(n, dtype=np.int64)
        for i, tr in enumerate(tracks):
            m[i], P[i] = _mean_cov(tr.state)
            labels[i] = self._track_labels.setdefault(tr.id, len(self._track_labels))
        if self.labels == "target":
            labels = self._label_keeper.labels([tr.id for tr in tracks], m, P)
        return Estimate(total, m, P, labels)

    @classmethod
    def resource_terms(cls, params, model, looks_per_step, targets) -> ResourceTerms:
        """The peers' terms and the undetected field of the cells looked at so far."""
        return dataclasses.replace(
            super().resource_terms(params, model, looks_per_step, targets),
            looked_cell_bytes=LOOKED_CELL_BYTES, looked_cell_seconds=LOOKED_CELL_S)


# ======================================================================== GM-PHD
@register
class StoneSoupGMPHD(_StoneSoupPeer):
    """Stone Soup's GM-PHD filter (module docstring)."""

    name = "ss-gmphd"
    summary = ("Stone Soup's GM-PHD (PHD updater, Gaussian-mixture reducer, birth "
               "components at detected cells) on cell detections; optional extra")
    parameters: ClassVar[dict[str, Param]] = {
        "birth_scale": Param(float, 0, low_open=True, search=Search(0.1, 10.0, log=True),
                             doc="a birth component's weight, in multiples of the "
                                 "undetected intensity at its detection's cell"),
        "birth_velocity_scale": Param(float, 0, low_open=True,
                                      search=Search(0.5, 2.0, log=True),
                                      doc="velocity sd of a birth component, in multiples "
                                          "of the model's birth velocity sd"),
        "prune_threshold": Param(float, 0, 1, high_open=True,
                                 search=Search(1e-6, 1e-3, log=True),
                                 doc="components lighter than this are pruned (with "
                                     "max_components, it bounds a step's cost)"),
        "merge_threshold": Param(float, 0, search=Search(0.5, 25.0, log=True),
                                 doc="squared Mahalanobis distance within which "
                                     "components merge"),
        "max_components": Param(int, 1, doc="at most this many components kept"),
        "gate": Param(float, 0, low_open=True,
                      doc="Mahalanobis distance beyond which a component does not "
                          "explain a detection"),
        "extraction_threshold": Param(float, 0, 1, search=Search(0.2, 0.9),
                                      doc="components heavier than this are reported"),
        "count": Param(choices=("sum", "round"), doc="the count: sum of the weights, or "
                                                     "its rounding"),
    }
    budget: ClassVar[dict[str, Budget]] = {
        "max_components": Budget(3, 300, doc="components kept; Stone Soup costs about 2 ms "
                                             "per component and step in clutter, so 300 "
                                             "is 0.5-1 s per step"),
    }

    def __init__(self, birth_scale: float = 1.0, birth_velocity_scale: float = 1.0,
                 prune_threshold: float = 1e-5, merge_threshold: float = 9.0,
                 max_components: int = 100, gate: float = 5.0,
                 extraction_threshold: float = 0.3, count: str = "sum") -> None:
        self.birth_scale = birth_scale
        self.birth_velocity_scale = birth_velocity_scale
        self.prune_threshold = prune_threshold
        self.merge_threshold = merge_threshold
        self.max_components = max_components
        self.gate = gate
        self.extraction_threshold = extraction_threshold
        self.count = count

    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        """Stone Soup's components; an empty mixture ``w (K,)``, ``m (K, 4)``, ``P``."""
        ss = self._reset_common(model)
        self._rng = rng  # unused: the tracker is deterministic
        self._ss = ss
        self._hypothesiser = ss.GaussianMixtureHypothesiser(
            ss.DistanceHypothesiser(self._predictor, self._updater, measure=ss.Mahalanobis(),
                                    missed_distance=self.gate),
            order_by_detection=True)
        self._reducer = ss.GaussianMixtureReducer(
            prune_threshold=self.prune_threshold, merge_threshold=self.merge_threshold,
            max_number_components=self.max_components)
        bd = model.birth_death
        self._p_s = bd.survival_probability
        sv = self.birth_velocity_scale * bd.birth_velocity_std
        self._birth_P = np.diag([self._r_var, sv * sv, self._r_var, sv * sv])
        sensor = model.sensor
        self._p_d, self._p_f = sensor.p_d, sensor.p_f
        self._p_target = target_detection_probability(sensor.p_d, sensor.p_f)
        self._miss = look_ratios(sensor).miss
        n = model.grid.n_cells
        self._birth_per_cell = bd.birth_rate / n
        self._undetected = CellField(n, bd.initial_count_mean / n)  # lambda_c
        self._expected = bd.initial_count_mean  # the model's expected count, E[N_k]
        self._w = np.zeros(0)
        self._m = np.zeros((0, 4))
        self._P = np.zeros((0, 4, 4))
        self._label = np.zeros(0, dtype=np.int64)  # a component's label (its tag)
        self._next_label = 0

    def set_components(self, w: np.ndarray, m: np.ndarray, P: np.ndarray) -> None:
        """Replace the mixture (tests): ``w (K,)``, ``m (K, 4)``, ``P (K, 4, 4)``; labels
        ``0 .. K-1``."""
        self._w = np.array(w, dtype=float).reshape(-1)
        self._m = np.array(m, dtype=float).reshape(-1, 4)
        self._P = np.array(P, dtype=float).reshape(-1, 4, 4)
        self._label = np.arange(len(self._w), dtype=np.int64)
        self._next_label = len(self._w)

    @property
    def components(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of ``w (K,)``, ``m (K, 4)``, ``P (K, 4, 4)`` (sorted, see module doc)."""
        return self._w.copy(), self._m.copy(), self._P.copy()

    def predict(self) -> None:
        """The next step (Stone Soup predicts inside the update); the undetected intensity
        ``p_s lambda + b / n``."""
        self._k += 1
        self._undetected.affine(self._p_s, self._birth_per_cell)
        self._expected = self._p_s * self._expected + self._birth_per_cell * self._grid.n_cells

    def cell_count_distribution(self) -> CellCounts:
        """Poisson with the predicted intensity mass per cell: rows of their own within 6
        sd of a component and at the cells looked at so far, the undetected intensity
        alone everywhere else."""
        m, P = kalman.predict(self._m, self._P, self._F, self._Q)
        comp, cells, mass = gaussian_cell_mass_sparse(self._grid,
                                                      *kalman.position_marginal(m, P))
        field = self._undetected
        own, inv = np.unique(np.concatenate([cells, field.cells]), return_inverse=True)
        lam = np.bincount(inv[:len(cells)], weights=(self._p_s * self._w)[comp] * mass,
                          minlength=len(own)) + field.at(own)
        return CellCounts(self._grid.n_cells, own, poisson_counts(lam, N_COUNTS),
                          poisson_counts(np.array([field.default]), N_COUNTS)[0])

    def _state(self, w: float, m: np.ndarray, P: np.ndarray, tag: str, k: int) -> Any:
        return self._ss.TaggedWeightedGaussianState(m.reshape(4, 1), P, weight=w, tag=tag,
                                                     timestamp=self._time(k))

    def update(self, looks: Looks) -> None:
        """Stone Soup's GM-PHD update of the components in looked cells, plus birth
        components at detected cells; the others predicted only; then the reducer."""
        dets, looked_cells, n_looked = self._detections(looks)
        t, k = self._time(self._k), self._k
        m_pred, _ = kalman.predict(self._m, self._P, self._F, self._Q)
        alive = self._inside(m_pred)
        looked = np.isin(self._cells_of(m_pred), looked_cells) & alive
        comps = [self._state(w, m, P, str(lab), k - 1)
                 for w, m, P, lab in zip(self._w, self._m, self._P, self._label, strict=True)]
        out = []
        for c, on in zip(comps, alive & ~looked, strict=True):
            if on:  # not looked at: detection probability 0, the prediction times p_s
                pred = self._predictor.predict(c, timestamp=t)
                out.append(self._state(float(c.weight) * self._p_s,
                                       np.asarray(pred.state_vector, float),
                                       np.asarray(pred.covar, float), c.tag, k))
        if len(n_looked):
            p = float(np.mean(-np.expm1(n_looked * np.log1p(-self._p_target))))
            kappa = float(np.mean(-np.expm1(n_looked * np.log1p(-self._p_f)))
                          / self._grid.cell_size ** 2)
            # a birth's weight: the untracked targets expected in its cell before its looks,
            # lambda_c plus the model's expected count the mixture and lambda do not hold
            # (spread evenly): E[N_k] - p_s sum w - sum lambda, when positive
            spare = self._spare(self._p_s * float(self._w.sum()))
            lam = self.birth_scale * (
                self._undetected.at([d.metadata["cell"] for d in dets]) + spare)
            births = [self._state(float(b),
                                  np.array([d.state_vector[0, 0], 0.0, d.state_vector[1, 0], 0.0]),
                                  self._birth_P, "birth", k - 1)
                      for b, d in zip(lam, dets, strict=True)]
            active = [c for c, on in zip(comps, looked, strict=True) if on] + births
            updater = self._ss.PHDUpdater(self._updater, clutter_spatial_density=kappa,
                                          prob_detection=p, prob_survival=self._p_s)
            hyps = self._hypothesiser.hypothesise(active, dets, t)
            out += list(updater.update(hyps).components)
        if out:
            out = self._reduce(out)
        self._set_sorted(out)
        self._undetected.multiply(looked_cells, self._miss ** n_looked)

    def _reduce(self, comps: list[Any]) -> list[Any]:
        """Stone Soup's ``GaussianMixtureReducer.reduce`` (prune, merge, then truncate to
        ``max_components``), its own steps in its order, with the merged mixture put in the
        order of :func:`_sorted` before the truncation. Stone Soup's merge emits the
        components that share a tag in the order of a set of tags (salted string hashes),
        and its truncation keeps the first of equal weights: in clutter, births at
        isolated detections tie exactly, so a binding cap kept different components in
        processes with different hash seeds."""
        reducer = self._reducer
        if reducer.pruning:
            comps = reducer.prune(comps)
        if len(comps) > 1 and reducer.merging:
            comps = reducer.merge(comps)
        if len(comps) > reducer.max_number_components and reducer.truncating:
            order = _sorted(comps)[3]
            comps = reducer.truncate([comps[i] for i in order])
        return comps

    def _set_sorted(self, comps: list[Any]) -> None:
        """The mixture as arrays, sorted by (weight descending, mean, covariance)."""
        w, m, P, order = _sorted(comps)
        self._w, self._m, self._P = w[order], m[order], P[order]
        # labels: Stone Soup's reducer gives a merged component the tag of its heaviest
        # member and fresh random tags to lighter ones that shared a tag; heaviest first, a
        # label tag seen for the first time is kept, any other tag (a birth, a fresh one, a
        # repeat) gets the next new label
        label, seen = np.zeros(len(comps), dtype=np.int64), set()
        for j, i in enumerate(order):
            tag = str(comps[i].tag)
            if tag.isdigit() and int(tag) not in seen:
                label[j] = int(tag)
            else:
                label[j] = self._next_label
                self._next_label += 1
            seen.add(int(label[j]))
        self._label = label

    def estimate(self) -> Estimate:
        """Components above ``extraction_threshold``; count ``sum w`` or its rounding;
        labels from the components' tags (a GM-PHD keeps no track identity, so the label
        of a component follows Stone Soup's tags: kept through updates and by the heaviest
        member of a merge, new for births; deterministic, unlike Stone Soup's own random
        tags)."""
        total = float(self._w.sum())
        count = total if self.count == "sum" else float(round(total))
        sel = self._w > self.extraction_threshold
        return Estimate(count, self._m[sel].copy(), self._P[sel].copy(),
                        self._label[sel].copy())

    @classmethod
    def resource_terms(cls, params, model, looks_per_step, targets) -> ResourceTerms:
        """The peers' terms, ``P_c(t)`` from at most ``max_components`` Gaussians' boxes."""
        gaussians = min(gaussian_boxes(targets), param_number(params, "max_components", 200))
        return dataclasses.replace(
            super().resource_terms(params, model, looks_per_step, targets),
            prediction_entries=gaussians * BOX_CELLS)

"""``ss-jpda``: Stone Soup's JPDA with efficient hypothesis management behind the
:class:`~mttbench.trackers.base.Tracker` interface, tracks initiated, deleted and reported
by an existence probability computed from the model (JIPDA-style track management).

An optional extra, as ``ss-gnn`` and ``ss-gmphd`` (:mod:`~mttbench.trackers.
stonesoup.peers`, whose model conversion, detections, undetected intensity and
determinism measures it shares): Stone Soup is imported on the first :meth:`reset`.

Stone Soup's components, unchanged
    ``JPDAwithEHM`` (``stonesoup.dataassociator.probability``: exact marginal association
    probabilities by Maskell's efficient hypothesis management, per cluster of tracks that
    share gated detections), ``PDAHypothesiser`` (one per track, see below),
    ``KalmanPredictor``, ``PDAUpdater`` (``stonesoup.updater.probability``: the PDA update
    of a track from its ``MultipleHypothesis``, ``x = x_p + K sum_i b_i nu_i``, ``P = b_0
    P_p + (1 - b_0) (I - K H) P_p + K (sum_i b_i nu_i nu_i^T - nu nu^T) K^T``, equal to
    Stone Soup's JPDA tutorial's Gaussian-mixture reduction), and ``SimpleMeasurementInitiator``
    (a new track at the detection, covariance ``R``, velocity 0 with sd ``velocity_scale``
    times the model's birth velocity sd). Model, detections (one per positive cell at its
    centre, ``R = cell^2 / 12 I``) and clutter as the other peers.

Per-track hypothesiser (the detection probability of a track)
    ``PDAHypothesiser`` weighs the missed detection ``1 - P_D P_G`` and detection ``i``
    ``P_D N(z_i; H x, S) / kappa`` (``P_G`` = ``gate_probability``, detections outside the
    ``P_G`` chi-square gate dropped). The adapter gives each track its own hypothesiser with
    ``P_D = r sum_c q_c (1 - (1 - p)^n_c)``, ``p = (p_d - p_f) / (1 - p_f)`` the cell
    sensor's detection of a target beside independent clutter (:func:`~mttbench.trackers.
    stonesoup.peers.target_detection_probability`): ``q_c`` the predicted position Gaussian's
    mass in looked cell ``c`` (within 6 sd), ``n_c`` the looks at it this step, ``r`` the
    track's existence probability. With that ``P_D`` the joint association weights that
    JPDA's EHM marginalises are JIPDA's (Musicki & Evans, "Joint integrated probabilistic
    data association: JIPDA", IEEE TAES 2004): a track either does not exist, or exists
    undetected, or is detected. A track with ``P_D / r`` below :data:`MIN_DETECTION` is not
    looked at: it keeps its prediction. ``kappa = p_f / cell_size^2`` (``1 - (1 - p_f)^n``
    per cell looked ``n`` times, averaged over the looked cells as the GM-PHD's), from the
    model's ``p_f``. Each hypothesiser is handed only the detections within its gate (a numpy
    pre-gate with a 1e-6 margin on the same chi-square bound; Stone Soup's own gate
    decides), which changes nothing but the cost.

Confirmed tracks jointly, tentative tracks one by one
    The confirmed tracks (existence once at least ``1 - alpha``, ``alpha`` =
    ``false_track_probability``) are associated jointly by ``JPDAwithEHM``. Tentative
    tracks are associated one by one (IPDA, Musicki, Evans & Stankovic 1994) on what the
    confirmed tracks leave of each detection: detection ``z``'s weight in a tentative
    track's ``PDAHypothesiser`` output is multiplied by ``1 - s_z``, ``s_z`` the confirmed
    tracks' marginal probability of ``z``. Deviation from JIPDA, for the cost: in clutter
    every positive cell starts a tentative track, and EHM over all of them (whose gates
    share most of the detections) is exponential in the detections a cluster shares.

Existence and the state (JIPDA on Stone Soup's marginals)
    From the marginals ``b_0`` (missed) and ``b_i`` (detection ``i``) of a track with
    prior existence ``r``: the missed weight ``1 - r P_D P_G`` is the track's absence
    ``1 - r`` plus its undetected presence ``r (1 - P_D P_G)``, so

        r+ = 1 - b_0 (1 - r) / (1 - r P_D P_G),

    and the state given existence is the PDA mixture with weights ``b_0 r (1 - P_D P_G) /
    ((1 - r P_D P_G) r+)`` (missed) and ``b_i / r+``, which the adapter hands to Stone
    Soup's ``PDAUpdater`` as a ``MultipleHypothesis``. With ``r = 1`` it is Stone Soup's
    JPDA exactly. Between steps ``r <- p_s r`` (model survival).

Initiation (births from the model)
    The adapter keeps KF-NN's undetected Poisson intensity ``lambda_c`` per cell (as
    ``ss-gnn``: initial count over the grid, ``p_s lambda + birth_rate / n`` per step,
    ``((1 - p_d) / (1 - p_f))^n`` per look). A detection in cell ``c`` that the tracks do
    not explain (``s``: the sum of every track's marginal probability of it) starts a
    tentative track with existence

        r0 = (1 - s) (1 - exp(-lambda_c P)) / (1 - (1 - p_f,c) exp(-lambda_c P)),

    ``P = 1 - (1 - p_d)^n``, ``p_f,c = 1 - (1 - p_f)^n``: the probability that the
    positive cell holds a newly detected target rather than only clutter. (For one look
    and a small ``lambda_c`` this is ``lambda p_d / (p_f + lambda p_d (1 - p_f))``, near the
    exact ``lambda p_d / (p_f + lambda (p_d - p_f))``: a present target leaves the cell
    positive with ``p_d`` whatever the clutter; ``P_D = (p_d - p_f) / (1 - p_f)`` in place
    of ``p_d`` would count only the target's own detections, docs/stonesoup.md.) (The
    track-oriented PMB puts the new target into the joint association; using the tracks'
    marginal ``s`` is the usual approximation of JIPDA trackers.) At ``p_f = 5e-4`` on the
    presets a first detection gives ``r0`` near 0.95; at ``p_f = 0.3``, 0.034.

Deletion, recycling and the cap (error rates and bounds, as ``ss-gnn``)
    A confirmed track is deleted when ``r < beta`` (``lost_track_probability``), a
    tentative one when ``r < prune_existence``; any track whose position sd (root half
    trace of its position covariance) exceeds ``max_position_sd`` cells is deleted by Stone
    Soup's ``CovarianceBasedDeleter`` (a track that has coasted that long says nothing,
    and its gate would take every detection); at most ``max_tracks`` are kept, the most
    probable (ties by age). A tentative track dropped by the prune or the cap gives its
    existence back to the undetected intensity of its mean's cell (recycling, Williams,
    "Hybrid Poisson and multi-Bernoulli filters", FUSION 2012), so the expected count is
    not lost with it.

Estimate (the count and the reported states)
    The expected number of targets among the tracks, ``sum r``, rounded; the states of
    that many tracks of highest existence (ties by age). Count = the number reported. (An
    "existence above a threshold" estimate collapses in clutter, where no track may reach
    the threshold while the existences sum to most of the targets; docs/stonesoup.md.)

Cost per step (bounded in clutter)
    JPDA (EHM) only over the confirmed tracks, whose number the estimate keeps near the
    count; each tentative track costs its gated detections; the cap bounds the tracks;
    the covariance deleter bounds a gate (measured: docs/stonesoup.md). Nothing per cell of the
    grid (``P_c(t)``: the tracks' Gaussian masses within 6 sd times their existence, and
    the undetected intensity of the cells looked at so far).

Determinism
    Tracks are kept in a list ordered by the detection that started them (step, cell),
    detections in cell order; Stone Soup's cluster and EHM code iterates lists and dicts
    in that order. Labels: a stable id per Stone Soup track, numbered when first reported.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from types import SimpleNamespace
from typing import Any, ClassVar

import numpy as np

from ...scenarios.model import Looks, TrackingModel
from .. import kalman
from ..base import LOOKED_CELL_BYTES, LOOKED_CELL_S, Estimate, ResourceTerms, register
from ..cell_evidence import look_ratios
from ..cells import (
    CellCounts,
    CellField,
    bernoulli_cell_counts,
    gaussian_cell_mass_sparse,
    untracked_probabilities,
)
from ..params import Budget, Param, Search
from ..pmb.ppp import add_intensity
from .peers import (
    N_COUNTS,
    _mean_cov,
    _StoneSoupPeer,
    stonesoup,
    target_detection_probability,
)

#: a track whose detection probability this step (its mass in the looked cells times p_d)
#: is below this is not looked at: it keeps its prediction
MIN_DETECTION = 1e-6
#: the numpy pre-gate admits squared distances up to this factor of Stone Soup's bound
#: (Stone Soup's own gate then decides; the margin only absorbs round-off)
PREGATE_MARGIN = 1.0 + 1e-6


@functools.cache
def _jpda() -> SimpleNamespace:
    """Stone Soup's JPDA classes, and the per-track hypothesiser built on its base."""
    stonesoup()  # ImportError naming the extra when Stone Soup is missing
    from stonesoup.base import Property
    from stonesoup.dataassociator.probability import JPDAwithEHM
    from stonesoup.deleter.error import CovarianceBasedDeleter
    from stonesoup.hypothesiser.base import Hypothesiser
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.initiator.simple import SimpleMeasurementInitiator
    from stonesoup.types.hypothesis import SingleProbabilityHypothesis
    from stonesoup.types.multihypothesis import MultipleHypothesis
    from stonesoup.updater.probability import PDAUpdater

    class PerTrackHypothesiser(Hypothesiser):
        """Hands each track to its own ``PDAHypothesiser`` (its own detection probability),
        with the detections in its gate."""

        hypothesisers: dict = Property(doc="track -> PDAHypothesiser")
        candidates: dict = Property(doc="track -> list of the detections in its gate")

        def hypothesise(self, track, detections, timestamp, **kwargs):
            return self.hypothesisers[track].hypothesise(track, self.candidates[track],
                                                         timestamp, **kwargs)

    return SimpleNamespace(
        JPDAwithEHM=JPDAwithEHM, CovarianceBasedDeleter=CovarianceBasedDeleter,
        PDAHypothesiser=PDAHypothesiser,
        SimpleMeasurementInitiator=SimpleMeasurementInitiator,
        SingleProbabilityHypothesis=SingleProbabilityHypothesis,
        MultipleHypothesis=MultipleHypothesis, PDAUpdater=PDAUpdater,
        PerTrackHypothesiser=PerTrackHypothesiser)


@register
class StoneSoupJPDA(_StoneSoupPeer):
    """Stone Soup's JPDA with EHM, existence-based track management (module docstring)."""

    name = "ss-jpda"
    summary = ("Stone Soup's JPDA with EHM (PDA hypothesiser, PDA updater) on cell "
               "detections, tracks by existence from the model; optional extra")
    parameters: ClassVar[dict[str, Param]] = {
        "gate_probability": Param(float, 0, 1, low_open=True, high_open=True,
                                  search=Search(0.9, 0.999),
                                  doc="P_G: a detected target's detection falls in the "
                                      "chi-square gate with this probability"),
        "false_track_probability": Param(
            float, 0, 1, low_open=True, high_open=True, search=Search(1e-3, 0.5, log=True),
            doc="alpha: a track is confirmed (joint JPDA, deleted only below beta) once "
                "its existence is >= 1 - alpha"),
        "lost_track_probability": Param(
            float, 0, 1, low_open=True, high_open=True, search=Search(1e-3, 0.3, log=True),
            doc="beta: a confirmed track is deleted when its existence is below beta"),
        "prune_existence": Param(float, 0, 1, low_open=True, high_open=True,
                                 search=Search(1e-4, 1e-2, log=True),
                                 doc="tentative tracks below this existence are dropped"),
        "max_tracks": Param(int, 1, doc="at most this many tracks kept, the most probable "
                                        "(bounds a step's cost in clutter)"),
        "max_position_sd": Param(float, 0, low_open=True, search=Search(1.5, 8.0, log=True),
                                 doc="a track whose position sd (root half trace, in "
                                     "cells) exceeds this is deleted (Stone Soup's "
                                     "CovarianceBasedDeleter)"),
        "velocity_scale": Param(float, 0, low_open=True, search=Search(0.5, 2.0, log=True),
                                doc="velocity sd of a new track, in multiples of the "
                                    "model's birth velocity sd"),
    }
    budget: ClassVar[dict[str, Budget]] = {
        "max_tracks": Budget(5, 120, doc="tracks kept; 5 is just above the small presets' "
                                         "3-4 targets, 120 twice the default"),
    }

    def __init__(self, gate_probability: float = 0.99, false_track_probability: float = 0.1,
                 lost_track_probability: float = 0.05, prune_existence: float = 1e-3,
                 max_tracks: int = 60, max_position_sd: float = 5.0,
                 velocity_scale: float = 1.0) -> None:
        self.gate_probability = gate_probability
        self.false_track_probability = false_track_probability
        self.lost_track_probability = lost_track_probability
        self.prune_existence = prune_existence
        self.max_tracks = max_tracks
        self.max_position_sd = max_position_sd
        self.velocity_scale = velocity_scale

    @classmethod
    def param_conflict(cls, params):
        alpha, beta = params["false_track_probability"], params["lost_track_probability"]
        if beta >= 1.0 - alpha:
            return (f"lost_track_probability ({beta}) must be below 1 - "
                    f"false_track_probability ({1.0 - alpha}): a track would be deleted as "
                    "soon as it is confirmed")
        return None

    # ------------------------------------------------------------------ run state
    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        """Stone Soup's components; no tracks; KF-NN's undetected intensity."""
        ss = self._reset_common(model)
        js = _jpda()
        self._rng = rng  # unused: the tracker is deterministic
        self._js = js
        self._pda_updater = js.PDAUpdater(self._measurement)
        bd, sensor, n = model.birth_death, model.sensor, model.grid.n_cells
        sv2 = (self.velocity_scale * bd.birth_velocity_std) ** 2
        prior = ss.GaussianState(np.zeros((4, 1)), np.diag([0.0, sv2, 0.0, sv2]),
                                 timestamp=self._time(-1))
        self._initiator = js.SimpleMeasurementInitiator(prior_state=prior,
                                                        measurement_model=self._measurement)
        self._p_s, self._birth_per_cell = bd.survival_probability, bd.birth_rate / n
        self._p_d, self._p_f = sensor.p_d, sensor.p_f
        self._p_target = target_detection_probability(sensor.p_d, sensor.p_f)
        self._miss = look_ratios(sensor).miss
        self._undetected = CellField(n, bd.initial_count_mean / n)
        self._gate_d2 = kalman.gate_d2(self.gate_probability)
        sd = self.max_position_sd * model.grid.cell_size
        self._cov_deleter = js.CovarianceBasedDeleter(covar_trace_thresh=2.0 * sd * sd,
                                                      mapping=[0, 2])
        self._tracks: list[Any] = []  # in the order of the detections that started them
        self._r = np.zeros(0)  # existence probability per track
        self._confirmed = np.zeros(0, dtype=bool)
        #: a track's label by its Stone Soup id, numbered in the order first reported
        self._track_labels: dict[str, int] = {}

    def set_tracks(self, m: np.ndarray, P: np.ndarray, r: np.ndarray,
                   confirmed: np.ndarray | None = None) -> None:
        """Replace the tracks (tests): posterior means ``m (K, 4)``, covariances
        ``P (K, 4, 4)`` at the current step, existences ``r (K,)``."""
        ss = stonesoup()
        from stonesoup.types.track import Track
        m = np.asarray(m, float).reshape(-1, 4)
        P = np.asarray(P, float).reshape(-1, 4, 4)
        t = self._time(self._k)
        self._tracks = [Track([ss.GaussianState(mi.reshape(4, 1), Pi, timestamp=t)])
                        for mi, Pi in zip(m, P, strict=True)]
        self._r = np.asarray(r, float).reshape(len(m)).copy()
        self._confirmed = (np.zeros(len(m), bool) if confirmed is None
                           else np.asarray(confirmed, bool).reshape(len(m)).copy())

    @property
    def existence(self) -> np.ndarray:
        """A copy of the tracks' existence probabilities ``(K,)``."""
        return self._r.copy()

    def predict(self) -> None:
        """The next step (Stone Soup predicts inside the association): existence ``p_s r``;
        the undetected intensity ``p_s lambda + b / n``."""
        self._k += 1
        self._r = self._p_s * self._r
        self._undetected.affine(self._p_s, self._birth_per_cell)

    def cell_count_distribution(self) -> CellCounts:
        """Poisson-binomial of the tracks (their existence, predicted Gaussians within 6
        sd) and of the untracked targets (the undetected intensity)."""
        m, P = self._predicted(self._tracks)
        comp, cells, mass = gaussian_cell_mass_sparse(self._grid,
                                                      *kalman.position_marginal(m, P))
        return bernoulli_cell_counts(self._grid.n_cells, N_COUNTS, cells,
                                     mass * self._r[comp],
                                     *untracked_probabilities(self._undetected))

    def _predicted(self, tracks: list[Any]) -> tuple[np.ndarray, np.ndarray]:
        m = np.zeros((len(tracks), 4))
        P = np.zeros((len(tracks), 4, 4))
        for i, tr in enumerate(tracks):
            m[i], P[i] = _mean_cov(tr.state)
        return kalman.predict(m, P, self._F, self._Q)

    # ------------------------------------------------------------------ the step
    def update(self, looks: Looks) -> None:
        """JPDA (EHM) of the confirmed tracks in looked cells with per-track ``P_D = r
        p_D``; each tentative track in a looked cell by itself (IPDA) on what the confirmed
        tracks leave of the detections; existences and PDA updates; the others predicted;
        new tracks from the detections the tracks do not explain; confirmation, deletion
        and the cap (module docstring)."""
        dets, looked, n_looks = self._detections(looks)
        t = self._time(self._k)
        js = self._js
        m_pred, P_pred = self._predicted(self._tracks)
        alive = self._inside(m_pred)
        pd_cell = self._detection_probability(m_pred, P_pred, looked, n_looks)
        r = self._r.copy()
        explained = np.zeros(len(dets))  # s_z: marginal probability a detection is a track's
        seen = pd_cell >= MIN_DETECTION
        for i in np.flatnonzero(alive & ~seen):  # not looked at: prediction only
            self._tracks[i].append(self._predictor.predict(self._tracks[i].state, timestamp=t))
        active = np.flatnonzero(alive & seen)
        if len(active):
            kappa = float(np.mean(-np.expm1(n_looks * math.log1p(-self._p_f)))
                          / self._grid.cell_size ** 2)
            z = np.array([d.state_vector.ravel() for d in dets], float).reshape(-1, 2)
            gated = self._in_gate(m_pred[active], P_pred[active], z)
            index = {id(d): j for j, d in enumerate(dets)}

            def hypothesiser(i: int, normalise: bool) -> Any:
                return js.PDAHypothesiser(
                    self._predictor, self._updater, clutter_spatial_density=kappa,
                    prob_detect=float(r[i] * pd_cell[i]), prob_gate=self.gate_probability,
                    normalise=normalise)

            joint = [(i, g) for i, g in zip(active, gated, strict=True) if self._confirmed[i]]
            if joint:  # Stone Soup's JPDA with EHM over the confirmed tracks
                act = [self._tracks[i] for i, _ in joint]
                hyps = {tr: hypothesiser(i, True) for tr, (i, _) in zip(act, joint, strict=True)}
                cands = {tr: [dets[j] for j in np.flatnonzero(g)]
                         for tr, (_, g) in zip(act, joint, strict=True)}
                assoc = js.JPDAwithEHM(js.PerTrackHypothesiser(hyps, cands)).associate(
                    act, dets, t)
                for tr, (i, _) in zip(act, joint, strict=True):
                    r[i] = self._update_track(tr, assoc[tr], r[i], pd_cell[i], explained, index)
            left = 1.0 - np.clip(explained, 0.0, 1.0)
            claimed = np.zeros(len(dets))
            for i, g in zip(active, gated, strict=True):
                if self._confirmed[i]:
                    continue
                tr = self._tracks[i]  # tentative: PDA on the detections' unclaimed part
                multi = hypothesiser(i, False).hypothesise(tr, [dets[j] for j in
                                                                np.flatnonzero(g)], t)
                w = np.array([float(h.probability) * (left[index[id(h.measurement)]] if h
                                                      else 1.0) for h in multi])
                multi = js.MultipleHypothesis([js.SingleProbabilityHypothesis(
                    h.prediction, h.measurement, measurement_prediction=h.measurement_prediction,
                    probability=wi / w.sum()) for h, wi in zip(multi, w, strict=True)])
                r[i] = self._update_track(tr, multi, r[i], pd_cell[i], claimed, index)
            explained += claimed
        self._undetected_births(dets, looked, n_looks, explained, alive, r)

    def _detection_probability(self, m: np.ndarray, P: np.ndarray, looked: np.ndarray,
                               n_looks: np.ndarray) -> np.ndarray:
        """``(K,)``: ``sum_c q_kc (1 - (1 - p)^n_c)`` over the looked cells, ``q_kc`` the
        predicted position Gaussian's mass in cell ``c`` (within 6 sd)."""
        comp, cells, mass = gaussian_cell_mass_sparse(self._grid,
                                                      *kalman.position_marginal(m, P))
        n = _looks_at(cells, looked, n_looks)
        return np.bincount(comp, weights=mass * -np.expm1(n * math.log1p(-self._p_target)),
                           minlength=len(m))

    def _in_gate(self, m: np.ndarray, P: np.ndarray, z: np.ndarray) -> np.ndarray:
        """``(K, D)`` True where detection ``z (D, 2)`` is within the gate of predicted
        track ``(m (K, 4), P (K, 4, 4))`` (``S = H P H^T + R``)."""
        mz, Pz = kalman.position_marginal(m, P)
        S = Pz + self._r_var * np.eye(2)
        nu = z[None, :, :] - mz[:, None, :]  # (K, D, 2)
        sol = np.linalg.solve(S[:, None, :, :], nu[..., None])[..., 0]
        d2 = np.einsum("kdi,kdi->kd", nu, sol)
        return d2 <= self._gate_d2 * PREGATE_MARGIN

    def _update_track(self, track: Any, multi: Any, r: float, pd: float,
                      explained: np.ndarray, index: dict[int, int]) -> float:
        """JIPDA's existence and the PDA update (Stone Soup's PDAUpdater) of one track from
        its JPDA marginals; adds its detection marginals to ``explained``."""
        pg = self.gate_probability
        b0 = 0.0
        for h in multi:
            if h:
                explained[index[id(h.measurement)]] += float(h.probability)
            else:
                b0 = float(h.probability)
        miss_prior = 1.0 - r * pd * pg
        present_missed = b0 * r * (1.0 - pd * pg) / miss_prior
        r_post = present_missed + (1.0 - b0)
        if r_post <= 0.0:
            track.append(multi[0].prediction)
            return 0.0
        js = self._js
        reweighted = [js.SingleProbabilityHypothesis(
            h.prediction, h.measurement, measurement_prediction=h.measurement_prediction,
            probability=(float(h.probability) if h else present_missed) / r_post)
            for h in multi]
        track.append(self._pda_updater.update(js.MultipleHypothesis(reweighted)))
        return min(r_post, 1.0)

    def _undetected_births(self, dets: list[Any], looked: np.ndarray, n_looks: np.ndarray,
                           explained: np.ndarray, alive: np.ndarray, r: np.ndarray) -> None:
        """New tracks from the detections, confirmation, deletion, the cap; the looks'
        factor on the undetected intensity."""
        cells = np.array([d.metadata["cell"] for d in dets], dtype=np.int64)
        n = _looks_at(cells, looked, n_looks)
        pd = -np.expm1(n * math.log1p(-self._p_d))
        pf = -np.expm1(n * math.log1p(-self._p_f))
        x = self._undetected.at(cells) * pd  # detected undetected-target mean per cell
        r_new = ((1.0 - np.clip(explained, 0.0, 1.0)) * -np.expm1(-x)
                 / (1.0 - (1.0 - pf) * np.exp(-x)))
        born = np.flatnonzero(r_new >= self.prune_existence)
        t = self._time(self._k)
        new_tracks = [next(iter(self._initiator.initiate({dets[j]}, t))) for j in born]
        tracks = self._tracks + new_tracks
        r = np.concatenate([r, r_new[born]])
        sharp = np.array([not self._cov_deleter.check_for_deletion(tr) for tr in tracks],
                         dtype=bool)
        keep_alive = np.concatenate([alive, np.ones(len(born), bool)]) & sharp
        confirmed = np.concatenate([self._confirmed, np.zeros(len(born), bool)])
        confirmed |= r >= 1.0 - self.false_track_probability
        keep = keep_alive & np.where(confirmed, r >= self.lost_track_probability,
                                     r >= self.prune_existence)
        if keep.sum() > self.max_tracks:  # the most probable, ties by age (stable sort)
            idx = np.flatnonzero(keep)
            best = idx[np.argsort(-r[idx], kind="stable")[:self.max_tracks]]
            keep = np.zeros(len(r), bool)
            keep[best] = True
        self._undetected.multiply(looked, self._miss ** n_looks)
        # recycling (Williams 2012): the existence of a dropped tentative track (already
        # updated by this step's looks) goes back to the undetected intensity of its cell
        recycle = keep_alive & ~confirmed & ~keep
        if recycle.any():
            m = np.array([_mean_cov(tr.state)[0] for tr, g in zip(tracks, recycle, strict=True)
                          if g]).reshape(-1, 4)
            add_intensity(self._undetected, self._cells_of(m), r[recycle])
        self._tracks = [tr for tr, k in zip(tracks, keep, strict=True) if k]
        self._r, self._confirmed = r[keep], confirmed[keep]

    def estimate(self) -> Estimate:
        """The ``round(sum r)`` tracks of highest existence: count, states ``(n, 4)``,
        covariances ``(n, 4, 4)`` and a persistent label per track."""
        n = int(round(float(self._r.sum())))  # the expected count (EAP), rounded
        idx = np.sort(np.argsort(-self._r, kind="stable")[:n])
        m, P = np.zeros((len(idx), 4)), np.zeros((len(idx), 4, 4))
        labels = np.zeros(len(idx), dtype=np.int64)
        for k, i in enumerate(idx):
            tr = self._tracks[i]
            m[k], P[k] = _mean_cov(tr.state)
            labels[k] = self._track_labels.setdefault(tr.id, len(self._track_labels))
        return Estimate(float(len(idx)), m, P, labels)

    @classmethod
    def resource_terms(cls, params, model, looks_per_step, targets) -> ResourceTerms:
        """The peers' terms and the undetected field of the cells looked at so far."""
        return dataclasses.replace(
            super().resource_terms(params, model, looks_per_step, targets),
            looked_cell_bytes=LOOKED_CELL_BYTES, looked_cell_seconds=LOOKED_CELL_S)


def _looks_at(cells: np.ndarray, looked: np.ndarray, n_looks: np.ndarray) -> np.ndarray:
    """Looks this step at each of ``cells (K,)``, 0 where not looked at (``looked`` sorted)."""
    cells = np.asarray(cells, dtype=np.int64)
    if not len(looked) or not len(cells):
        return np.zeros(len(cells), dtype=np.int64)
    i = np.minimum(np.searchsorted(looked, cells), len(looked) - 1)
    return np.where(looked[i] == cells, n_looks[i], 0)


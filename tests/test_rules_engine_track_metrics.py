"""Rules of the track-level scores (benchmarks/engine/track_metrics.py) at their edges,
on runs small enough to count by hand: the parameters' allowed ranges, CLEAR-MOT's gate
(strict) when a truth keeps its track, fragmentations, and the crossings' first step
and zero window."""

from __future__ import annotations

import numpy as np
import pytest

from mttbench.benchmarks.engine import track_metrics as tm


def _one(points):
    return [np.array([p], dtype=float) for p in points]


def test_the_parameters_ranges():
    truth, ids = _one([(0, 0)] * 3), [np.array([0])] * 3
    with pytest.raises(ValueError, match="gamma must be positive"):
        tm.trajectory_gospa(truth, ids, truth, ids, gamma=0.0)
    with pytest.raises(ValueError, match="window must be >= 1"):
        tm.ospa2(truth, ids, truth, ids, window=0)
    assert tm.ospa2(truth, ids, truth, ids, window=1).total == 0.0
    with pytest.raises(ValueError, match="gate must be positive"):
        tm.clear_mot(truth, ids, truth, ids, gate=0.0)
    # a crossing window of 0 steps is allowed: near is exactly the close steps
    xs = [np.array([[0.0, 0.0], [d, 0.0]]) for d in (5.0, 1.0, 5.0, 5.0)]
    cr = tm.crossings(xs, [np.array([0, 1])] * 4, distance=2.0, window=0)
    assert cr.close.tolist() == [0, 1, 0, 0] and cr.near.tolist() == [False, True, False,
                                                                      False]
    with pytest.raises(ValueError, match="window must be an integer >= 0"):
        tm.crossings(xs, [np.array([0, 1])] * 4, window=-1)


def test_a_truth_keeps_its_track_only_strictly_inside_the_gate():
    # step 0: truth at 0 matched with track 7 (0.5 away); step 1: track 7 exactly at the
    # gate (1.0), track 8 at 0.9: the truth cannot keep 7 and is matched with 8, a switch
    truth, ids = _one([(0, 0), (0, 0)]), [np.array([0])] * 2
    est = [np.array([[0.5, 0.0]]), np.array([[1.0, 0.0], [0.9, 0.0]])]
    labels = [np.array([7]), np.array([7, 8])]
    m = tm.clear_mot(truth, ids, est, labels, gate=1.0)
    assert (m.id_switches, m.switch_steps.tolist()) == (1, [0, 1])
    # inside the gate it keeps track 7, although track 8 is nearer
    est[1] = np.array([[0.95, 0.0], [0.1, 0.0]])
    m = tm.clear_mot(truth, ids, est, labels, gate=1.0)
    assert m.id_switches == 0


def test_fragmentations_count_the_resumptions_within_a_truths_life():
    T = 7
    truth, ids = _one([(0, 0)] * T), [np.array([0])] * T
    # tracked at 0-1, lost at 2, tracked at 3, lost at 4-5, tracked at 6: two resumptions
    on = [True, True, False, True, False, False, True]
    est = [np.array([[0.2, 0.0]]) if t else np.zeros((0, 2)) for t in on]
    lab = [np.array([3]) if t else np.zeros(0, np.int64) for t in on]
    m = tm.clear_mot(truth, ids, est, lab, gate=1.0)
    assert (m.fragmentations, m.id_switches) == (2, 0)
    assert m.coverage.tolist() == [4 / 7]
    # tracked from the first step to the last without a gap: none
    m = tm.clear_mot(truth, ids, _one([(0.2, 0)] * T), [np.array([3])] * T, gate=1.0)
    assert (m.fragmentations, m.coverage.tolist()) == (0, [1.0])


def test_an_encounter_under_way_at_the_first_step_counts():
    xs = [np.array([[0.0, 0.0], [d, 0.0]]) for d in (1.0, 1.0, 5.0, 1.0)]
    cr = tm.crossings(xs, [np.array([0, 1])] * 4, distance=2.0, window=1)
    assert cr.starts.tolist() == [1, 0, 0, 1]
    assert cr.close.tolist() == [1, 1, 0, 1]
    assert cr.near.tolist() == [True, True, True, True]


def test_trajectory_gospa_of_one_clean_switch_by_hand():
    # one truth, track 1 for steps 0-2 then track 2 for steps 3-5, both exactly on it:
    # localisation 0, no miss, one switch between two tracks: gamma**p
    T = 6
    truth, ids = _one([(0, 0)] * T), [np.array([0])] * T
    lab = [np.array([1 if k < 3 else 2]) for k in range(T)]
    for gamma, p in ((2.0, 2.0), (1.0, 1.0), (1.5, 3.0)):
        g = tm.trajectory_gospa(truth, ids, truth, lab, c=2.0, p=p, gamma=gamma)
        assert (g.localisation, g.missed, g.false, g.switches) == (0.0, 0.0, 0.0, 1.0)
        assert g.switch == pytest.approx(gamma**p)
        assert g.total == pytest.approx(gamma)

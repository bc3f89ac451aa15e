"""Rules of the per-step and run-level metric registry (benchmarks/engine/metrics.py)
that a slip could break without changing the headline numbers: the cut-off's default,
GOSPA at exactly ``c``, RMSE with one point on a side, the shared computation equal to
the metric functions bit for bit, the registry's refusals and orders, the labels of
part columns, the mostly-tracked/lost thresholds and the run's cache keys."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mttbench.benchmarks.engine import metrics, track_metrics
from mttbench.benchmarks.engine.metrics import (
    Metric,
    RunData,
    RunMetric,
    builtin_run_columns,
    column_label,
    display_metrics,
    gospa,
    objective_names,
    ospa,
    register_metric,
    register_run_metric,
    run_level_metrics,
    step_metrics,
    unregister_metric,
    unregister_run_metric,
)


def test_the_cutoff_is_the_default_only_when_none_is_given():
    assert metrics.cutoff(None, 5.0) == 10.0  # two cells of 5
    assert metrics.cutoff(0.0, 5.0) == 0.0  # given: kept, and refused by the metrics
    with pytest.raises(ValueError, match="cut-off c must be positive"):
        step_metrics(np.zeros((1, 2)), np.zeros((1, 2)), 1.0, c=metrics.cutoff(0.0, 5.0))


@pytest.mark.parametrize("p", [1.0, 2.0, 3.0])
def test_a_pair_at_exactly_c_is_one_missed_and_one_false(p):
    truth, est = np.array([[0.0, 0.0]]), np.array([[2.0, 0.0]])  # distance exactly c = 2
    cp = 2.0**p
    g = gospa(truth, est, c=2.0, p=p)
    row = step_metrics(truth, est, 1.0, c=2.0, p=p)
    for loc, missed, false, total in ((g.localisation, g.missed, g.false, g.total),
                                      (row["gospa_loc"], row["gospa_missed"],
                                       row["gospa_false"], row["gospa"])):
        assert (loc, missed, false) == (0.0, cp / 2, cp / 2)
        assert total == pytest.approx(cp ** (1 / p))


def test_rmse_with_one_truth_takes_the_nearest_estimate_even_beyond_c():
    truth = np.array([[0.0, 0.0]])
    est = np.array([[5.0, 0.0], [3.0, 0.0], [0.0, 4.0]])  # all beyond c = 2: equal cut costs
    assert step_metrics(truth, est, 3.0, c=2.0)["rmse"] == 3.0
    assert step_metrics(est, truth, 1.0, c=2.0)["rmse"] == 3.0  # one estimate, three truths
    assert metrics.assigned_rmse(truth, est) == 3.0


def test_the_shared_run_columns_are_the_metric_functions_bit_for_bit():
    rng = np.random.default_rng(np.random.SeedSequence(20261129))
    truth, est = [], []
    for _ in range(200):
        n, m = rng.integers(0, 7, 2)
        truth.append(rng.uniform(0, 6, (n, 2)))
        est.append(rng.uniform(0, 6, (m, 2)))
    cols = builtin_run_columns(truth, est, [float(len(y)) for y in est], c=2.0, p=2.0)
    for k, (x, y) in enumerate(zip(truth, est, strict=True)):
        o = ospa(x, y, c=2.0, p=2.0)
        assert (cols["ospa"][k], cols["ospa_loc"][k], cols["ospa_card"][k]) == (
            o.total, o.localisation, o.cardinality)
        g = gospa(x, y, c=2.0, p=2.0)
        assert (cols["gospa"][k], cols["gospa_loc"][k]) == (g.total, g.localisation)


def _fn(truth, estimate, count, c, p):
    return {"probe": 0.0, "probe_a": 0.0}


def test_the_registry_refuses_a_repeated_column_and_the_step_counts():
    with pytest.raises(ValueError, match="must be distinct"):
        Metric("probe", _fn, ("probe", "probe_a", "probe_a"))
    for col in metrics.STEP_COUNTS:
        m = Metric("probe", _fn, ("probe", col))
        try:
            with pytest.raises(ValueError, match=f"column '{col}'"):
                register_metric(m)
        finally:
            unregister_metric("probe")


def test_a_builtin_per_step_metric_cannot_be_unregistered():
    for name in metrics.BUILTIN_METRICS:
        with pytest.raises(ValueError, match="cannot be unregistered"):
            unregister_metric(name)
    assert list(metrics.BUILTIN_METRICS) == metrics.metric_names()[:5]


def test_tables_show_the_objectives_first_then_the_others_in_registration_order():
    names = [m.name for m in display_metrics()]
    assert names[:5] == ["ospa", "gospa", "count_error", "rmse", "own_count_error"]
    assert metrics.metric_columns(display=True)[:3] == ["ospa", "ospa_loc", "ospa_card"]


def test_a_run_level_objective_is_offered_after_the_per_step_ones():
    m = RunMetric("probe_run", lambda run: {"probe_run": 1.0}, objective=True)
    register_run_metric(m)
    try:
        assert objective_names() == ["ospa", "gospa", "probe_run"]
    finally:
        unregister_run_metric("probe_run")
    assert objective_names() == ["ospa", "gospa"]


@pytest.mark.parametrize("column, label", [("ospa_loc", "OSPA loc"), ("ospa", "OSPA"),
                                           ("gospa_missed", "GOSPA missed"),
                                           ("own_count_error", "own count error"),
                                           ("tgospa_switch", "TGOSPA switch"),
                                           ("not_a_metric", "not_a_metric")])
def test_part_columns_are_labelled_by_their_part(column, label):
    assert column_label(column) == label


def _one_truth(tracked: list[bool]) -> RunData:
    """One truth at the origin for len(tracked) steps, a track at 0.5 from it where
    ``tracked``."""
    T = len(tracked)
    est = [np.array([[0.5, 0.0]]) if t else np.zeros((0, 2)) for t in tracked]
    lab = [np.array([9]) if t else np.zeros(0, np.int64) for t in tracked]
    return RunData([np.zeros((1, 2))] * T, [np.array([0])] * T, est, lab)


def test_mostly_tracked_and_lost_include_their_thresholds():
    # coverage 4/5 = 0.8 (the mostly-tracked threshold) and 1/5 = 0.2 (mostly lost)
    v = run_level_metrics(_one_truth([True, True, True, True, False]))
    assert (v["mostly_tracked"], v["mostly_lost"]) == (1.0, 0.0)
    v = run_level_metrics(_one_truth([False, False, True, False, False]))
    assert (v["mostly_tracked"], v["mostly_lost"]) == (0.0, 1.0)
    v = run_level_metrics(_one_truth([False, True, True, False, False]))  # 0.4: neither
    assert (v["mostly_tracked"], v["mostly_lost"]) == (0.0, 0.0)


def test_n_estimated_counts_the_states_not_the_trackers_count():
    row = step_metrics(np.zeros((1, 2)), np.array([[0.0, 0.0], [1.0, 1.0]]), 3.5)
    assert (row["n_estimated"], row["true_count"]) == (2.0, 1.0)
    assert (row["count_error"], row["own_count_error"]) == (1.0, 2.5)


def test_an_unlabelled_run_keeps_the_run_metrics_that_need_no_labels():
    run = _one_truth([True] * 4)
    unlabelled = RunData(run.truth, run.truth_ids, run.estimate, None)
    v = run_level_metrics(unlabelled)
    assert math.isnan(v["tgospa"]) and math.isnan(v["id_switches"])
    assert v["crossings"] == 0.0 and v["crossings_near"] == 0.0  # one target: none


def test_the_runs_cache_keeps_each_window_and_gate_apart():
    # a truth tracked at steps 0-5, then a track 1.5 away at steps 6-11
    T = 12
    est = [np.array([[0.0 if k < 6 else 1.5, 0.0]]) for k in range(T)]
    lab = [np.array([1 if k < 6 else 2]) for k in range(T)]
    run = RunData([np.zeros((1, 2))] * T, [np.array([0])] * T, est, lab)
    dense = track_metrics.dense_pair(run.truth, run.truth_ids, run.estimate, run.labels)
    for w in (3, 10):
        want = track_metrics.ospa2(run.truth, run.truth_ids, run.estimate, run.labels,
                                   window=w).total
        assert metrics.ospa2_of(run, w).total == want
    for gate in (1.0, 2.0):
        want = track_metrics.clear_mot(run.truth, run.truth_ids, run.estimate, run.labels,
                                       gate=gate, dense=dense)
        got = metrics._clear_mot(run, gate)
        assert (got.id_switches, got.coverage.tolist()) == (want.id_switches,
                                                            want.coverage.tolist())
    # by hand: gate 1 matches track 1 only (6 of 12 steps, no switch); gate 2 both (a switch)
    for gate, cover, switches in ((1.0, [0.5], 0), (2.0, [1.0], 1)):
        got = metrics._clear_mot(run, gate)
        assert (got.coverage.tolist(), got.id_switches) == (cover, switches)

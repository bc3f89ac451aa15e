"""The metric registry: one declaration puts a metric in the results table, the summaries,
the report and the tuning objectives (``benchmarks/engine/metrics.py``).

The worked example ``n_false`` counts the estimates farther than the cut-off ``c`` from
every true target; the tests check it against a brute-force loop over the points.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.distance import cdist

from mttbench import scenarios
from mttbench.benchmarks.app import cli, report, summary, tune
from mttbench.benchmarks.app.usage import UsageError
from mttbench.benchmarks.engine import loop
from mttbench.benchmarks.engine.metrics import (
    BUILTIN_METRICS,
    STEP_COUNTS,
    Metric,
    get_metric,
    metric_columns,
    metric_names,
    objective_names,
    register_metric,
    registered_metrics,
    run_metric_columns,
    step_metrics,
    unregister_metric,
)
from mttbench.benchmarks.engine.snapshot import trace_run
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec

C = 1.0  # the cut-off of the runs (small enough for kfnn to place false estimates)
STEPS = 20
SEEDS = (tune.TUNING_SEED_BASE, tune.TUNING_SEED_BASE + 1, tune.TUNING_SEED_BASE + 2)
TRACKERS = ("kfnn", "null")


def n_false(truth, estimate, estimated_count, c, p):
    """Estimates farther than ``c`` from every true target."""
    if len(truth) == 0:
        return {"n_false": float(len(estimate))}
    if len(estimate) == 0:
        return {"n_false": 0.0}
    return {"n_false": float(np.count_nonzero(cdist(estimate, truth).min(axis=1) > c))}


def brute_n_false(truth: np.ndarray, estimate: np.ndarray, c: float) -> float:
    return float(sum(all(math.hypot(e[0] - t[0], e[1] - t[1]) > c for t in truth)
                     for e in estimate))


@pytest.fixture
def n_false_metric():
    metric = register_metric(Metric("n_false", n_false, label="false estimates",
                                    objective=True, ranked=True))
    try:
        yield metric
    finally:
        unregister_metric("n_false")


def short(name: str, n_steps: int) -> scenarios.Scenario:
    return dataclasses.replace(scenarios.get(name), n_steps=n_steps)


def run(jobs: list[loop.Job]) -> pd.DataFrame:
    return pd.concat([loop.run_job(j, c=C) for j in jobs], ignore_index=True)


def sweep() -> pd.DataFrame:
    jobs = loop.build_jobs([short("default", STEPS)], [TrackerSpec(t) for t in TRACKERS],
                           None, None, list(SEEDS))
    return run(jobs)


# --------------------------------------------------------------- the built-ins
def test_builtins_declare_the_columns_step_metrics_writes():
    assert [m.name for m in registered_metrics()] == list(BUILTIN_METRICS) == metric_names()
    rng = np.random.default_rng(3)
    row = step_metrics(rng.uniform(0, 5, (3, 2)), rng.uniform(0, 5, (4, 2)), 3.5)
    assert list(row) == metric_columns(BUILTIN_METRICS) + list(STEP_COUNTS)
    # the results table keeps its historical metric columns, in place
    assert loop.METRIC_COLUMNS == metric_columns() == [
        "count_error", "ospa", "ospa_loc", "ospa_card", "gospa", "gospa_loc", "gospa_missed",
        "gospa_false", "rmse", "own_count_error"]
    i = loop.COLUMNS.index("est_count") + 1
    assert loop.COLUMNS[i:i + len(loop.METRIC_COLUMNS)] == loop.METRIC_COLUMNS
    assert objective_names() == ["ospa", "gospa"]
    assert [m.name for m in report.ranked_metrics()] == ["ospa", "gospa", "count_error"]


def test_a_duplicate_name_or_column_is_refused():
    with pytest.raises(ValueError, match="'ospa' is already registered"):
        register_metric(Metric("ospa", n_false))
    with pytest.raises(ValueError, match="ospa_loc"):
        register_metric(Metric("other", n_false, ("other", "ospa_loc")))
    with pytest.raises(ValueError, match="true_count"):
        register_metric(Metric("other", n_false, ("other", "true_count")))
    with pytest.raises(ValueError, match="headline"):
        Metric("other", n_false, ("n_false",))
    with pytest.raises(ValueError, match="minimised"):
        Metric("other", n_false, objective=True, lower_is_better=False)
    with pytest.raises(ValueError, match="built-in"):
        unregister_metric("ospa")
    assert metric_names() == list(BUILTIN_METRICS)


def test_an_unknown_metric_names_the_known_ones():
    with pytest.raises(KeyError) as err:
        get_metric("nosuch")
    assert "nosuch" in str(err.value)
    assert all(name in str(err.value) for name in BUILTIN_METRICS)
    with pytest.raises(UsageError, match="'ospa', 'gospa'"):
        tune.TuneSettings(TrackerSpec("kfnn"), (short("default", 4),), SEEDS,
                          objective="n_false")
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["tune", "kfnn", "--objective", "n_false"])


def test_a_metric_that_writes_other_columns_than_declared_is_an_error():
    register_metric(Metric("wrong", lambda *a: {"other": 1.0}))
    try:
        with pytest.raises(ValueError, match="'wrong' returned the columns"):
            step_metrics(np.zeros((1, 2)), np.zeros((1, 2)), 1.0)
    finally:
        unregister_metric("wrong")


# ------------------------------------------------ the worked example, end to end
def test_n_false_matches_brute_force():
    rng = np.random.default_rng(0)
    for _ in range(200):
        x = rng.uniform(0, 6, (rng.integers(0, 5), 2))
        y = rng.uniform(0, 6, (rng.integers(0, 5), 2))
        c = float(rng.choice([0.5, 1.0, 2.0]))
        assert n_false(x, y, 0.0, c, 2.0)["n_false"] == brute_n_false(x, y, c)


def test_a_registered_metric_reaches_rows_summary_report_and_tuning(n_false_metric, tmp_path):
    assert metric_names() == [*BUILTIN_METRICS, "n_false"]
    results = sweep()
    # (1) the rows of run_job: the column after the fixed and parameter columns, each
    # step's value the brute-force count on the same run's truth and estimates
    fixed = list(results.columns[: len(loop.COLUMNS)])
    assert fixed == loop.COLUMNS and results.columns[-1] == "n_false"
    assert results["n_false"].dtype == np.float64
    trace = trace_run(short("default", STEPS), TrackerSpec("kfnn"), seed=SEEDS[0],
                      policy=PolicySpec("raster"))
    rows = results[(results["tracker_label"] == "kfnn") & (results["seed"] == SEEDS[0])]
    assert len(rows) == len(trace.steps) == STEPS
    for s, value in zip(trace.steps, rows["n_false"], strict=True):
        assert value == brute_n_false(s.truth[:, [0, 2]], s.est_states[:, [0, 2]], C)
    assert (results.loc[results["tracker_label"] == "null", "n_false"] == 0).all()
    assert results["n_false"].sum() > 0  # the example is not trivially zero

    # (2) summaries: the per-run mean over steps, then mean ± ci95 over seeds
    runs = summary.per_run(results)
    want = results.groupby(["tracker_label", "seed"])["n_false"].mean()
    got = runs.set_index(["tracker_label", "seed"])["n_false"]
    pd.testing.assert_series_equal(got.sort_index(), want.sort_index(), check_names=False)
    summ = summary.summarize(results)
    assert {"n_false_mean", "n_false_ci95"} <= set(summ.columns)
    text = summary.to_markdown(summ)
    assert "false estimates" in text.splitlines()[0]

    # (3) the report: accuracy table, paired differences (ranked), Markdown and HTML
    files = report.build_report(results, tmp_path, reference="kfnn", draw=False)
    md, page = files.markdown.read_text(), files.html.read_text()
    acc = md.split("## Accuracy", 1)[1].split("### ", 1)[0]
    assert "| false estimates |" in acc
    paired = md.split("## Paired differences", 1)[1].split("## ", 1)[0]
    assert "Δ false estimates" in paired
    assert "<th>false estimates</th>" in page and "<th>Δ false estimates</th>" in page

    # (4) a tuning objective: accepted by TuneSettings and by the command line
    assert "n_false" in objective_names()
    settings = tune.TuneSettings(TrackerSpec("kfnn"), (short("default", STEPS),), SEEDS,
                                 objective="n_false")
    value, per_sc, msg = tune.objective_value(results, "kfnn", settings)
    kfnn = results[results["tracker_label"] == "kfnn"]
    assert msg == "" and value == pytest.approx(
        kfnn.groupby("seed")["n_false"].mean().mean(), rel=1e-12, abs=0)
    args = cli.build_parser().parse_args(["tune", "kfnn", "--objective", "n_false"])
    assert args.objective == "n_false"


def test_a_registered_metric_changes_the_job_key_and_fills_error_rows(n_false_metric):
    job = loop.Job(short("default", 3), TrackerSpec("kfnn"), seed=1)
    with_metric = job.key(C, 2.0)
    unregister_metric("n_false")
    try:
        assert job.key(C, 2.0) != with_metric  # a resumed sweep recomputes its parts
    finally:
        register_metric(n_false_metric)
    bad = loop.run_job(loop.Job(short("default", 3), TrackerSpec("kfnn", {"gate": -1.0})))
    assert (bad["status"] != "ok").all() and bad["n_false"].isna().all()
    assert bad["n_false"].dtype == np.float64


def test_the_builtins_alone_after_unregistering():
    assert "n_false" not in metric_names()
    df = loop.run_job(loop.Job(short("default", 3), TrackerSpec("null"), seed=0))
    # the fixed columns, then the built-in run-level (track) metrics' columns
    assert list(df.columns) == [*loop.COLUMNS, *run_metric_columns()]

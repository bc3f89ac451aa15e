"""A report's figures drawn in several processes: the same files as in one (also when the
snapshot is added after the other figures started, as `compare` does), each figure in
another process than the report's, and a figure's error raised by the report."""

from __future__ import annotations

import dataclasses
import os

import pytest
from test_report import synthetic_results

from mttbench import scenarios
from mttbench.benchmarks.app import figures, report
from mttbench.benchmarks.engine.snapshot import trace_run
from mttbench.benchmarks.engine.specs import TrackerSpec


def test_two_processes_write_the_same_report_and_figures_as_one(tmp_path):
    """``build_report`` in one process, and in two steps with two drawing processes and the
    snapshot added while the other figures are drawn (as ``compare`` does)."""
    results = synthetic_results()
    sc = dataclasses.replace(scenarios.get("default"), n_steps=8)
    trace = trace_run(sc, TrackerSpec("kfnn"), seed=1)
    one = report.build_report(results, tmp_path / "one", reference="kfnn", trace=trace,
                              processes=1)
    with report.start_report(results, tmp_path / "two", processes=2) as pending:
        pending.add_snapshot(trace)
        two = pending.finish(reference="kfnn")
    assert list(two.figures) == list(one.figures)  # the same figures, in the same order
    assert len(one.figures) >= 5 and list(one.figures)[-1] == "snapshot"
    for key, path in one.figures.items():
        assert two.figures[key].read_bytes() == path.read_bytes(), key
    assert two.markdown.read_text() == one.markdown.read_text()
    assert two.html.read_bytes() == one.html.read_bytes()


def _pid(path):
    return os.getpid()


def test_each_figure_is_drawn_by_a_worker_process(tmp_path):
    tasks = [report.FigureTask(str(k), tmp_path / f"{k}.png", _pid, ()) for k in range(4)]
    with report._Drawing(tasks, processes=2) as drawing:
        drawn = drawing.wait()
    assert list(drawn) == ["0", "1", "2", "3"]
    assert os.getpid() not in set(drawn.values())
    with report._Drawing(tasks, processes=1) as drawing:
        assert drawing.wait() == dict.fromkeys(drawn, os.getpid())


def test_a_figure_that_fails_in_a_worker_raises_its_error(tmp_path):
    results = synthetic_results().drop(columns="count_error")
    tasks = [report.FigureTask("ospa", tmp_path / "ospa.png", figures.metric_over_time,
                               (results, "ospa")),
             report.FigureTask("count_error", tmp_path / "count.png",
                               figures.metric_over_time, (results, "count_error"))]
    with pytest.raises(KeyError, match="count_error"), \
            report._Drawing(tasks, processes=2) as drawing:
        drawing.wait()

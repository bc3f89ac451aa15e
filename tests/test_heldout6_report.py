"""The report's metric tables show each metric's values times its declared ``scale``
(``Metric.scale``: a share shown in per cent, say), headline and part columns alike.
The reference is the documented rule written out: ``format(mean * scale, fmt) ± format(half
* scale, fmt)`` for every column of a registered metric."""

from __future__ import annotations

import pandas as pd
import pytest

from mttbench.benchmarks.app import report
from mttbench.benchmarks.engine.metrics import Metric, register_metric, unregister_metric


def _share(truth, estimate, estimated_count, c, p):
    n = max(len(truth), 1)
    return {"miss_share": len(truth) / n, "miss_share_far": 0.0}


@pytest.fixture
def percent_metric():
    metric = register_metric(Metric("miss_share", _share, columns=("miss_share", "miss_share_far"),
                                    label="missed %", scale=100.0, fmt=".1f"))
    try:
        yield metric
    finally:
        unregister_metric("miss_share")


def test_the_accuracy_table_shows_a_metric_times_its_scale(percent_metric):
    summ = pd.DataFrame({"scenario": ["a", "a"], "tracker_label": ["x", "y"],
                         "n_seeds": [3, 3],
                         "miss_share_mean": [0.125, 0.5], "miss_share_ci95": [0.025, 0.0625],
                         "miss_share_far_mean": [0.0375, 0.25],
                         "miss_share_far_ci95": [0.0125, 0.05]})
    table = report.summary_table(summ, report.accuracy_columns())
    for col, head in (("miss_share", "missed %"), ("miss_share_far", "missed % far")):
        want = [f"{format(m * 100.0, '.1f')} ± {format(h * 100.0, '.1f')}"
                for m, h in zip(summ[f"{col}_mean"], summ[f"{col}_ci95"], strict=True)]
        assert list(table[head]) == want


def test_the_title_is_the_reports_one_top_level_heading(tmp_path):
    """The title heads both renderings as their only top-level heading (``# title`` in
    Markdown, ``<h1>`` in HTML, escaped), before every section (``##`` / ``<h2>``)."""
    import re

    from test_report import synthetic_results

    title = "Trackers <A & B> compared"
    files = report.build_report(synthetic_results(), tmp_path, reference="kfnn",
                                title=title, draw=False)
    md = files.markdown.read_text().splitlines()
    assert md[0] == f"# {title}"
    assert [ln for ln in md if re.match(r"#(?!#)", ln)] == [f"# {title}"]
    assert any(ln.startswith("## ") for ln in md)
    page = files.html.read_text()
    heads = re.findall(r"<(h[1-3])>(.*?)</\1>", page)
    assert heads[0] == ("h1", "Trackers &lt;A &amp; B&gt; compared")
    assert [h for h in heads if h[0] == "h1"] == [heads[0]]

"""Report builder: tables, intervals against scipy, paired differences, figures, HTML.

Intervals are checked against independent scipy computations
(``scipy.stats.t.interval`` on the per-run means, ``ttest_rel(...).confidence_interval``
for paired differences). Display cells are rounded to 3 decimals, so the text
comparison tolerance is half a unit of the last digit.
"""

from __future__ import annotations

import base64
import dataclasses
import re

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mttbench import scenarios
from mttbench.benchmarks.app import figures, report, summary
from mttbench.benchmarks.engine.loop import COLUMNS, Job, run_job
from mttbench.benchmarks.engine.metrics import step_metrics
from mttbench.benchmarks.engine.snapshot import trace_run
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec

DISPLAY_TOL = 5e-4 + 1e-12  # half a unit in the 3rd decimal of a ".3f" cell
NUM_TOL = 1e-10

SCENARIOS = ["alpha", "beta"]
TRACKERS = ["kfnn", "other", "third"]
SEEDS = range(6)
STEPS = range(8)


def synthetic_results(seed: int = 1) -> pd.DataFrame:
    """A results table with the harness schema and random metric values."""
    rng = np.random.default_rng(seed)
    rows = []
    for sc in SCENARIOS:
        for ti, tr in enumerate(TRACKERS):
            for s in SEEDS:
                shared = rng.normal(0, 0.3)  # a per-seed effect shared by the trackers
                for k in STEPS:
                    ospa = abs(0.5 + 0.2 * ti + shared + rng.normal(0, 0.2))
                    rows.append({
                        "scenario": sc, "tracker": tr, "tracker_label": tr,
                        "tracker_params": "{}", "policy": "raster", "policy_label": "raster",
                        "policy_params": "{}", "tracker_uses_truth": False,
                        "policy_uses_truth": False, "looks_per_step": 24,
                        "seed": s, "step": k, "true_count": 3.0,
                        "est_count": 3.0 + rng.normal(0, 1),
                        "count_error": abs(rng.normal(0, 1)),
                        "own_count_error": abs(rng.normal(0, 1)), "ospa": ospa,
                        "ospa_loc": ospa / 2, "ospa_card": ospa / 3, "gospa": 2 * ospa,
                        "gospa_loc": ospa, "gospa_missed": 0.1 * ti, "gospa_false": 0.2,
                        "rmse": ospa / 4, "n_looks": 24, "n_positive": 3,
                        "tracker_wall_s": 1e-3 * (1 + ti) * rng.uniform(0.9, 1.1),
                        "tracker_cpu_s": 1e-3 * (1 + ti), "select_wall_s": 1e-5,
                        "select_cpu_s": 1e-5, "status": "ok", "error": "", "ospa_c": 2.0,
                        "ospa_p": 2.0, "peak_rss_mb": 100.0})
    df = pd.DataFrame(rows)
    assert set(COLUMNS) <= set(df.columns)
    return df


def _parse_pm(text: str) -> tuple[float, float]:
    m = re.fullmatch(r"(-?[\d.e+-]+) ± (-?[\d.e+-]+)", text)
    assert m, text
    return float(m.group(1)), float(m.group(2))


def _scipy_interval(values: np.ndarray) -> tuple[float, float]:
    lo, hi = stats.t.interval(0.95, len(values) - 1, loc=values.mean(), scale=stats.sem(values))
    return values.mean(), (hi - lo) / 2


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    results = synthetic_results()
    out = tmp_path_factory.mktemp("report")
    files = report.build_report(results, out, reference="kfnn", settings={"seeds": "0-5"})
    return results, out, files


def test_accuracy_table_rows_and_intervals_match_scipy(built):
    results, _, _ = built
    from mttbench.benchmarks.app import summary
    table = report.summary_table(summary.summarize(results),
                                 report.ACCURACY_COLUMNS + report.GOSPA_COLUMNS)
    assert len(table) == len(SCENARIOS) * len(TRACKERS)
    assert sorted(zip(table["scenario"], table["tracker"], strict=True)) == sorted(
        (s, t) for s in SCENARIOS for t in TRACKERS)
    assert (table["seeds"] == len(SEEDS)).all()
    for _, row in table.iterrows():
        g = results[(results["scenario"] == row["scenario"])
                    & (results["tracker_label"] == row["tracker"])]
        for stem, head in (("ospa", "OSPA"), ("count_error", "count error"),
                           ("gospa_loc", "GOSPA loc")):
            per_run = g.groupby("seed")[stem].mean().to_numpy()
            mean, half = _scipy_interval(per_run)
            shown_mean, shown_half = _parse_pm(row[head])
            assert abs(shown_mean - mean) <= DISPLAY_TOL
            assert abs(shown_half - half) <= DISPLAY_TOL


def test_paired_differences_match_scipy_ttest_rel(built):
    results, _, _ = built
    paired = report.paired_differences(results, "kfnn")
    # one row per scenario x non-reference tracker x metric
    assert len(paired) == len(SCENARIOS) * (len(TRACKERS) - 1) * len(report.PAIRED_COLUMNS)
    assert "kfnn" not in set(paired["tracker_label"])
    for _, r in paired[paired["metric"] == "ospa"].iterrows():
        sel = results[results["scenario"] == r["scenario"]]
        a = sel[sel["tracker_label"] == r["tracker_label"]].groupby("seed")["ospa"].mean()
        b = sel[sel["tracker_label"] == "kfnn"].groupby("seed")["ospa"].mean()
        ci = stats.ttest_rel(a.to_numpy(), b.to_numpy()).confidence_interval(0.95)
        assert r["diff_mean"] == pytest.approx((a - b).mean(), abs=NUM_TOL)
        assert r["diff_ci95"] == pytest.approx((ci.high - ci.low) / 2, abs=NUM_TOL)
    wide = report.paired_table(paired)
    assert len(wide) == len(SCENARIOS) * (len(TRACKERS) - 1)


def test_step_band_matches_scipy(built):
    results, _, _ = built
    st = figures.step_stats(results, "ospa")
    assert len(st) == len(SCENARIOS) * len(TRACKERS) * len(STEPS)
    r = st[(st["scenario"] == "beta") & (st["tracker_label"] == "other") & (st["step"] == 5)]
    v = results[(results["scenario"] == "beta") & (results["tracker_label"] == "other")
                & (results["step"] == 5)]["ospa"].to_numpy()
    mean, half = _scipy_interval(v)
    assert r["mean"].item() == pytest.approx(mean, abs=NUM_TOL)
    assert r["ci95"].item() == pytest.approx(half, abs=NUM_TOL)


def test_figures_written_and_html_self_contained(built):
    _, out, files = built
    assert set(files.figures) == {"ospa", "count_error", "runtime", "accuracy_runtime"}
    for path in files.figures.values():
        data = path.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000, path
    md = files.markdown.read_text()
    for path in files.figures.values():
        assert f"(figures/{path.name})" in md
    assert "Paired differences against kfnn" in md
    page = files.html.read_text()
    imgs = re.findall(r'<img [^>]*src="([^"]+)"', page)
    assert len(imgs) == len(files.figures)
    for src in imgs:  # every image embedded, decodable PNG
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:4] == b"\x89PNG"
    assert "http://" not in page and "https://" not in page


def test_missing_reference_gives_note(tmp_path):
    results = synthetic_results()
    files = report.build_report(results, tmp_path, reference="nosuch", draw=False)
    assert "No ok runs of the reference tracker 'nosuch'" in files.markdown.read_text()


def test_failed_runs_listed_and_excluded(tmp_path):
    results = synthetic_results()
    bad = (results["tracker_label"] == "third") & (results["seed"] == 0) & (results["step"] == 7)
    results.loc[bad, "status"] = "error"
    results.loc[bad, "error"] = "RuntimeError: boom"
    files = report.build_report(results, tmp_path, reference="kfnn", draw=False)
    md = files.markdown.read_text()
    assert "Failed or unsupported runs" in md and "RuntimeError: boom" in md
    from mttbench.benchmarks.app import summary
    summ = summary.summarize(results)
    assert set(summ.loc[summ["tracker_label"] == "third", "n_seeds"]) == {len(SEEDS) - 1}


def test_trace_is_the_harness_run_and_snapshot_draws(tmp_path):
    """The traced run reproduces the harness's per-step metrics exactly (same seeds)."""
    sc = dataclasses.replace(scenarios.get("default"), n_steps=12)
    spec, pol = TrackerSpec("kfnn"), PolicySpec("random")
    trace = trace_run(sc, spec, seed=3, policy=pol)
    rows = run_job(Job(sc, spec, pol, None, 3))
    assert len(trace.steps) == len(rows) == 12
    for s, (_, r) in zip(trace.steps, rows.iterrows(), strict=True):
        m = step_metrics(s.truth[:, [0, 2]], s.est_states[:, [0, 2]], s.est_count)
        assert m["ospa"] == r["ospa"] and m["count_error"] == r["count_error"]
        assert len(s.cells) == r["n_looks"] and int(s.returns.sum()) == r["n_positive"]
    frames = trace.frames()
    assert len(frames["looks"]) == rows["n_looks"].sum()
    assert len(frames["truth"]) == rows["true_count"].sum()
    path = figures.snapshot(frames, tmp_path / "snap.png", [0, 11], sc.grid.nx, sc.grid.ny)
    assert path.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.skipif(report.find_chromium() is None,
                    reason="no chromium on PATH (Debian: apt-get install chromium); "
                           "the browser check needs a real headless browser")
def test_html_report_renders_in_headless_chromium(built):
    _, out, files = built
    png = report.screenshot(files.html, out / "screenshot.png", height=1500)
    data = png.read_bytes()
    assert data[:4] == b"\x89PNG" and len(data) > 20000


# ------------------------------------------- the baseline and the displayed tables
def _summary_rows(values: dict[str, tuple[float, float]], metric: str = "gospa") -> pd.DataFrame:
    """A summarize()-shaped table for one scenario: tracker -> (mean, ci95) of ``metric``."""
    return pd.DataFrame([{
        "scenario": "paper", "tracker_label": t, "policy_label": "raster", "looks_per_step": 24,
        "tracker": t, "n_seeds": 10, "note": "", f"{metric}_mean": m, f"{metric}_ci95": h}
        for t, (m, h) in values.items()])


def test_baseline_best_or_inside_the_best_interval_is_flagged():
    best = report.baseline_notes(_summary_rows({"null": (2.0, 0.1), "kfnn": (2.3, 0.1)}))
    assert best == ["On `paper` (raster, 24 looks) the baseline `null` has the best GOSPA, "
                    "2.000 ± 0.100: this scenario cannot rank trackers on GOSPA."]
    inside = report.baseline_notes(_summary_rows({"null": (2.05, 0.0), "gpf": (2.0, 0.06),
                                                  "kfnn": (2.5, 0.1)}))
    assert len(inside) == 1 and "within the 95% interval of the best, `gpf`" in inside[0]
    # just outside the best's interval, or no baseline at all: nothing to say
    assert report.baseline_notes(_summary_rows({"null": (2.07, 0.0), "gpf": (2.0, 0.06)})) == []
    assert report.baseline_notes(_summary_rows({"kfnn": (2.0, 0.1), "gpf": (2.3, 0.1)})) == []


def test_a_tracker_given_the_truth_is_not_the_best_the_baseline_is_measured_against():
    rows = _summary_rows({"null": (2.05, 0.0), "truth-aided": (2.0, 0.06),
                          "kfnn": (2.5, 0.1)})
    rows["tracker_uses_truth"] = rows["tracker"] == "truth-aided"
    notes = report.baseline_notes(rows)
    assert len(notes) == 1 and "has the best GOSPA" in notes[0] and "truth-aided" not in notes[0]


def test_report_flags_the_baseline_in_its_own_section(tmp_path):
    results = synthetic_results()
    null = results[results["tracker_label"] == "third"].copy()
    null[["tracker", "tracker_label"]] = "null"
    null["ospa"] = 0.01  # the baseline "wins" OSPA on both scenarios
    md = report.build_report(pd.concat([results, null], ignore_index=True), tmp_path,
                             reference="kfnn", draw=False).markdown.read_text()
    section = md.split("## Where the baseline is not beaten", 1)[1].split("## ", 1)[0]
    assert section.count("cannot rank trackers on OSPA") == len(SCENARIOS)
    assert md.index("Where the baseline") < md.index("## Accuracy")


def test_markdown_tables_escape_pipes_and_show_the_looks_made():
    from mttbench.benchmarks.app import summary
    summ = summary.summarize(synthetic_results())
    summ["looks_made"] = np.where(summ["tracker_label"] == "kfnn", 144.0, 24.0)
    summ.loc[summ["tracker_label"] == "other", "scenario"] = "a|b"
    table = report.summary_table(summ, report.ACCURACY_COLUMNS)
    assert set(table.loc[table["tracker"] == "kfnn", "looks"]) == {"24 (144 made)"}
    assert set(table.loc[table["tracker"] != "kfnn", "looks"]) == {"24"}
    md = report._md_table(table)
    rows = md.splitlines()
    assert {len(re.split(r"(?<!\\)\|", r)) for r in rows} == {len(table.columns) + 2}
    assert sum(r.startswith("| a\\|b |") for r in rows) == len(SCENARIOS)
    text = summary.to_markdown(summ)
    assert "| a\\|b |" in text and "| 24 (144 made) |" in text


# ------------------------------------------------------- track-level scores
def test_tiny_sweep_report_has_ospa2_figure_and_crossing_table(tmp_path):
    """A real sweep on `crossing` (kfnn labels its tracks; null gives no labels): the
    OSPA(2)-over-time figure, the table of switches around the crossings, and the
    track-level tables of summary.md."""
    from mttbench.benchmarks.app import summary

    sc = dataclasses.replace(scenarios.get("crossing"), n_steps=70)
    results = pd.concat([run_job(Job(sc, TrackerSpec(t), seed=s))
                         for t in ("kfnn", "null") for s in (0, 1)], ignore_index=True)
    files = report.build_report(results, tmp_path, reference="kfnn")
    assert "ospa2" in files.figures
    assert files.figures["ospa2"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = files.markdown.read_text()
    assert "(figures/ospa2_over_time.png)" in md
    section = md.split("### Identity switches around the crossings", 1)[1].split("## ", 1)[0]
    assert "`crossing`:" in section and "crossings per run" in section
    table = [r for r in section.splitlines() if r.startswith("| kfnn")]
    assert len(table) == 1 and "null" not in section  # no labels, no row
    want = summary.crossing_switches(results)
    near, half = summary.mean_ci95(want["switches_near"].to_numpy())
    cells = [c.strip() for c in table[0].strip("|").split("|")]
    assert cells[4] == report.fmt_pm(near, half, 1.0, ".2f")
    text = summary.write_summary(results, tmp_path, "tiny")
    assert "## Track-level scores" in text and "No track-level scores for `null`" in text
    assert "## Identity switches around the crossings" in text
    assert (tmp_path / "summary.md").read_text() == text
    track = text.split("## Track-level scores", 1)[1].split("## Identity", 1)[0]
    runs = summary.per_run(results)
    tg, tg_half = summary.mean_ci95(runs.loc[runs["tracker"] == "kfnn", "tgospa"].to_numpy())
    assert f"{tg:.3f} ± {tg_half:.3f}" in track and "| crossing | null" not in track
    # the caller's tables (as compare's report has them) give the same files
    (tmp_path / "given").mkdir()
    given = summary.write_summary(results, tmp_path / "given", "tiny", runs=runs,
                                  summ=summary.summarize(runs), gc=summary.gap_closed(runs))
    assert given == text
    assert (tmp_path / "given" / "summary.csv").read_text() == (
        tmp_path / "summary.csv").read_text()


def _runs(gaps: dict[str, np.ndarray], metric: str = "gospa") -> pd.DataFrame:
    """Per-run rows of one scenario: the baseline's per-seed values swing widely, each
    tracker's are the baseline's minus ``gaps[tracker]`` (per seed)."""
    seeds = np.arange(10)
    base = 2.0 + 0.5 * np.sin(seeds)
    rows = [{"scenario": "paper", "policy_label": "raster", "looks_per_step": 24,
             "tracker": t, "tracker_label": t, "seed": int(s), "status": "ok",
             metric: float(v)}
            for t, values in {"null": base, **{t: base - g for t, g in gaps.items()}}.items()
            for s, v in zip(seeds, values, strict=True)]
    return pd.DataFrame(rows)


def test_baseline_notes_use_the_paired_rule():
    """The seeds move every tracker together: ``gpf`` better than ``null`` by 0.05 on every
    seed (+-0.005) is within ``null``'s unpaired interval but beats it in the paired test,
    so the scenario ranks trackers on GOSPA; ``gpf`` equal to ``null`` up to noise does
    not, and the note names the paired difference."""
    seeds = np.arange(10)
    beats = _runs({"gpf": 0.05 + 0.005 * np.cos(seeds), "kfnn": -0.3 + 0 * seeds})
    summ = summary.summarize(beats, metrics=["gospa"])
    assert report.baseline_notes(summ) != []  # the unpaired rule would flag it
    assert report.baseline_notes(summ, beats) == []
    level = _runs({"gpf": 0.02 * np.cos(3 * seeds), "kfnn": -0.3 + 0 * seeds})
    notes = report.baseline_notes(summary.summarize(level, metrics=["gospa"]), level)
    assert len(notes) == 1 and "no tracker beats the baseline `null` on GOSPA" in notes[0]
    assert "`gpf`" in notes[0] and "paired test" in notes[0]

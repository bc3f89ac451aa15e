"""``mttbench compare``: the report folder, its manifest and the CLI wiring."""

from __future__ import annotations

import json
import re

import pandas as pd
import pytest

from mttbench import trackers
from mttbench.benchmarks.app import compare
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.engine.specs import TrackerSpec


def test_compare_writes_the_report_folder(tmp_path, capsys):
    out = tmp_path / "cmp"
    rc = main(["compare", "--untuned", "--scenarios", "default", "--trackers", "null", "kfnn",
               "--seeds", "3", "--steps", "6", "--workers", "1", "--out", str(out),
               "--no-progress"])
    assert rc == 0
    for name in ("results.parquet", "report.md", "report.html", "manifest.json", "summary.csv",
                 "figures/ospa_over_time.png", "figures/count_error_over_time.png",
                 "figures/runtime_per_step.png", "figures/accuracy_vs_runtime.png",
                 "figures/snapshot.png", "figures/ospa2_over_time.png"):
        assert (out / name).is_file(), name
    df = pd.read_parquet(out / "results.parquet")
    assert len(df) == 2 * 3 * 6
    man = json.loads((out / "manifest.json").read_text())
    assert man["command"][:2] == ["mttbench", "compare"] and "--seeds" in man["command"]
    assert man["seeds"] == [0, 1, 2] and sorted(man["trackers"]) == ["kfnn", "null"]
    assert man["reference"] == "kfnn" and man["wall_time_s"] > 0
    assert man["versions"]["numpy"] and "commit" in man["git"]
    # one finished session; the total wall time is its wall time
    assert man["status"] == "finished" and man["n_rows"] == len(df) and man["n_runs"] == 6
    (session,) = man["sessions"]
    assert session["status"] == "finished" and session["command"] == man["command"]
    assert man["wall_time_s"] == session["wall_time_s"] == man["session_wall_time_s"]
    assert man["runs_wall_time_s"] <= man["wall_time_s"]
    printed = capsys.readouterr().out.strip().splitlines()[-1]
    assert printed == (f"wrote {out}/: results.parquet, summary.csv, summary.md, report.md, "
                       f"report.html, figures/, manifest.json ({man['wall_time_s']:.0f} s)")
    for name in compare.OUTPUT_FILES:
        assert (out / name).exists(), name
    md = (out / "report.md").read_text()
    # paired table: null against the kfnn reference, 3 pairs
    assert re.search(r"\| default \| raster \| 24 \| null \| 3 \|", md), md
    # the floor ran, the ceiling did not: no shares, and the report says why
    assert "The ceiling `truth-aided` did not run, so no tracker's share" in md
    assert "share of gap closed" not in md and "gap_closed_mean" not in (
        out / "summary.csv").read_text()
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 6


def test_default_trackers_cover_the_registry_with_budget_params():
    texts = compare.default_tracker_texts()
    # every registered tracker but the references without the truth (grid-bayes)
    refs = {n for n in trackers.available() if getattr(trackers.get_class(n), "reference",
                                                       False)}
    assert "grid-bayes" in refs
    assert {t.split(":")[0] for t in texts} == set(trackers.available()) - refs
    for t in texts:  # every budget parameter is one the tracker accepts
        name, _, params = t.partition(":")
        accepted = set(trackers.get_class(name).param_names())
        assert {kv.split("=")[0] for kv in params.split(",") if kv} <= accepted


def test_reference_by_bare_name_picks_the_setting():
    from mttbench.benchmarks.engine.specs import TrackerSpec
    specs = [TrackerSpec("kfnn"), TrackerSpec("null", {})]
    assert compare._resolve_reference("kfnn", specs) == "kfnn"
    specs = [TrackerSpec("null"), TrackerSpec("kfnn", {"lost_track_probability": 0.1})]
    assert compare._resolve_reference("kfnn", specs) == "kfnn(lost_track_probability=0.1)"


def test_unknown_reference_is_a_usage_error(tmp_path, capsys):
    rc = main(["compare", "--scenarios", "default", "--trackers", "null", "--reference", "kfnn",
               "--seeds", "1", "--steps", "2", "--out", str(tmp_path / "never"),
               "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "--reference 'kfnn' is not one of the trackers" in err, err
    assert "\n" not in err and not (tmp_path / "never").exists()


def test_reference_defaults_to_the_first_tracker_without_kfnn(tmp_path):
    res = compare.run_compare(["default"], ["null"], [0, 1], steps=2, workers=1,
                              out_dir=tmp_path, progress=False, snapshot=False, argv=["x"])
    assert res.manifest["reference"] == "null"


def test_a_failed_compare_is_marked_in_its_manifest(tmp_path, monkeypatch):
    """A comparison that stops (here the report cannot be drawn) leaves a manifest with
    status "failed" and its session's wall time, so the folder counts as unfinished."""
    from mttbench.benchmarks.app import report

    def broken(*args, **kwargs):
        raise RuntimeError("no figures today")

    monkeypatch.setattr(report, "start_report", broken)
    with pytest.raises(RuntimeError, match="no figures today"):
        compare.run_compare(["default"], ["null"], [0], steps=2, workers=1, out_dir=tmp_path,
                            progress=False, snapshot=False, argv=["x"])
    man = compare.read_manifest(tmp_path)
    assert man["status"] == "failed" and man["sessions"][0]["wall_time_s"] > 0
    assert not compare.is_finished(tmp_path) and compare.is_finished(tmp_path / "nothing") is False


def test_default_scenarios_can_rank_trackers():
    """``paper`` at 24 looks cannot rank trackers (every tracker within ~0.2 OSPA of the
    floor); the default scenarios are presets that can, and the reference is pmb (the
    principled peer) when it runs, else kfnn."""
    from mttbench import scenarios

    assert compare.COMPARE_SCENARIOS == ("default", "crossing", "births", "kreucher")
    assert set(compare.COMPARE_SCENARIOS) <= set(scenarios.preset_names())
    assert compare.COMPARE_REFERENCES == ("pmb", "kfnn")
    specs = [TrackerSpec(n) for n in ("null", "gpf", "kfnn", "pmb", "truth-aided")]
    assert compare.default_reference(specs) == "pmb"
    assert compare.default_reference([s for s in specs if s.name != "pmb"]) == "kfnn"
    assert compare.default_reference([TrackerSpec("truth-aided"), TrackerSpec("gpf")]) == "gpf"

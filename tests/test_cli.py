"""The command line, called in-process through ``main([...])``."""

from __future__ import annotations

import dataclasses

import pandas as pd
import pytest

from mttbench import scenarios, trackers
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.app.compare import COMPARE_SCENARIOS
from mttbench.benchmarks.engine import policies
from mttbench.benchmarks.engine.loop import COLUMNS
from mttbench.scenarios.spec import dumps


@pytest.mark.parametrize("command", [[], ["scenarios"], ["trackers"], ["run"], ["compare"]])
def test_help_of_every_command(command, capsys):
    assert main([*command, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: mttbench")
    if command in (["run"], ["compare"]):
        assert "--trackers" in out and "--seeds" in out and "--workers" in out


def test_no_command_prints_help_and_fails(capsys):
    assert main([]) == 2
    assert "usage: mttbench" in capsys.readouterr().out


def test_scenarios_lists_every_preset_with_its_description(capsys):
    assert main(["scenarios"]) == 0
    out = capsys.readouterr().out
    lines = out.strip().splitlines()
    assert len(lines) == len(scenarios.preset_names())
    for name, line in zip(scenarios.preset_names(), lines, strict=True):
        assert line.startswith(name) and scenarios.get(name).description in line


def test_trackers_lists_trackers_parameters_and_policies(capsys):
    assert main(["trackers"]) == 0
    out = capsys.readouterr().out
    for name in trackers.available():
        cls = trackers.get_class(name)
        assert f"  {name} " in out and cls.summary in out
        for param in cls.param_names():
            assert f"{param}=" in out
    for name in policies.available_policies():
        assert f"  {name} " in out


def test_tiny_run_writes_results_and_summary(tmp_path, capsys):
    model = scenarios.get("default").model  # grid-bayes runs single-target models only
    names = [n for n in trackers.available() if trackers.make(n).unsupported_reason(model) is None]
    out_dir = tmp_path / "out"
    rc = main(["run", "--scenarios", "default", "--trackers", *names, "--seeds", "2",
               "--steps", "5", "--out", str(out_dir), "--no-progress"])
    assert rc == 0
    for f in ("results.parquet", "summary.csv", "summary.md"):
        assert (out_dir / f).is_file()
    df = pd.read_parquet(out_dir / "results.parquet")
    assert list(df.columns[: len(COLUMNS)]) == COLUMNS
    assert len(df) == len(names) * 2 * 5
    assert (df["status"] == "ok").all(), df.loc[df["status"] != "ok", "error"].unique()
    counts = df.groupby(["tracker_label", "seed"]).size()
    assert set(counts.index) == {(n, s) for n in names for s in (0, 1)}
    assert (counts == 5).all()
    assert (df["looks_per_step"] == scenarios.get("default").model.sensor.looks_per_step).all()
    # "null" is a tracker name, not a missing value
    summary = pd.read_csv(out_dir / "summary.csv", keep_default_na=False, na_values=[""])
    assert sorted(summary["tracker_label"]) == sorted(names)
    assert (summary["n_seeds"] == 2).all()
    assert {"ospa_mean", "ospa_ci95", "gospa_mean", "count_error_mean"} <= set(summary.columns)
    printed = capsys.readouterr().out
    assert printed.split("Track-level scores")[0].count("| default |") == len(names)
    accuracy, track_level = (out_dir / "summary.md").read_text().split("## Track-level scores")
    assert accuracy.count("| default |") == len(names)
    labelled = [n for n in names if n != "null"]  # null keeps no track identity
    assert track_level.count("| default |") == len(labelled)


def test_run_with_scenario_file_policies_and_looks(tmp_path, capsys):
    sc = dataclasses.replace(scenarios.get("default"), name="mine", n_steps=3)
    path = tmp_path / "mine.toml"
    path.write_text(dumps(sc))
    rc = main(["run", "--scenarios", str(path), "--trackers", "null", "--seed-list", "4,7",
               "--policy", "raster,random", "--looks", "6", "12", "--out",
               str(tmp_path / "o"), "--no-progress"])
    assert rc == 0
    df = pd.read_parquet(tmp_path / "o" / "results.parquet")
    assert set(df["scenario"]) == {"mine"} and set(df["seed"]) == {4, 7}
    assert set(df["policy_label"]) == {"raster", "random"} and set(df["n_looks"]) == {6, 12}
    assert len(df) == 2 * 2 * 2 * 3


def test_compare_with_overrides(tmp_path, capsys):
    assert set(COMPARE_SCENARIOS) <= set(scenarios.preset_names())
    rc = main(["compare", "--scenarios", "default", "births", "--trackers", "null",
               "--seeds", "2", "--steps", "3", "--workers", "1", "--out", str(tmp_path),
               "--no-progress"])
    assert rc == 0
    df = pd.read_parquet(tmp_path / "results.parquet")
    assert set(df["scenario"]) == {"default", "births"} and set(df["policy"]) == {"raster"}
    assert len(df) == 2 * 2 * 3
    assert (tmp_path / "summary.md").is_file() and (tmp_path / "summary.csv").is_file()


def _bad(tmp_path):
    bad_toml = tmp_path / "bad.toml"
    bad_toml.write_text('n_steps = "many"\n')
    return [
        (["run", "--scenarios", "nowhere", "--trackers", "null"], "nowhere"),
        (["run", "--scenarios", "default", "--trackers", "nosuch"], "nosuch"),
        (["run", "--scenarios", "default", "--trackers", "null:bogus=1"], "bogus"),
        (["run", "--scenarios", "default", "--trackers", "null:bogus"], "key=value"),
        (["run", "--scenarios", "default", "--trackers", "null", "--policy", "wild"], "wild"),
        (["run", "--scenarios", str(bad_toml), "--trackers", "null"], "n_steps"),
        (["run", "--scenarios", str(tmp_path / "missing.toml"), "--trackers", "null"],
         "missing.toml"),
        (["run", "--scenarios", "default", "--trackers", "null", "--seeds", "0"], "--seeds"),
        (["run", "--scenarios", "default", "--trackers", "null", "--looks", "x"], "'x'"),
        (["run", "--scenarios", "default", "--trackers", "null", "--steps", "0"], "--steps"),
        (["compare", "--trackers", "nosuch"], "nosuch"),
        (["compare", "--scenarios", "nowhere"], "nowhere"),
    ]


def test_bad_inputs_exit_2_with_one_line_message(tmp_path, capsys):
    for argv, needle in _bad(tmp_path):
        assert main([*argv, "--out", str(tmp_path / "never"), "--no-progress"]) == 2, argv
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "Traceback" not in err, err
        assert err.startswith("mttbench") and "error" in err and needle in err, (argv, err)
    assert not (tmp_path / "never").exists()


def test_argparse_errors_exit_2(capsys):
    assert main(["run", "--trackers", "null"]) == 2  # --scenarios missing
    assert "--scenarios" in capsys.readouterr().err
    assert main(["run", "--scenarios", "default", "--trackers", "null", "--seeds", "x"]) == 2
    assert main(["frobnicate"]) == 2


def test_run_uses_one_worker_per_cpu_by_default(tmp_path, capsys):
    import os
    rc = main(["run", "--scenarios", "default", "--trackers", "null", "--seeds", "8", "--steps",
               "2", "--out", str(tmp_path), "--no-progress"])
    assert rc == 0
    workers = min(os.cpu_count() or 1, 8)
    assert f"8 runs on {workers} worker(s) -> {tmp_path}" in capsys.readouterr().err


def test_a_policy_named_by_class_path_runs(tmp_path):
    """``--policy package.module:Class`` works like ``--trackers`` does (one registry
    mechanism serves both)."""
    out = tmp_path / "out"
    rc = main(["run", "--scenarios", "default", "--trackers", "null", "--policy",
               "crashing_tracker:FirstCells", "--seeds", "1", "--steps", "3", "--workers", "1",
               "--no-progress", "--out", str(out)])
    assert rc == 0
    df = pd.read_parquet(out / "results.parquet")
    assert set(df["policy"]) == {"crashing_tracker:FirstCells"}
    assert (df["status"] == "ok").all() and (df["n_looks"] == 24).all()


def test_a_new_output_folder_is_locked_before_anything_runs(tmp_path, monkeypatch):
    """compare into a folder that does not exist: the folder is created and locked before
    run_compare starts (no window for a second command), and a refused compare leaves no
    folder behind."""
    import os

    from mttbench.benchmarks.app import compare
    from mttbench.benchmarks.engine import store

    out = tmp_path / "new" / "cmp"
    seen = {}

    def fake_run_compare(*args, **kwargs):
        seen["locked"] = os.path.realpath(out) in store._LOCKS
        raise compare.UsageError("refused for the test")

    monkeypatch.setattr(compare, "run_compare", fake_run_compare)
    assert main(["compare", "--trackers", "null", "--seeds", "1", "--out", str(out),
                 "--no-progress"]) == 2
    assert seen == {"locked": True}
    assert not out.exists()

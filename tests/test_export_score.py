"""Open world files (``mttbench export``) and scoring outside trackers (``mttbench score``).

References are independent of the code under test: the in-process world and rows come from
the step loop (``play``, ``run_job``) with another tracker than the one export uses; the
model card's numbers from the sensor equation written out here; the Stone Soup files are
read by Stone Soup itself; a world scored with its own truth must give OSPA 0.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mttbench.benchmarks.app import export as ex
from mttbench.benchmarks.app import score as sc_mod
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.app.summary import summarize
from mttbench.benchmarks.engine.loop import Job, play, run_job
from mttbench.benchmarks.engine.metrics import metric_columns, run_metric_columns
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec, resolve_scenarios
from mttbench.scenarios.simulator import simulate
from mttbench.scenarios.spec import loads

EXAMPLE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "outside_tracker.py"


def _export(tmp_path: Path, scenario: str, seeds: str, policy: str, *extra: str) -> Path:
    out = tmp_path / "worlds"
    assert main(["export", scenario, "--seed-list", seeds, "--policy", policy,
                 "--out", str(out), *extra]) == 0
    return out


def _world(out: Path, scenario: str, seed: int, policy: str, m: int) -> Path:
    return out / ex.world_name(scenario, seed, policy, m)


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


# ------------------------------------------------------------------------ export
@pytest.mark.parametrize("policy", ["random", "raster", "all"])
def test_exported_world_equals_the_in_process_world(tmp_path, policy):
    """Truth and every look of an exported world equal what a tracker meets in-process
    (another tracker than export's null, so the looks do not depend on the tracker), and
    CSV and Parquet hold the same numbers."""
    out = _export(tmp_path, "births", "3,4", policy, "--steps", "30")
    scenario = resolve_scenarios(["births"], 30)[0]
    for seed in (3, 4):
        folder = _world(out, "births", seed, policy, 24)
        for stem in ("truth", "looks"):
            a = pd.read_parquet(folder / f"{stem}.parquet")
            b = pd.read_csv(folder / f"{stem}.csv")
            assert list(a.columns) == list(b.columns)
            assert np.array_equal(a.to_numpy(float), b.to_numpy(float)), stem
        truth = pd.read_parquet(folder / "truth.parquet")
        looks = pd.read_parquet(folder / "looks.parquet")
        run = simulate(scenario, seed)
        assert len(truth) == sum(len(s) for s in run.states)
        recs = list(play(scenario, TrackerSpec("kfnn").make(), seed,
                         policy=PolicySpec(policy).make()))
        assert len(recs) == scenario.n_steps
        for rec in recs:
            t = truth[truth["step"] == rec.k]
            assert np.array_equal(t[["px", "vx", "py", "vy"]].to_numpy(), run.states[rec.k])
            assert np.array_equal(t["target_id"].to_numpy(), run.ids[rec.k])
            lk = looks[looks["step"] == rec.k]
            assert np.array_equal(lk["cell"].to_numpy(), rec.looks.cells)
            assert np.array_equal(lk["return"].to_numpy(), rec.looks.returns.astype(int))
            assert np.array_equal(lk["look"].to_numpy(), np.arange(len(lk)))
            nx = scenario.grid.nx
            assert np.array_equal(lk["iy"] * nx + lk["ix"], lk["cell"])
        # every look is a row, the zeros included
        assert (looks["return"] == 0).sum() > 0
        assert len(looks) == sum(len(r.looks.cells) for r in recs)


def test_model_card_carries_the_model_and_each_files_hash(tmp_path):
    out = _export(tmp_path, "default", "5", "random")
    folder = _world(out, "default", 5, "random", 24)
    card = json.loads((folder / ex.CARD).read_text())
    scenario = resolve_scenarios(["default"])[0]
    assert card["format"] == ex.FORMAT and card["format_version"] == ex.FORMAT_VERSION
    assert loads(card["scenario"]["toml"]) == scenario
    assert card["seed"] == 5 and card["policy"]["name"] == "random"
    pd_, snr = card["sensor"]["p_d"], card["sensor"]["snr"]
    assert (pd_, snr) == (scenario.model.sensor.p_d, scenario.model.sensor.snr)
    for t, value in enumerate(card["sensor"]["p_d_of_T"]):
        assert value == pytest.approx(pd_ ** ((1 + snr) / (1 + t * snr)), rel=1e-14)
    assert card["sensor"]["p_f"] == pytest.approx(pd_ ** (1 + snr), rel=1e-14)
    assert card["sensor"]["p_d_of_T"][0] == pytest.approx(card["sensor"]["p_f"], rel=1e-14)
    tau = card["dynamics"]["tau"]
    assert np.array_equal(card["dynamics"]["F"], [[1, tau, 0, 0], [0, 1, 0, 0],
                                                  [0, 0, 1, tau], [0, 0, 0, 1]])
    assert np.array_equal(card["dynamics"]["Q"], scenario.model.dynamics.Q)
    assert sorted(card["files"]) == sorted(ex.WORLD_FILES)
    for name, meta in card["files"].items():
        data = (folder / name).read_bytes()
        assert meta["sha256"] == hashlib.sha256(data).hexdigest()
        assert meta["bytes"] == len(data)
    index = pd.read_csv(out / ex.WORLDS_INDEX)
    assert index["world"].tolist() == [folder.name]


@pytest.mark.parametrize("policy, why", [("renyi", "tracker's own estimates"),
                                         ("oracle", "true targets")])
def test_closed_loop_policies_are_refused_in_one_line(tmp_path, capsys, policy, why):
    out = tmp_path / "never"
    assert main(["export", "default", "--policy", policy, "--out", str(out)]) == 2
    line = _one_error_line(capsys)
    assert policy in line and why in line
    assert not out.exists()


def test_a_scenario_without_cells_is_refused(tmp_path, capsys):
    assert main(["export", "superposition", "--out", str(tmp_path / "x")]) == 2
    assert "superposition sensor" in _one_error_line(capsys)


def test_stonesoup_readers_read_the_converted_files(tmp_path):
    generic = pytest.importorskip("stonesoup.reader.generic")
    out = _export(tmp_path, "births", "2", "raster", "--steps", "40")
    folder = _world(out, "births", 2, "raster", 24)
    truth = pd.read_parquet(folder / "truth.parquet")
    looks = pd.read_parquet(folder / "looks.parquet")
    tau = resolve_scenarios(["births"])[0].model.dynamics.tau

    reader = generic.CSVGroundTruthReader(
        folder / "stonesoup_truth.csv", state_vector_fields=("px", "vx", "py", "vy"),
        time_field="time", path_id_field="target_id", timestamp=True)
    paths: dict[str, list] = {}
    n_times = 0
    for _, updated in reader:
        n_times += 1
        for path in updated:
            paths[path.id] = path
    assert n_times == truth["step"].nunique()
    assert sorted(int(i) for i in paths) == sorted(truth["target_id"].unique())
    for tid, path in paths.items():
        rows = truth[truth["target_id"] == int(tid)]
        got = np.hstack([s.state_vector for s in path.states]).T
        assert np.array_equal(got, rows[["px", "vx", "py", "vy"]].to_numpy())
        seconds = [(s.timestamp - path.states[0].timestamp).total_seconds() for s in path.states]
        assert np.allclose(seconds, (rows["step"] - rows["step"].iloc[0]) * tau)

    def read(name):
        rd = generic.CSVDetectionReader(folder / name, state_vector_fields=("x", "y"),
                                        time_field="time", timestamp=True)
        return [d for _, dets in rd for d in dets]

    positive, negative = looks[looks["return"] == 1], looks[looks["return"] == 0]
    dets, misses = read("stonesoup_detections.csv"), read("stonesoup_misses.csv")
    assert len(dets) == len(positive) > 0 and len(misses) == len(negative)
    size = resolve_scenarios(["births"])[0].grid.cell_size
    want = sorted(zip(positive["step"], (positive["ix"] + 0.5) * size,
                      (positive["iy"] + 0.5) * size, strict=True))
    got = sorted((int(d.metadata["step"]), float(d.state_vector[0, 0]),
                  float(d.state_vector[1, 0])) for d in dets)
    assert got == want


def test_steps_file_lists_every_step_with_its_time(tmp_path):
    """``steps.csv``: one row per step ``0 .. n_steps - 1`` with ``time = step * tau`` and
    the looks and positive looks of the looks table counted here, the steps without a
    positive look (no row in the detections file, no scan for a Stone Soup reader)
    included."""
    out = _export(tmp_path, "births", "2", "raster", "--steps", "40")
    folder = _world(out, "births", 2, "raster", 24)
    steps = pd.read_csv(folder / "steps.csv")
    looks = pd.read_csv(folder / "looks.csv")
    card = json.loads((folder / ex.CARD).read_text())
    tau = card["dynamics"]["tau"]
    assert list(steps.columns) == card["columns"]["steps"] == ex.STEPS_COLUMNS
    assert steps["step"].tolist() == list(range(card["scenario"]["n_steps"])) == list(range(40))
    assert np.array_equal(steps["time"].to_numpy(), np.arange(40) * tau)
    made = looks.groupby("step").size().reindex(range(40), fill_value=0)
    fired = looks.groupby("step")["return"].sum().reindex(range(40), fill_value=0)
    assert np.array_equal(steps["n_looks"], made) and np.array_equal(steps["n_positive"], fired)
    detected = set(pd.read_csv(folder / "stonesoup_detections.csv")["step"])
    silent = set(steps.loc[steps["n_positive"] == 0, "step"])
    assert silent and not silent & detected and silent | detected == set(range(40))


# ------------------------------------------------------------------------- score
def _truth_estimates(folder: Path) -> Path:
    t = pd.read_csv(folder / "truth.csv")
    est = t.rename(columns={"px": "x", "py": "y", "target_id": "label"})[
        ["step", "x", "y", "label"]]
    path = folder / "estimates.csv"
    est.to_csv(path, index=False)
    return path


def test_a_world_scored_with_its_own_truth_scores_zero(tmp_path, capsys):
    out = _export(tmp_path, "births", "0,1", "random")
    for seed in (0, 1):
        _truth_estimates(_world(out, "births", seed, "random", 24))
    res = tmp_path / "scored"
    assert main(["score", str(out), "--estimates", "estimates.csv", "--name", "truth",
                 "--out", str(res)]) == 0
    rows = pd.read_parquet(res / "results.parquet")
    assert set(rows["tracker"]) == {"outside:truth"} and len(rows) == 200
    for col in ("ospa", "gospa", "count_error", "own_count_error", "tgospa", "ospa2",
                "id_switches", "fragmentations"):
        assert (rows[col] == 0).all(), col
    assert (rows["mostly_tracked"] == 1).all()
    assert rows["rmse"].fillna(0).eq(0).all()
    assert (res / "summary.md").is_file() and "outside:truth" in capsys.readouterr().out


def _write_estimates(scenario, tracker: TrackerSpec, policy: PolicySpec, seed: int,
                     path: Path) -> None:
    """An in-process tracker's estimates as an outside tracker would write them."""
    rows = []
    for rec in play(scenario, tracker.make(), seed, policy=policy.make()):
        e = rec.estimate
        states = np.asarray(e.states, float).reshape(-1, 4)
        if not len(states):
            rows.append({"step": rec.k, "x": None, "y": None, "label": None,
                         "count": float(e.count)})
        for s, lab in zip(states, e.labels, strict=True):
            rows.append({"step": rec.k, "x": s[0], "y": s[2], "label": lab,
                         "count": float(e.count)})
    pd.DataFrame(rows, columns=["step", "x", "y", "label", "count"]).to_csv(path, index=False)


@pytest.mark.parametrize("tracker", ["kfnn", "gpf"])
def test_in_process_estimates_scored_outside_match_the_run_to_the_last_digit(tmp_path,
                                                                              tracker):
    """run_job's rows and summary, against the same estimates written to CSV and scored:
    every metric column equal bit for bit (gpf: its count, a weight sum, is not its number
    of states, so the count column matters)."""
    steps, seeds, policy = 60, (0, 1, 2), PolicySpec("random")
    scenario = resolve_scenarios(["births"], steps)[0]
    out = _export(tmp_path, "births", ",".join(map(str, seeds)), "random",
                  "--steps", str(steps))
    spec = TrackerSpec(tracker)
    for seed in seeds:
        folder = _world(out, "births", seed, "random", 24)
        _write_estimates(scenario, spec, policy, seed, folder / "estimates.csv")
    res = tmp_path / "scored"
    assert main(["score", str(out), "--estimates", "estimates.csv", "--name", tracker,
                 "--out", str(res)]) == 0
    got = pd.read_parquet(res / "results.parquet").sort_values(["seed", "step"])
    ref = pd.concat([run_job(Job(scenario, spec, policy, None, s)) for s in seeds])
    ref = ref.sort_values(["seed", "step"])
    cols = ["step", "true_count", "est_count", "n_looks", "n_positive", *metric_columns(),
            *run_metric_columns()]
    # the same columns in the same order, but the tracker's own parameters
    assert list(got.columns) == [c for c in ref.columns if not c.startswith("param_")]
    assert np.array_equal(got[cols].to_numpy(float), ref[cols].to_numpy(float),
                          equal_nan=True)
    s_got = summarize(got).iloc[0]
    s_ref = summarize(ref).iloc[0]
    means = [c for c in s_ref.index if c.endswith(("_mean", "_ci95"))
             and not c.startswith(("tracker_", "select_", "peak_rss"))]
    assert len(means) > 20
    for c in means:
        assert (s_got[c] == s_ref[c]) or (np.isnan(s_got[c]) and np.isnan(s_ref[c])), c
    assert s_got["n_seeds"] == s_ref["n_seeds"] == len(seeds)
    assert s_got["tracker_label"] == f"outside:{tracker}"


def test_count_only_rows_give_a_count_without_states(tmp_path):
    path = tmp_path / "e.csv"
    path.write_text("step,x,y,count\n0,1.5,2.5,0.7\n2,,,0.4\n")
    est = sc_mod.read_estimates(path, 3)
    assert est[0].positions.tolist() == [[1.5, 2.5]] and est[0].count == 0.7
    assert est[1].positions.shape == (0, 2) and est[1].count == 0.0
    assert est[2].positions.shape == (0, 2) and est[2].count == 0.4


BAD_FILES = {
    "missing column": ("step,x\n0,1\n", "missing column(s) y"),
    "unknown column": ("step,x,y,vx\n0,1,2,3\n", "unknown column 'vx'"),
    "non-numeric": ("step,x,y\n0,1,abc\n", "y 'abc' on line 2 is not a number"),
    "NaN": ("step,x,y\n0,1,2\n1,NaN,2\n", "x is empty or NaN on line 3"),
    "empty x": ("step,x,y\n0,,2\n", "x is empty or NaN on line 2"),
    "infinite": ("step,x,y\n0,inf,2\n", "x is infinite on line 2"),
    "negative step": ("step,x,y\n0,1,2\n-1,1,2\n", "negative step -1 on line 3"),
    "beyond": ("step,x,y\n100,1,2\n", "step 100 on line 2 is beyond the world"),
    "fractional step": ("step,x,y\n1.5,1,2\n", "is not an integer"),
    "repeated label": ("step,x,y,label\n0,1,2,7\n0,3,4,7\n", "labels repeat within step 0"),
    "empty label": ("step,x,y,label\n0,1,2,7\n0,3,4,\n", "label is empty or NaN on line 3"),
    "negative count": ("step,x,y,count\n0,1,2,-1\n", "negative count on line 2"),
    "counts disagree": ("step,x,y,count\n0,1,2,1\n0,3,4,2\n", "different counts"),
    "empty file": ("", "cannot read it"),
    "huge position": ("step,x,y\n0,1e160,2\n", "x 1e+160 on line 2 is beyond +-1e+12"),
    "huge count": ("step,x,y,count\n0,1,2,1e30\n", "count 1e+30 on line 2 is beyond"),
    "huge label": ("step,x,y,label\n0,1,2,1e30\n", "label 1e+30 on line 2 is beyond"),
}


@pytest.fixture(scope="module")
def one_world(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("world")
    return _world(_export(tmp, "default", "0", "raster"), "default", 0, "raster", 24)


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_estimate_files_exit_2_with_one_line(tmp_path, capsys, one_world, case):
    text, expected = BAD_FILES[case]
    path = tmp_path / "est.csv"
    path.write_text(text)
    out = tmp_path / "out"
    assert main(["score", str(one_world), "--estimates", str(path), "--out", str(out)]) == 2
    line = _one_error_line(capsys)
    assert line.startswith("mttbench score: error: estimates ") and expected in line, line
    assert not out.exists()


def test_bad_parquet_estimates_and_other_inputs_exit_2(tmp_path, capsys, one_world):
    pq = tmp_path / "est.parquet"
    pd.DataFrame({"step": [0, 1], "x": [1.0, np.nan], "y": [2.0, 3.0]}).to_parquet(pq)
    assert main(["score", str(one_world), "--estimates", str(pq)]) == 2
    assert "x is empty or NaN on row 1" in _one_error_line(capsys)
    txt = tmp_path / "est.txt"
    txt.write_text("step,x,y\n")
    assert main(["score", str(one_world), "--estimates", str(txt)]) == 2
    assert ".csv or .parquet" in _one_error_line(capsys)
    assert main(["score", str(tmp_path), "--estimates", str(pq)]) == 2
    assert "neither an exported world" in _one_error_line(capsys)
    ok = tmp_path / "ok.csv"
    ok.write_text("step,x,y\n0,1,2\n")
    assert main(["score", str(one_world), "--estimates", str(ok), "--name", "a b"]) == 2
    assert "--name 'a b' is not allowed" in _one_error_line(capsys)


def test_a_world_changed_after_export_is_refused(tmp_path, capsys):
    out = _export(tmp_path, "default", "0", "raster")
    folder = _world(out, "default", 0, "raster", 24)
    est = _truth_estimates(folder)
    looks = folder / "looks.parquet"
    df = pd.read_parquet(looks)
    df.loc[0, "return"] = 1 - df.loc[0, "return"]
    df.to_parquet(looks, index=False)
    assert main(["score", str(folder), "--estimates", str(est)]) == 2
    assert "looks.parquet does not match its sha256" in _one_error_line(capsys)


def test_worked_example_joins_a_run_in_one_report(tmp_path, capsys):
    """The README's example: export, the outside script, a run of ours on the same worlds,
    score beside it; the report holds both. A run on other worlds is refused."""
    out = _export(tmp_path, "default", "0,1", "random", "--steps", "30")
    worlds = sorted(str(p) for p in out.iterdir() if p.is_dir())
    subprocess.run([sys.executable, str(EXAMPLE), *worlds], check=True)
    inside = tmp_path / "inside"
    assert main(["run", "--scenarios", "default", "--trackers", "null", "kfnn", "--seed-list",
                 "0,1", "--policy", "random", "--steps", "30", "--workers", "1",
                 "--no-progress", "--out", str(inside)]) == 0
    res = tmp_path / "report"
    assert main(["score", str(out), "--estimates", "estimates.csv", "--name", "cells",
                 "--beside", str(inside), "--out", str(res)]) == 0
    report = (res / "report.md").read_text()
    assert "outside:cells" in report and "kfnn" in report
    table = pd.read_parquet(res / "results.parquet")
    assert set(table["tracker_label"]) == {"null", "kfnn", "outside:cells"}
    assert len(table) == 3 * 2 * 30
    capsys.readouterr()
    other = tmp_path / "other"
    assert main(["run", "--scenarios", "default", "--trackers", "null", "--seed-list", "5",
                 "--policy", "random", "--steps", "30", "--workers", "1", "--no-progress",
                 "--out", str(other)]) == 0
    capsys.readouterr()
    assert main(["score", str(out), "--estimates", "estimates.csv", "--beside", str(other),
                 "--out", str(tmp_path / "r2")]) == 2
    assert "no run on the world" in _one_error_line(capsys)


def test_export_is_byte_for_byte_repeatable_and_keeps_earlier_worlds_listed(tmp_path):
    a = _export(tmp_path / "a", "default", "1", "random", "--steps", "20")
    again = tmp_path / "a" / "worlds"
    assert main(["export", "default", "--seed-list", "1", "--policy", "random", "--steps",
                 "20", "--out", str(tmp_path / "b")]) == 0
    for f in sorted((a / ex.world_name("default", 1, "random", 24)).iterdir()):
        assert f.read_bytes() == (tmp_path / "b" / f.parent.name / f.name).read_bytes(), f
    assert main(["export", "births", "--seed-list", "2", "--policy", "raster", "--steps", "20",
                 "--out", str(again)]) == 0
    assert pd.read_csv(again / ex.WORLDS_INDEX)["world"].tolist() == [
        ex.world_name("default", 1, "random", 24), ex.world_name("births", 2, "raster", 24)]


GMPHD_EXAMPLE = EXAMPLE.with_name("stonesoup_gmphd.py")


def test_the_stonesoup_example_runs_every_step_and_is_scored(tmp_path):
    """docs/examples/stonesoup_gmphd.py on a tiny export: it writes one step or more per
    step ``0 .. n_steps - 1`` (the steps without a detection included: a loop over Stone
    Soup's scans would skip them), and ``mttbench score`` scores it into a folder of
    ``n_steps`` rows per world."""
    pytest.importorskip("stonesoup")
    out = _export(tmp_path, "births", "2", "raster", "--steps", "25")
    world = _world(out, "births", 2, "raster", 24)
    steps = pd.read_csv(world / "steps.csv")
    assert (steps["n_positive"] == 0).any()  # some steps have no scan in Stone Soup's reader
    subprocess.run([sys.executable, str(GMPHD_EXAMPLE), str(world)], check=True,
                   capture_output=True)
    est = pd.read_csv(world / "stonesoup_gmphd.csv")
    assert sorted(est["step"].unique()) == list(range(25))
    res = tmp_path / "scored"
    # one world: the estimates' path is the working folder's (an export folder: the world's)
    assert main(["score", str(world), "--estimates", str(world / "stonesoup_gmphd.csv"),
                 "--name", "gmphd", "--out", str(res)]) == 0
    rows = pd.read_parquet(res / "results.parquet")
    assert (res / "summary.md").is_file() and (res / "score.json").is_file()
    assert sorted(rows["step"]) == list(range(25)) and set(rows["status"]) == {"ok"}
    assert rows["ospa"].between(0, 2).all() and rows["ospa"].mean() < 2.0  # it tracks


def test_scoring_reads_the_worlds_cell_size_for_the_default_cutoff(tmp_path):
    """The default cut-off is 2 cells of the world's grid: on cells of 2.5 units the rows
    scored outside equal run_job's (c = 5) metric for metric, and differ from a scoring
    with c = 2 units (the reference is the in-process run, not the scorer)."""
    import dataclasses

    base = resolve_scenarios(["births"], 20)[0]
    grid = dataclasses.replace(base.model.grid, cell_size=2.5)
    scenario = dataclasses.replace(base, model=dataclasses.replace(base.model, grid=grid))
    spec, policy = TrackerSpec("kfnn"), PolicySpec("random")
    out = tmp_path / "worlds"
    ex.export_worlds([scenario], [policy], [0], out)
    folder = _world(out, "births", 0, "random", 24)
    _write_estimates(scenario, spec, policy, 0, folder / "estimates.csv")
    res = tmp_path / "scored"
    assert main(["score", str(out), "--estimates", "estimates.csv", "--name", "kfnn",
                 "--out", str(res)]) == 0
    got = pd.read_parquet(res / "results.parquet").sort_values("step")
    ref = run_job(Job(scenario, spec, policy, None, 0)).sort_values("step")
    assert (got["ospa_c"] == 5.0).all() and (ref["ospa_c"] == 5.0).all()
    cols = ["ospa", "gospa", "ospa_card", "tgospa", "ospa2"]
    assert np.array_equal(got[cols].to_numpy(float), ref[cols].to_numpy(float), equal_nan=True)
    res2 = tmp_path / "scored2"
    assert main(["score", str(out), "--estimates", "estimates.csv", "--name", "kfnn",
                 "--c", "2", "--out", str(res2)]) == 0
    two = pd.read_parquet(res2 / "results.parquet").sort_values("step")
    assert (two["ospa_c"] == 2.0).all()
    assert not np.allclose(two["ospa"].to_numpy(), got["ospa"].to_numpy())

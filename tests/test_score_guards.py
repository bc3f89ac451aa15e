"""``score`` and ``export`` cannot be fooled: a model card checked field by field and
against its tables, an export folder's index, runs beside worlds of another length, an
absolute estimates path, a re-export with other settings, worlds too large to export; and
one command's output per folder (``score``, ``export`` and ``run`` refuse each other's
folders and a folder in use). Each refused case: exit 2, one line, nothing written.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
from pathlib import Path

import pandas as pd
import pytest

from mttbench.benchmarks.app import export as ex
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.engine.store import LOCK_FILE

STEPS = "4"


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != LOCK_FILE}


def one_line(capsys) -> str:
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    return err[0]


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> Path:
    """An export folder of two worlds (default, raster, seeds 0 and 1, 4 steps), each with
    its truth as estimates."""
    out = tmp_path_factory.mktemp("export") / "worlds"
    assert main(["export", "default", "--seed-list", "0,1", "--policy", "raster",
                 "--steps", STEPS, "--out", str(out)]) == 0
    for world in out.iterdir():
        if world.is_dir():
            t = pd.read_csv(world / "truth.csv")
            t.rename(columns={"px": "x", "py": "y", "target_id": "label"})[
                ["step", "x", "y", "label"]].to_csv(world / "est.csv", index=False)
    return out


def _copy(exported: Path, tmp_path: Path) -> Path:
    out = tmp_path / "worlds"
    shutil.copytree(exported, out)
    return out


def _world(out: Path, seed: int = 0) -> Path:
    return out / ex.world_name("default", seed, "raster", 24)


def _score(world: Path, out: Path, *extra: str, estimates: str | None = None) -> int:
    est = estimates or (str(world / "est.csv") if (world / ex.CARD).is_file() else "est.csv")
    return main(["score", str(world), "--estimates", est, "--name", "t", "--out", str(out),
                 *extra])


def _edit_card(world: Path, edit) -> None:
    card = json.loads((world / ex.CARD).read_text())
    edit(card)
    (world / ex.CARD).write_text(json.dumps(card))


def _pop(*path):
    def edit(card):
        for key in path[:-1]:
            card = card[key]
        del card[path[-1]]
    return edit


def _set(value, *path):
    def edit(card):
        for key in path[:-1]:
            card = card[key]
        card[path[-1]] = value
    return edit


CARD_CASES = {
    "no n_steps": (_pop("scenario", "n_steps"), "no scenario.n_steps"),
    "no policy": (_pop("policy"), "no policy table"),
    "n_steps text": (_set("five", "scenario", "n_steps"), "scenario.n_steps = 'five'"),
    "n_steps 1e10": (_set(10**10, "scenario", "n_steps"), "scenario.n_steps = 10000000000"),
    "n_steps bool": (_set(True, "scenario", "n_steps"), "scenario.n_steps = True"),
    "n_steps fewer": (_set(2, "scenario", "n_steps"), "steps outside 0..1"),
    "n_steps more": (_set(9, "scenario", "n_steps"), "its looks cover 4 steps"),
    "seed text": (_set("0", "seed"), "seed = '0'"),
    "looks negative": (_set(-1, "policy", "looks_per_step"), "policy.looks_per_step = -1"),
    "params list": (_set([], "policy", "params"), "policy.params = []"),
    "no files": (_pop("files"), "no files table"),
    "looks unlisted": (_pop("files", "looks.parquet"), "lists no sha256 of looks.parquet"),
}


@pytest.mark.parametrize("case", sorted(CARD_CASES))
def test_a_model_card_is_checked_field_by_field(exported, tmp_path, capsys, case):
    edit, expected = CARD_CASES[case]
    world = _world(_copy(exported, tmp_path))
    _edit_card(world, edit)
    out = tmp_path / "scored"
    assert _score(world, out) == 2
    line = one_line(capsys)
    assert expected in line, line
    assert not out.exists()


@pytest.mark.parametrize("index, expected", [
    ("world\n", "lists no world"),
    ("twice", "lists the world default__seed0__raster__m24 twice"),
    ("world\n..\n", "'..' is not a world folder's name"),
])
def test_an_export_index_is_checked(exported, tmp_path, capsys, index, expected):
    out = _copy(exported, tmp_path)
    path = out / ex.WORLDS_INDEX
    if index == "twice":
        df = pd.read_csv(path)
        pd.concat([df, df.iloc[:1]]).to_csv(path, index=False)
    else:
        path.write_text(index)
    assert _score(out, tmp_path / "scored") == 2
    assert expected in one_line(capsys)
    assert not (tmp_path / "scored").exists()


def test_an_absolute_estimates_path_with_an_export_folder_is_refused(exported, tmp_path,
                                                                      capsys):
    est = str(_world(exported) / "est.csv")
    assert _score(exported, tmp_path / "scored", estimates=est) == 2
    assert "is an absolute path" in one_line(capsys)
    assert _score(exported, tmp_path / "scored", estimates="nowhere.csv") == 2
    line = one_line(capsys)
    assert "no such file" in line and str(_world(exported) / "nowhere.csv") in line, line
    assert _score(exported, tmp_path / "scored") == 0  # relative: each world's own file
    rows = pd.read_parquet(tmp_path / "scored" / "results.parquet")
    assert sorted(rows["seed"].unique()) == [0, 1] and (rows["ospa"] == 0).all()


def test_runs_beside_of_another_length_are_refused(exported, tmp_path, capsys):
    runs = tmp_path / "runs"
    assert main(["run", "--scenarios", "default", "--trackers", "null", "--policy", "raster",
                 "--seed-list", "0,1", "--steps", "6", "--workers", "1", "--no-progress",
                 "--out", str(runs)]) == 0
    capsys.readouterr()
    before = snapshot(runs)
    assert _score(exported, tmp_path / "scored", "--beside", str(runs)) == 2
    assert "have 6 steps, the world 4" in one_line(capsys)
    assert snapshot(runs) == before and not (tmp_path / "scored").exists()


def test_a_re_export_with_other_steps_is_refused(exported, tmp_path, capsys):
    out = _copy(exported, tmp_path)
    before = snapshot(out)
    assert main(["export", "default", "--seed-list", "0", "--policy", "raster", "--steps",
                 "5", "--out", str(out)]) == 2
    assert "holds a world exported with other settings" in one_line(capsys)
    assert snapshot(out) == before
    assert main(["export", "default", "--seed-list", "0", "--policy", "raster", "--steps",
                 STEPS, "--out", str(out)]) == 0  # the same world again: allowed


@pytest.mark.parametrize("extra, expected", [
    (["--steps", "1000000000"], "too many to export"),
    (["--looks", "1000000000"], "1000000000 looks"),
])
def test_a_world_too_large_is_refused_before_any_work(tmp_path, capsys, extra, expected):
    out = tmp_path / "new"
    assert main(["export", "default", "--seed-list", "0", "--policy", "raster", *extra,
                 "--out", str(out)]) == 2
    line = one_line(capsys)
    assert expected in line and "--workers" not in line, line
    assert not out.exists()


def test_a_name_collision_leaves_no_folder(tmp_path, capsys):
    from mttbench.benchmarks.engine.specs import resolve_scenarios

    text = ex.dumps(resolve_scenarios(["default"], 3)[0])
    paths = []
    for i, name in enumerate(("a b", "a_b")):
        path = tmp_path / f"s{i}.toml"
        path.write_text(text.replace('name = "default"', f'name = "{name}"'))
        paths.append(str(path))
    out = tmp_path / "new"
    assert main(["export", *paths, "--seed-list", "0", "--policy", "raster",
                 "--out", str(out)]) == 2
    assert "same folder name" in one_line(capsys)
    assert not out.exists()


# ---------------------------------------------------------------- one command per folder
@pytest.fixture(scope="module")
def run_folder(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run") / "out"
    assert main(["run", "--scenarios", "default", "--trackers", "null", "--seed-list", "0",
                 "--steps", "3", "--workers", "1", "--no-progress", "--out", str(out)]) == 0
    return out


def test_score_export_and_run_refuse_each_others_folders(exported, run_folder, tmp_path,
                                                         capsys):
    world = _world(exported)
    scored = tmp_path / "scored"
    assert _score(world, scored) == 0
    capsys.readouterr()
    run = ["run", "--scenarios", "default", "--trackers", "null", "--seed-list", "0",
           "--steps", "3", "--workers", "1", "--no-progress", "--out"]
    export = ["export", "default", "--seed-list", "0", "--policy", "raster", "--steps", STEPS,
              "--out"]
    cases = [
        (["score", str(world), "--estimates", str(world / "est.csv"), "--out",
          str(run_folder)], run_folder, "holds the runs of a sweep"),
        ([*export, str(run_folder)], run_folder, "holds the runs of a sweep"),
        ([*run, str(scored)], scored, "holds the output of `mttbench score`"),
        ([*run, str(exported)], exported, "holds the worlds of `mttbench export`"),
        ([*export, str(scored)], scored, "holds the output of `mttbench score`"),
        (["score", str(world), "--estimates", str(world / "est.csv"), "--out",
          str(exported)], exported, "holds the worlds of `mttbench export`"),
    ]
    for argv, folder, expected in cases:
        before = snapshot(folder)
        assert main(argv) == 2, argv
        line = one_line(capsys)
        assert expected in line and line.startswith(f"mttbench {argv[0]}: error: "), line
        assert snapshot(folder) == before, argv


def test_score_and_export_refuse_a_folder_in_use(exported, tmp_path, capsys):
    world = _world(exported)
    for argv, out in [
        (["score", str(world), "--estimates", str(world / "est.csv"), "--out"], "scored"),
        (["export", "default", "--seed-list", "0", "--policy", "raster", "--steps", STEPS,
          "--out"], "worlds"),
    ]:
        folder = tmp_path / out
        folder.mkdir()
        fd = os.open(folder / LOCK_FILE, os.O_RDWR | os.O_CREAT)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            assert main([*argv, str(folder)]) == 2
        finally:
            os.close(fd)
        assert "in use by another mttbench process" in one_line(capsys)
        assert {p.name for p in folder.iterdir()} == {LOCK_FILE}

"""``mttbench score``'s inputs against its documented format (benchmarks/app/score.py):
a count-only row leaves both x and y empty and gives a count; a row with one coordinate
empty, or a value beyond the magnitude limit on either side, is refused in one line; runs
``--beside`` the worlds are compared by the length of their ok rows."""

from __future__ import annotations

import re

import crashing_tracker
import pandas as pd
import pytest

from mttbench.benchmarks.app import export as ex
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.app.score import read_estimates
from mttbench.benchmarks.app.usage import UsageError


def _csv(tmp_path, body: str):
    path = tmp_path / "est.csv"
    path.write_text("step,x,y,count\n" + body)
    return path


def test_a_count_only_row_leaves_both_coordinates_empty(tmp_path):
    steps = read_estimates(_csv(tmp_path, "0,,,2.5\n1,1.0,2.0,1\n"), 2)
    assert steps[0].positions.shape == (0, 2) and steps[0].count == 2.5
    assert steps[1].positions.tolist() == [[1.0, 2.0]] and steps[1].count == 1.0


@pytest.mark.parametrize("row, empty", [("0,,1.5,2", "x"), ("0,1.5,,2", "y"),
                                        ("0,,1.5,", "x"), ("0,1.5,nan,2", "y")])
def test_a_row_with_one_coordinate_empty_is_refused(tmp_path, row, empty):
    with pytest.raises(UsageError) as err:
        read_estimates(_csv(tmp_path, "1,1.0,1.0,2\n" + row + "\n"), 2)
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith(f"estimates {tmp_path / 'est.csv'}: {empty} is empty or NaN on "
                           "line 3")


@pytest.mark.parametrize("col, sign", [(c, s) for c in ("x", "y", "label") for s in (1, -1)]
                         + [("count", 1)])  # a negative count is refused as negative
def test_a_value_beyond_the_magnitude_limit_is_refused_on_either_side(tmp_path, col, sign):
    """|value| > MAX_ABS (MAX_LABEL for labels) is refused; at the limit it is read. The
    limits are written out here (1e12 and 2^53), not read from the module."""
    limit = 2.0**53 if col == "label" else 1e12
    row = {"step": 0, "x": 1.0, "y": 1.0, "label": 1, "count": 1.0}
    path = tmp_path / "est.csv"

    def write(value: float) -> None:
        path.write_text("step,x,y,label,count\n" + ",".join(
            repr(float(value)) if k == col else str(v) for k, v in row.items()) + "\n")

    write(sign * limit)
    read_estimates(path, 1)  # at the limit: read
    write(sign * limit * 4)
    with pytest.raises(UsageError, match=re.escape(f"{col} {sign * limit * 4:g} on line 2 is "
                                                     f"beyond +-{limit:g}")):
        read_estimates(path, 1)


class FailAtOnce(crashing_tracker._Nothing):
    """Raises at its first step: its runs have no ok row."""

    summary = "test tracker: raises at step 0"

    def predict(self):
        raise RuntimeError("deliberate failure at step 0")


def test_runs_beside_that_all_failed_on_the_world_are_joined(tmp_path, capsys):
    """--beside compares the worlds' lengths with the ok rows of the runs there; a world
    whose runs there all failed has no length to compare, so the score is joined with
    them (their error rows kept), while runs of the same tracker on a longer run of the
    world are refused."""
    worlds = tmp_path / "worlds"
    assert main(["export", "default", "--seed-list", "0", "--policy", "raster", "--steps",
                 "4", "--out", str(worlds)]) == 0
    world = worlds / ex.world_name("default", 0, "raster", 24)
    t = pd.read_csv(world / "truth.csv")
    t.rename(columns={"px": "x", "py": "y"})[["step", "x", "y"]].to_csv(
        world / "est.csv", index=False)
    common = ["--scenarios", "default", "--policy", "raster", "--seed-list", "0",
              "--workers", "1", "--no-progress", "--retries", "0"]
    failed, longer = tmp_path / "failed", tmp_path / "longer"
    assert main(["run", *common, "--trackers", "test_heldout4_score:FailAtOnce", "null",
                 "--steps", "4", "--out", str(failed)]) == 1
    ok = pd.read_parquet(failed / "results.parquet")
    assert (ok.loc[ok["tracker"] == "null", "status"] == "ok").all()
    # the failing tracker's run alone: a folder with no ok row on the world
    alone = tmp_path / "alone"
    assert main(["run", *common, "--trackers", "test_heldout4_score:FailAtOnce",
                 "--steps", "4", "--out", str(alone)]) == 1
    assert main(["run", *common, "--trackers", "null", "--steps", "5",
                 "--out", str(longer)]) == 0
    capsys.readouterr()
    assert main(["score", str(world), "--estimates", str(world / "est.csv"), "--name", "t",
                 "--beside", str(alone), "--out", str(tmp_path / "s1")]) == 0
    table = pd.read_parquet(tmp_path / "s1" / "results.parquet")
    assert set(table["tracker_label"]) == {"outside:t", "test_heldout4_score:FailAtOnce"}
    assert (table.loc[table["tracker_label"] == "outside:t", "status"] == "ok").sum() == 4
    capsys.readouterr()
    assert main(["score", str(world), "--estimates", str(world / "est.csv"), "--name", "t",
                 "--beside", str(longer), "--out", str(tmp_path / "s2")]) == 2
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert len(err) == 1 and "steps" in err[0], err

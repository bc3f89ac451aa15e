"""``mttbench score``'s estimates file, row by row against its documented format
(benchmarks/app/score.py): a count-only row leaves both x and y empty and gives a count;
a row with one coordinate empty is refused in one line naming it, count or not."""

from __future__ import annotations

import pytest

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

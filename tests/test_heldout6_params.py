"""A budget range (``params.Budget``) must be an interval with ``0 < low < high``: a
range of one value cannot be swept (its log grid repeats one point), so it is refused
when declared, as a reversed, zero or non-finite range is."""

from __future__ import annotations

import math

import pytest

from mttbench.trackers.params import Budget


@pytest.mark.parametrize("low, high", [(2.0, 2.0), (100.0, 100.0), (3.0, 2.0), (0.0, 1.0),
                                       (-1.0, 1.0), (1.0, math.inf), (math.nan, 2.0)])
def test_a_range_that_is_not_an_open_positive_interval_is_refused(low, high):
    with pytest.raises(TypeError, match=r"0 < low < high"):
        Budget(low, high)


@pytest.mark.parametrize("low, high", [(1.0, 2.0), (1e-6, 1e-5), (10.0, 10.000001)])
def test_a_positive_interval_is_accepted_and_its_grid_spans_it(low, high):
    b = Budget(low, high)
    g = b.grid(5, integer=False)
    assert g[0] == pytest.approx(low) and g[-1] == pytest.approx(high)
    assert all(x < y for x, y in zip(g, g[1:], strict=False))

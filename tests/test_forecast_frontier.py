"""hours_for_error along the Pareto frontier of the plan's sizes: a dominated size between two frontier sizes is left
out, the target is interpolated between the frontier neighbours in log hours, and an unreached target is None."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.rig.forecast import hours_for_error, pareto_frontier


def _plan(hours: list[float], error_mm: list[float], depth_mm: list[float] | None = None) -> pd.DataFrame:
    return pd.DataFrame(
        {
            "design": ["random"] * len(hours),
            "depth_mm": depth_mm or [3.5] * len(hours),
            "rig_hours": hours,
            "mean_error_mm": error_mm,
        }
    )


def test_a_dominated_size_between_frontier_sizes_does_not_flatten_the_curve():
    # the audit's case, in round numbers: 1 h for 3.2 mm, 2 h for 2.4 mm (frontier); 1.9 h for 4.2 mm (dominated by
    # the 1 h size: more hours, more error). 3 mm is a quarter of the way from 3.2 to 2.4 mm: 1 h x 2^(1/4).
    frame = _plan([0.5, 1.0, 2.0, 1.9, 8.0], [4.4, 3.2, 2.4, 4.2, 2.0])
    assert hours_for_error(frame, 3.0) == pytest.approx(2.0**0.25)
    # 2.6 mm: three quarters of the way: 2^(3/4) h; the old best-so-far curve gave 1.9 h to 2 h for both
    assert hours_for_error(frame, 2.6) == pytest.approx(2.0**0.75)
    # on a frontier point: its own hours
    assert hours_for_error(frame, 2.4) == pytest.approx(2.0)
    # 2.2 mm: halfway from 2.4 mm at 2 h to 2.0 mm at 8 h in log hours: 4 h
    assert hours_for_error(frame, 2.2) == pytest.approx(4.0)


def test_a_target_no_size_reaches_is_none_and_one_the_first_size_reaches_is_its_hours():
    frame = _plan([0.5, 1.0, 2.0, 1.9], [4.4, 3.2, 2.4, 4.2])
    assert hours_for_error(frame, 2.39) is None
    assert hours_for_error(frame, 1.0) is None
    assert hours_for_error(frame, 5.0) == pytest.approx(0.5)
    assert hours_for_error(frame, 3.0, design="adaptive") is None


def test_the_frontier_keeps_the_better_of_equal_hours_and_only_the_protocols_depth():
    # two sizes at 1.5 h: only the 2.5 mm one is on the frontier; the 4.5 mm depth variant (1 mm) is another depth
    frame = _plan([1.0, 1.5, 1.5, 3.0, 1.2], [3.0, 3.5, 2.5, 2.0, 1.0], depth_mm=[3.5, 3.5, 3.5, 3.5, 4.5])
    assert list(pareto_frontier(np.array([1.0, 1.5, 1.5, 3.0]), np.array([3.0, 3.5, 2.5, 2.0]))) == [0, 2, 3]
    assert hours_for_error(frame, 2.75) == pytest.approx(np.sqrt(1.0 * 1.5))
    assert hours_for_error(frame, 1.5) is None


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(0.1, 20.0), st.floats(0.5, 6.0)),
        min_size=1,
        max_size=12,
    )
)
def test_the_frontier_is_exactly_the_undominated_sizes_with_error_falling(points):
    hours = np.array([h for h, _ in points])
    error = np.array([e for _, e in points])
    front = pareto_frontier(hours, error)
    assert np.all(np.diff(hours[front]) > 0) and np.all(np.diff(error[front]) < 0)
    for k in range(len(points)):
        dominated = np.any((hours <= hours[k]) & (error <= error[k]) & ((hours < hours[k]) | (error < error[k])))
        duplicate_before = np.any((hours[:k] == hours[k]) & (error[:k] == error[k]))
        assert (k in front) == (not dominated and not duplicate_before)

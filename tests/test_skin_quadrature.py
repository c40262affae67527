"""Near full-depth presses (p0 -> 1): the deformation integral's graded panels keep the default resolution within
its stated bound of an adaptive QUADPACK reference, where the channel crosses the probe and where it only grazes it."""

from __future__ import annotations

import numpy as np
import pytest
from test_skin_deformation import PROBE_MM, quad_reference

from neatskin.skin.deformation import _graded_edges, resistance_factor
from neatskin.skin.layouts import grid_layout

DEPTHS = (5.0, 5.3, 5.4, 5.45, 5.49, 5.499, 5.4999)  # the skin is 5.5 mm thick: p0 = d / T up to 0.99998
OFFSETS = (0.0, 1.0, 2.0, 2.5, 2.7, 2.75, 2.8, 3.0, 4.0)  # the channel's distance from the probe axis


@pytest.fixture(scope="module")
def single():
    return grid_layout(2, 2, pitch_mm=15.0)


@pytest.mark.parametrize("depth", DEPTHS)
def test_near_full_depth_within_the_stated_bound(single, depth):
    worst = 0.0
    for y in OFFSETS:
        for x in (7.5, 2.0, 14.0):
            got = resistance_factor(single, x, y, depth, PROBE_MM)[0, 0]
            worst = max(worst, abs(got / quad_reference(single, x, y, depth) - 1))
    assert worst < 1e-5  # docs/skin.md: the default resolution's bound, at every depth below the skin's thickness


def test_graded_panels_reach_the_peak_width():
    edges = _graded_edges(np.array([0.5, 0.999]))
    peak = np.sqrt(0.001 / 0.999)  # half-width of 1 / (1 - p0 exp(-u^2)) in decay lengths
    assert edges[0] == 0.0 and edges[1] <= peak < 2 * edges[1]
    assert np.all(np.diff(edges) > 0) and edges[-1] == np.inf

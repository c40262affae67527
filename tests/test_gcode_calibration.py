"""Sensor -> printer calibration: the fit recovers a known transform and reports its residual."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.errors import ConfigError
from neatskin.gcode.calibration import Calibration, fit_calibration


def test_transform_and_inverse():
    cal = Calibration(100.0, 50.0, 90.0, 4.0)
    px, py = cal.to_printer(10.0, 0.0)
    assert (float(px), float(py)) == pytest.approx((100.0, 60.0))
    sx, sy = cal.to_sensor(px, py)
    assert (float(sx), float(sy)) == pytest.approx((10.0, 0.0))


@settings(max_examples=40, deadline=None)
@given(st.floats(-50, 150), st.floats(-50, 150), st.floats(-180, 179.9), st.floats(0, 30), st.booleans())
def test_fit_recovers_known_offset_and_rotation(ox, oy, rot, z, three):
    truth = Calibration(ox, oy, rot, z)
    sensor = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0]])[: 3 if three else 2]
    px, py = truth.to_printer(sensor[:, 0], sensor[:, 1])
    fit = fit_calibration(sensor, np.column_stack([px, py, np.full(len(sensor), z)]))
    c = fit.calibration
    assert c.offset_x_mm == pytest.approx(ox, abs=1e-9) and c.offset_y_mm == pytest.approx(oy, abs=1e-9)
    assert (c.rotation_deg - rot + 180) % 360 - 180 == pytest.approx(0, abs=1e-9)
    assert c.surface_z_mm == pytest.approx(z)
    assert fit.max_mm < 1e-9 and fit.z_spread_mm < 1e-12


def test_residual_reports_a_misplaced_point():
    sensor = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0]])
    printer = np.array([[95.0, 95.0, 5.0], [125.0, 95.0, 5.2], [95.0, 125.0, 4.8]])
    printer[2, 0] += 0.3  # one jog 0.3 mm off
    fit = fit_calibration(sensor, printer)
    assert 0.05 < fit.max_mm < 0.3
    assert fit.rms_mm <= fit.max_mm
    assert fit.z_spread_mm == pytest.approx(0.2)
    assert fit.calibration.surface_z_mm == pytest.approx(5.0)


def test_bad_reference_points():
    with pytest.raises(ConfigError, match="at least 2"):
        fit_calibration([[0, 0]], [[1, 1, 1]])
    with pytest.raises(ConfigError, match="less than 1 mm"):
        fit_calibration([[0, 0], [0.1, 0]], [[1, 1, 1], [1.1, 1, 1]])
    with pytest.raises(ConfigError, match="points, 3"):
        fit_calibration([[0, 0], [1, 0]], [[1, 1], [2, 1]])

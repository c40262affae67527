"""The errors-in-variables average of `skin fit` against exact references: a quadratic forward model's average over
N(0, s^2 I) is f(c) + s^2 (a_xx + a_yy), which a 5-point Gauss-Hermite rule integrates exactly; s = 0 is the model."""

import numpy as np
import pytest

from neatskin.skin.fitblur import averaged_dr, coverage_of, landing_offsets


class QuadraticSkin:
    """dR of two pairs: 3 + 2x - y + 0.5 x^2 + 0.25 xy - 1.5 y^2, and x^2 + y^2."""

    baseline_pair_resistance_ohm = np.array([1.0, 0.0])

    def pair_resistance_ohm(self, x, y, depth):
        x, y = np.asarray(x, float), np.asarray(y, float)
        return np.column_stack([4 + 2 * x - y + 0.5 * x**2 + 0.25 * x * y - 1.5 * y**2, x**2 + y**2])


@pytest.mark.parametrize("sigma", [0.3, 1.35, 4.0])
def test_the_average_of_a_quadratic_is_exact(sigma):
    skin = QuadraticSkin()
    x, y = np.array([0.0, 1.5, -2.0]), np.array([1.0, 0.5, 3.0])
    got = averaged_dr(skin, x, y, np.full(3, 3.5), sigma)
    plain = skin.pair_resistance_ohm(x, y, 3.5) - skin.baseline_pair_resistance_ohm
    expected = plain + sigma**2 * np.array([0.5 - 1.5, 2.0])
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)


def test_no_placement_error_is_the_model_itself():
    skin = QuadraticSkin()
    offsets, weights = landing_offsets(0.0)
    assert offsets.tolist() == [[0.0, 0.0]] and weights.tolist() == [1.0]
    x, y = np.array([0.2]), np.array([0.7])
    np.testing.assert_array_equal(
        averaged_dr(skin, x, y, np.full(1, 3.5), 0.0), skin.pair_resistance_ohm(x, y, 3.5) - [1.0, 0.0]
    )


def test_the_rule_has_the_normals_moments():
    offsets, weights = landing_offsets(2.0)
    assert weights.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(weights @ offsets, 0.0, atol=1e-12)
    np.testing.assert_allclose((weights[:, None] * offsets).T @ offsets, 4.0 * np.eye(2), atol=1e-12)


def test_an_unmeasured_parameter_states_no_coverage():
    assert coverage_of("no_such_parameter", 1.0) is None


def test_the_measured_shortfalls_are_stated_and_the_rest_hold_their_95():
    assert coverage_of("pinch_gain", 1.2) == 0.22 and coverage_of("noise_ohm", 0.55) == 0.82
    assert coverage_of("pinch_gain", 0.5) is None and coverage_of("placement_error_mm", 0.6) is None
    assert coverage_of("drift_per_h", 1.35) is None


def test_errors_in_variables_remove_most_of_the_pinch_bias_at_paper_like_placement(tmp_path, paper_layout):
    """At 1.35 mm placement the fit against the model at the commanded point gave a pinch of 0.69 to 0.73 for 0.80
    (issue 23); averaged over the landing points it is within 0.05 of the truth on each of 3 seeds, and the
    interval says the coverage it was measured to have (22 %, benchmarks/bench_fit_coverage.py)."""
    from test_skin_fit import write_campaign

    from neatskin.skin.deformation import PinchParams
    from neatskin.skin.fit import fit_skin

    for seed in (1, 2, 3):
        folder = tmp_path / f"c{seed}"
        write_campaign(folder, paper_layout, seed=seed, repeats=8, placement_mm=1.35, pinch=PinchParams(0.8, 0.5))
        fit = fit_skin(folder)
        assert abs(fit.pinch_gain.value - 0.8) < 0.05, fit.pinch_gain
        assert fit.pinch_gain.coverage == 0.22
        assert "measured coverage 22 %, not 95 %" in fit.to_toml()

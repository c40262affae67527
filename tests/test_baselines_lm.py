"""The paper's LM network: weight count, Jacobian, a known function, determinism, scipy lm, sklearn checks."""

import numpy as np
import pytest
from sklearn.utils.estimator_checks import parametrize_with_checks

from neatskin.baselines.lm import LMNetworkRegressor, fit_with_scipy_lm, minmax_fit
from neatskin.baselines.lmnetwork import (
    forward,
    initial_weights,
    input_outer_products,
    n_weights,
    normal_equations,
    residual_jacobian,
    train_lm,
)


def test_paper_network_has_157_weights():
    assert n_weights(28, 5, 2) == 157
    rng = np.random.default_rng(0)
    X, y = rng.random((60, 28)), rng.random((60, 2))
    model = LMNetworkRegressor(n_restarts=1, max_epochs=3, random_state=0).fit(X, y)
    assert model.n_weights_ == 157
    assert model.weights_.shape == (157,)


def test_analytic_jacobian_matches_finite_differences():
    rng = np.random.default_rng(1)
    x = rng.random((7, 4))
    w = initial_weights(4, 3, 2, rng)
    hidden, out = forward(w, x, 3, 2)
    jac = residual_jacobian(w, x, hidden, 2)
    step = 1e-6
    numeric = np.empty_like(jac)
    for p in range(w.size):
        dw = np.zeros_like(w)
        dw[p] = step
        numeric[:, p] = (forward(w + dw, x, 3, 2)[1] - forward(w - dw, x, 3, 2)[1]).ravel() / (2 * step)
    np.testing.assert_allclose(jac, numeric, atol=1e-8)


def test_structured_normal_equations_equal_dense_ones():
    rng = np.random.default_rng(2)
    x, err = rng.random((50, 6)), rng.normal(size=(50, 3))
    w = initial_weights(6, 4, 3, rng)
    hidden, _ = forward(w, x, 4, 3)
    jac = residual_jacobian(w, x, hidden, 3)
    jtj, jte = normal_equations(w, x, input_outer_products(x), hidden, err)
    np.testing.assert_allclose(jtj, jac.T @ jac, atol=1e-10)
    np.testing.assert_allclose(jte, jac.T @ err.ravel(), atol=1e-10)


def test_reproduces_a_known_smooth_function():
    rng = np.random.default_rng(3)
    X = rng.uniform(-1, 1, (400, 2))
    y = np.column_stack([np.sin(2 * X[:, 0]) + X[:, 1] ** 2, X[:, 0] * X[:, 1]])
    model = LMNetworkRegressor(n_hidden=8, n_restarts=3, val_fraction=0.1, random_state=0).fit(X, y)
    X_test = rng.uniform(-0.9, 0.9, (200, 2))
    y_test = np.column_stack([np.sin(2 * X_test[:, 0]) + X_test[:, 1] ** 2, X_test[:, 0] * X_test[:, 1]])
    rms = np.sqrt(np.mean((model.predict(X_test) - y_test) ** 2))
    assert rms < 0.02, rms


def test_deterministic_for_a_seed_and_different_across_seeds():
    rng = np.random.default_rng(4)
    X, y = rng.random((120, 5)), rng.random((120, 2))
    a = LMNetworkRegressor(n_restarts=3, max_epochs=30, random_state=7).fit(X, y)
    b = LMNetworkRegressor(n_restarts=3, max_epochs=30, random_state=7).fit(X, y)
    c = LMNetworkRegressor(n_restarts=3, max_epochs=30, random_state=8).fit(X, y)
    np.testing.assert_array_equal(a.weights_, b.weights_)
    np.testing.assert_array_equal(a.predict(X), b.predict(X))
    assert not np.array_equal(a.weights_, c.weights_)


def test_best_restart_is_the_lowest_validation_mse():
    rng = np.random.default_rng(5)
    X = rng.random((200, 3))
    y = np.column_stack([np.tanh(3 * X[:, 0] - 1), X[:, 1] * X[:, 2]])
    model = LMNetworkRegressor(n_restarts=4, random_state=0).fit(X, y)
    assert model.val_mse_.shape == (4,)
    assert model.best_restart_ == int(np.argmin(model.val_mse_))
    assert set(model.stop_reasons_) <= {"max_fail", "min_grad", "mu_max", "max_epochs"}


def test_training_loss_never_increases_with_more_epochs():
    # validating on the training rows makes "best validation" the latest accepted step, and an
    # LM step is only accepted when it lowers the training loss
    rng = np.random.default_rng(6)
    x = rng.random((150, 4))
    y = np.column_stack([np.sin(4 * x[:, 0]) * x[:, 1], x[:, 2] - x[:, 3] ** 2])
    w0 = initial_weights(4, 3, 2, rng)
    runs = [train_lm(w0, x, y, x, y, 3, max_epochs=e, max_fail=10**6) for e in (0, 1, 2, 5, 10, 40)]
    losses = [r.train_mse for r in runs]
    assert all(b <= a for a, b in zip(losses, losses[1:]))
    assert losses[-1] < 0.5 * losses[0]
    assert [r.val_mse for r in runs] == pytest.approx(losses)


def test_comparable_loss_to_scipy_lm_on_a_small_problem():
    rng = np.random.default_rng(9)
    x = rng.random((120, 3))
    y = np.column_stack([np.sin(3 * x[:, 0]) * x[:, 1], x[:, 2] ** 2])
    ys = (y - minmax_fit(y)[0]) / minmax_fit(y)[1]
    w0 = initial_weights(3, 4, 2, rng)
    ours = train_lm(w0, x[:100], ys[:100], x[100:], ys[100:], 4, max_fail=10**6, max_epochs=300)
    ref = fit_with_scipy_lm(x[:100], ys[:100], x[100:], ys[100:], w0, 4, analytic_jacobian=True)
    assert ours.train_mse < 1e-3 and ref.train_mse < 1e-3
    # same problem, same start: our loop ends at least as low as MINPACK (here lower: MINPACK
    # stops on its relative-reduction tolerance in a flat valley)
    assert ours.train_mse <= 1.1 * ref.train_mse
    assert ours.val_mse <= 1.5 * ref.val_mse


def test_constant_input_and_target_columns_give_finite_predictions():
    rng = np.random.default_rng(10)
    X = rng.random((80, 4))
    X[:, 2] = 5.0
    y = np.column_stack([X[:, 0], np.full(80, 3.0)])
    model = LMNetworkRegressor(n_restarts=2, random_state=0).fit(X, y)
    pred = model.predict(X)
    assert np.isfinite(pred).all()
    np.testing.assert_allclose(pred[:, 1], 3.0, atol=1e-3)


@pytest.mark.parametrize("bad", [dict(n_hidden=0), dict(val_fraction=1.0), dict(mu_dec=2.0)])
def test_bad_parameters_raise_value_error(bad):
    with pytest.raises(ValueError):
        LMNetworkRegressor(**bad).fit(np.random.rand(10, 2), np.random.rand(10))


@parametrize_with_checks([LMNetworkRegressor(n_restarts=2, max_epochs=50, random_state=0)])
def test_sklearn_estimator_checks(estimator, check):
    check(estimator)


def test_restart_problem_reproduces_the_restart_it_names():
    rng = np.random.default_rng(11)
    X = rng.random((90, 4))
    y = np.column_stack([np.sin(3 * X[:, 0]), X[:, 1] * X[:, 3]])
    model = LMNetworkRegressor(n_restarts=3, val_fraction=0.2, random_state=5).fit(X, y)
    for k in range(3):
        p = model.restart_problem(X, y, restart=k)
        assert len(p["x_val"]) == 18 and len(p["x_train"]) == 72
        run = train_lm(p["w0"], p["x_train"], p["y_train"], p["x_val"], p["y_val"], 5)
        assert run.val_mse == pytest.approx(model.val_mse_[k], rel=1e-12)


def test_restarts_in_processes_give_the_same_network():
    from joblib import parallel_config

    rng = np.random.default_rng(9)
    X = rng.random((160, 6))
    y = np.column_stack([np.tanh(2 * X[:, 0] - X[:, 1]), X[:, 2] * X[:, 3]])
    here = LMNetworkRegressor(n_restarts=4, max_epochs=40, random_state=3, n_jobs=1).fit(X, y)
    pool = LMNetworkRegressor(n_restarts=4, max_epochs=40, random_state=3, n_jobs=2).fit(X, y)
    with parallel_config(n_jobs=2):  # n_jobs=None follows the enclosing joblib configuration
        context = LMNetworkRegressor(n_restarts=4, max_epochs=40, random_state=3).fit(X, y)
    for other in (pool, context):
        np.testing.assert_array_equal(other.weights_, here.weights_)
        np.testing.assert_array_equal(other.val_mse_, here.val_mse_)
        assert other.n_epochs_.tolist() == here.n_epochs_.tolist()

"""The LM network's numerics: the tanh network's forward pass, Jacobian, normal equations, start and trainlm loop.

Pure functions on inputs and targets already scaled to [0, 1] and a flat weight vector
(hidden rows (h, in+1) then output rows (out, h+1), bias last); `lm.LMNetworkRegressor` scales,
draws each restart's rows and start, and calls `train_lm`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dposv as _posv
from threadpoolctl import threadpool_limits


def n_weights(n_inputs: int, n_hidden: int, n_outputs: int) -> int:
    """Number of weights (biases included) of an n_inputs-n_hidden-n_outputs network."""
    return n_hidden * (n_inputs + 1) + n_outputs * (n_hidden + 1)


def _split_weights(w: np.ndarray, n_inputs: int, n_hidden: int, n_outputs: int):
    """Views of the flat weight vector: hidden (h, in+1) and output (out, h+1), bias last."""
    k = n_hidden * (n_inputs + 1)
    return w[:k].reshape(n_hidden, n_inputs + 1), w[k:].reshape(n_outputs, n_hidden + 1)


def forward(w: np.ndarray, x: np.ndarray, n_hidden: int, n_outputs: int) -> tuple[np.ndarray, np.ndarray]:
    """Hidden activations (n, h) and outputs (n, out) for scaled inputs x (n, in)."""
    w1, w2 = _split_weights(w, x.shape[1], n_hidden, n_outputs)
    hidden = np.tanh(x @ w1[:, :-1].T + w1[:, -1])
    return hidden, hidden @ w2[:, :-1].T + w2[:, -1]


def residual_jacobian(w: np.ndarray, x: np.ndarray, hidden: np.ndarray, n_outputs: int) -> np.ndarray:
    """d(outputs)/d(weights) for every sample and output: (n * out, n_weights), rows sample-major."""
    n, n_inputs = x.shape
    n_hidden = hidden.shape[1]
    _, w2 = _split_weights(w, n_inputs, n_hidden, n_outputs)
    # d y_k / d hidden pre-activation j = w2[k, j] * (1 - tanh^2)
    a = (1.0 - hidden * hidden)[:, None, :] * w2[None, :, :-1]  # (n, out, h)
    jac = np.zeros((n, n_outputs, n_weights(n_inputs, n_hidden, n_outputs)))
    k = n_hidden * (n_inputs + 1)
    first = jac[:, :, :k].reshape(n, n_outputs, n_hidden, n_inputs + 1)
    first[..., :-1] = a[..., None] * x[:, None, None, :]
    first[..., -1] = a
    second = jac[:, :, k:].reshape(n, n_outputs, n_outputs, n_hidden + 1)
    outs = np.arange(n_outputs)
    second[:, outs, outs, :-1] = hidden[:, None, :]
    second[:, outs, outs, -1] = 1.0
    return jac.reshape(n * n_outputs, -1)


def input_outer_products(x: np.ndarray) -> np.ndarray:
    """Upper-triangle products x1_i * x1_l of the bias-augmented inputs, (n, m(m+1)/2); fixed per fit."""
    x1 = np.column_stack([x, np.ones(len(x))])
    iu, ju = np.triu_indices(x1.shape[1])
    return x1[:, iu] * x1[:, ju]


def normal_equations(
    w: np.ndarray,
    x: np.ndarray,
    x_products: np.ndarray,
    hidden: np.ndarray,
    err: np.ndarray,
    x_bias: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """J^T J and J^T e of the residuals without forming J, from the network's block structure.

    Equal to `J.T @ J` and `J.T @ err.ravel()` with J = residual_jacobian(...), at a fraction of
    the cost: the hidden-hidden block is one product of the per-sample hidden-unit couplings
    (upper triangle) with the fixed input outer products `x_products`. `x_bias` is x with a
    column of ones appended (computed when not given; the training loop passes it once).
    """
    n, n_inputs = x.shape
    n_hidden, n_outputs = hidden.shape[1], err.shape[1]
    m = n_inputs + 1
    _, w2 = _split_weights(w, n_inputs, n_hidden, n_outputs)
    x1 = x_bias if x_bias is not None else np.column_stack([x, np.ones(n)])
    h1 = np.column_stack([hidden, np.ones(n)])
    a = (1.0 - hidden * hidden)[:, None, :] * w2[None, :, :-1]  # (n, out, h)
    k = n_hidden * m
    size = n_weights(n_inputs, n_hidden, n_outputs)
    jtj = np.empty((size, size))
    # hidden-hidden block: sum_n (sum_k a_kj a_kj') x1_i x1_i'
    jh, jh2 = np.triu_indices(n_hidden)
    coupling = a[:, 0, jh] * a[:, 0, jh2]  # (n, pairs of hidden units), summed over outputs
    for out in range(1, n_outputs):
        coupling += a[:, out, jh] * a[:, out, jh2]
    packed = coupling.T @ x_products  # (hidden pairs, input pairs)
    iu, ju = np.triu_indices(m)
    block = np.empty((len(jh), m, m))
    block[:, iu, ju] = packed
    block[:, ju, iu] = packed
    b11 = np.empty((n_hidden, n_hidden, m, m))
    b11[jh, jh2] = block
    b11[jh2, jh] = block.transpose(0, 2, 1)
    jtj[:k, :k] = b11.transpose(0, 2, 1, 3).reshape(k, k)
    # hidden-output block: sum_n a_kj x1_i h1_m for output k
    ah = (a[:, :, :, None] * h1[:, None, None, :]).reshape(n, -1)
    b12 = (x1.T @ ah).reshape(m, n_outputs, n_hidden, n_hidden + 1)
    b12 = b12.transpose(2, 0, 1, 3).reshape(k, n_outputs * (n_hidden + 1))
    jtj[:k, k:] = b12
    jtj[k:, :k] = b12.T
    # output-output block: block diagonal, one h1^T h1 per output
    hh = h1.T @ h1
    jtj[k:, k:] = np.kron(np.eye(n_outputs), hh)
    g1 = np.einsum("nkj,nk->nj", a, err).T @ x1  # (h, m)
    g2 = err.T @ h1  # (out, h + 1)
    return jtj, np.concatenate([g1.ravel(), g2.ravel()])


def initial_weights(n_inputs: int, n_hidden: int, n_outputs: int, rng: np.random.Generator) -> np.ndarray:
    """Nguyen-Widrow-like start for inputs in [0, 1]: hidden units spread over the input box.

    Each hidden unit's input weights have norm 0.7 * h^(1/in) (Nguyen & Widrow's magnitude) in a
    random direction, and its bias puts the unit's active region at a random point of the box;
    output weights are uniform in [-0.5, 0.5].
    """
    beta = 0.7 * n_hidden ** (1.0 / max(n_inputs, 1))
    w_in = rng.uniform(-1.0, 1.0, (n_hidden, n_inputs))
    norms = np.linalg.norm(w_in, axis=1, keepdims=True)
    w_in = beta * w_in / np.where(norms > 0, norms, 1.0)
    centre = rng.uniform(0.0, 1.0, (n_hidden, n_inputs))
    b_in = -np.sum(w_in * centre, axis=1)
    w_out = rng.uniform(-0.5, 0.5, (n_outputs, n_hidden + 1))
    return np.concatenate([np.column_stack([w_in, b_in]).ravel(), w_out.ravel()])


@dataclass(frozen=True)
class LMRun:
    """One Levenberg-Marquardt training run: best weights and how it went."""

    weights: np.ndarray
    train_mse: float
    val_mse: float
    n_epochs: int
    stop_reason: str


def train_lm(
    w0: np.ndarray,
    x_train: np.ndarray,
    y_train: np.ndarray,
    x_val: np.ndarray,
    y_val: np.ndarray,
    n_hidden: int,
    *,
    mu: float = 1e-3,
    mu_dec: float = 0.1,
    mu_inc: float = 10.0,
    mu_max: float = 1e10,
    max_fail: int = 6,
    max_epochs: int = 1000,
    min_grad: float = 1e-7,
) -> LMRun:
    """MATLAB-trainlm-style Levenberg-Marquardt on scaled data; returns the best-validation weights.

    Runs with one BLAS thread: on 157 x 157 systems, thread wake-ups cost more than they save
    (cholesky measured x5 slower with two busy threads).
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _train_lm(
            w0,
            x_train,
            y_train,
            x_val,
            y_val,
            n_hidden,
            mu=mu,
            mu_dec=mu_dec,
            mu_inc=mu_inc,
            mu_max=mu_max,
            max_fail=max_fail,
            max_epochs=max_epochs,
            min_grad=min_grad,
        )


def _train_lm(
    w0,
    x_train,
    y_train,
    x_val,
    y_val,
    n_hidden,
    *,
    mu,
    mu_dec,
    mu_inc,
    mu_max,
    max_fail,
    max_epochs,
    min_grad,
) -> LMRun:
    n_outputs = y_train.shape[1]
    w = w0.astype(float, copy=True)
    eye = np.eye(w.size)

    def sse(weights: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        hidden, out = forward(weights, x, n_hidden, n_outputs)
        err = out - y
        return float(np.einsum("ij,ij->", err, err)), hidden, err

    x_products = input_outer_products(x_train)
    x_bias = np.column_stack([x_train, np.ones(len(x_train))])
    train_sse, hidden, err = sse(w, x_train, y_train)
    val_sse = sse(w, x_val, y_val)[0]
    best_w, best_val, fails = w.copy(), val_sse, 0
    n_train, n_val = y_train.size, max(y_val.size, 1)
    stop, epoch = "max_epochs", 0
    for epoch in range(1, max_epochs + 1):  # noqa: B007 (the count is read after the loop)
        jtj, jte = normal_equations(w, x_train, x_products, hidden, err, x_bias)
        if np.sqrt(jte @ jte) * 2.0 / n_train < min_grad:
            stop = "min_grad"
            break
        while mu <= mu_max:
            _, step, info = _posv(jtj + mu * eye, -jte, lower=1, overwrite_a=1, overwrite_b=1)
            if info != 0:  # not positive definite at this damping: damp more
                mu *= mu_inc
                continue
            candidate = w + step
            cand_sse, cand_hidden, cand_err = sse(candidate, x_train, y_train)
            if cand_sse < train_sse:
                w, train_sse, hidden, err = candidate, cand_sse, cand_hidden, cand_err
                mu = max(mu * mu_dec, 1e-20)
                break
            mu *= mu_inc
        if mu > mu_max:
            stop = "mu_max"
            break
        val_sse = sse(w, x_val, y_val)[0]
        if val_sse < best_val:
            best_w, best_val, fails = w.copy(), val_sse, 0
        else:
            fails += 1
            if fails >= max_fail:
                stop = "max_fail"
                break
    best_train = sse(best_w, x_train, y_train)[0]
    return LMRun(best_w, best_train / n_train, best_val / n_val, epoch, stop)

"""The synthetic regression problem of the seed paper (section IV.A, Fig. 2).

Ten relevant inputs are drawn from a Gaussian with a random covariance; the output is
``y = b^T t`` with ``b = [1, 2, ..., 10]`` plus output noise; the relevant inputs are observed
with Gaussian noise; redundant inputs are random convex combinations of the *noisy* relevant
inputs; irrelevant inputs are ``N(0, 1)``; ``10 + r + u = 100`` in the paper.

Use `make_problem` to draw one trial (training set, a noiseless test set and a noisy test set,
all from the same covariance and mixing weights); `experiments.fig2` runs the whole
protocol. SNR is signal variance over noise variance, as in the paper.

Choices the paper leaves open, made here and documented: the covariance of the relevant inputs
is ``A A^T / 10`` with ``A`` standard normal 10 x 10 (so inputs have unit-order variance and a
condition number in the tens to hundreds); noise variances are set from the population
variances (``Sigma_mm / snr_in``, ``b^T Sigma b / snr_out``); convex weights of the redundant
inputs are uniform on the simplex (Dirichlet(1)); training and test sets default to 1,000 rows
each (the paper does not state its sample sizes). In the noiseless test set the relevant inputs
carry no noise, the redundant inputs are the same convex combinations of the noiseless relevant
inputs, irrelevant inputs are still drawn ``N(0, 1)``, and the output has no noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

__all__ = ["SyntheticProblem", "make_problem"]


@dataclass(frozen=True)
class SyntheticProblem:
    """One trial of the Fig. 2 protocol. Shapes: ``n`` rows, ``d = 10 + r + u`` inputs.

    Attributes:
        X_train, y_train: noisy training data, ``(n_train, d)`` and ``(n_train,)``.
        X_test_clean, y_test_clean: noiseless test data (inputs and output).
        X_test_noisy, y_test_noisy: test data with the training noise.
        X_train_repeat: a second measurement of the training inputs: the same noiseless inputs
            (and the same irrelevant inputs) with independent noise, as a robot gives when it
            repeats a period of its excitation. ``(X_train - X_train_repeat).var(0) / 2``
            estimates each column's noise variance from the data alone.
        coef_true: ``(d,)``, ``b`` on the relevant inputs and 0 elsewhere: the regression vector
            that maps noiseless inputs to the noiseless output.
        input_noise: ``(d,)`` the noise variance each training column actually carries
            (relevant: ``Sigma_mm / snr_in``; redundant: ``sum_k c_k^2 Sigma_kk / snr_in``, the
            noise it inherits from the columns it mixes; irrelevant: 0, they are exact).
        output_noise: the output noise variance.
        relevant, redundant, irrelevant: column indices of each kind, ``(10,)``, ``(r,)``, ``(u,)``.
    """

    X_train: torch.Tensor
    y_train: torch.Tensor
    X_test_clean: torch.Tensor
    y_test_clean: torch.Tensor
    X_test_noisy: torch.Tensor
    y_test_noisy: torch.Tensor
    X_train_repeat: torch.Tensor
    coef_true: torch.Tensor
    input_noise: torch.Tensor
    output_noise: float
    relevant: torch.Tensor
    redundant: torch.Tensor
    irrelevant: torch.Tensor


def make_problem(
    n_redundant: int,
    n_irrelevant: int,
    *,
    input_snr: float = 2.0,
    output_snr: float = 5.0,
    n_relevant: int = 10,
    n_train: int = 1000,
    n_test: int = 1000,
    seed: int | None = None,
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float64,
) -> SyntheticProblem:
    """Draw one trial of the paper's synthetic experiment.

    Args:
        n_redundant: r, the number of redundant inputs (convex combinations of noisy relevant ones).
        n_irrelevant: u, the number of irrelevant ``N(0, 1)`` inputs.
        input_snr: variance of each relevant input over the variance of its noise (2 or 5).
        output_snr: variance of ``b^T t`` over the output noise variance (5 in the paper).
        n_relevant: number of relevant inputs (10); ``b = [1, ..., n_relevant]``.
        n_train, n_test: rows of the training set and of each test set.
        seed: seed of a new generator (ignored when ``generator`` is given).
        generator: a ``torch.Generator`` to draw from.
        dtype: floating dtype of the returned tensors.

    Returns:
        A `SyntheticProblem`.
    """
    for name, value in (("n_redundant", n_redundant), ("n_irrelevant", n_irrelevant)):
        if int(value) != value or value < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {value}")
    if n_relevant < 1:
        raise ValueError(f"n_relevant must be at least 1, got {n_relevant}")
    if not (input_snr > 0 and output_snr > 0):
        raise ValueError(f"SNRs must be positive, got input {input_snr}, output {output_snr}")
    if n_train < 2 or n_test < 1:
        raise ValueError(f"need n_train >= 2 and n_test >= 1, got {n_train} and {n_test}")
    if generator is None:
        generator = torch.Generator()
        generator.manual_seed(torch.seed() if seed is None else int(seed))
    g, kw = generator, {"dtype": torch.float64}
    k, r, u = n_relevant, int(n_redundant), int(n_irrelevant)

    a = torch.randn(k, k, generator=g, **kw)
    cov = a @ a.T / k
    chol = torch.linalg.cholesky(cov + 1e-12 * torch.eye(k, **kw))
    b = torch.arange(1, k + 1, **kw)
    noise_in = torch.diagonal(cov) / input_snr  # (k,)
    noise_out = float(b @ cov @ b) / output_snr
    # convex weights: normalised exponentials are uniform on the simplex (Dirichlet(1))
    mix = -torch.log(torch.rand(r, k, generator=g, **kw))
    mix = mix / mix.sum(1, keepdim=True)  # (r, k)

    def observe(t: torch.Tensor, x_irr: torch.Tensor, noisy: bool) -> torch.Tensor:
        x_rel = t + torch.randn(t.shape, generator=g, **kw) * noise_in.sqrt() if noisy else t
        return torch.cat([x_rel, x_rel @ mix.T, x_irr], 1).to(dtype)

    def draw(n: int, noisy: bool, repeat: bool = False):
        t = torch.randn(n, k, generator=g, **kw) @ chol.T
        x_irr = torch.randn(n, u, generator=g, **kw)
        y = t @ b
        if noisy:
            y = y + torch.randn(n, generator=g, **kw) * noise_out**0.5
        X = observe(t, x_irr, noisy)
        X_repeat = observe(t, x_irr, noisy) if repeat else None
        return X, y.to(dtype), X_repeat

    X_train, y_train, X_repeat = draw(n_train, noisy=True, repeat=True)
    X_clean, y_clean, _ = draw(n_test, noisy=False)
    X_noisy, y_noisy, _ = draw(n_test, noisy=True)
    coef = torch.cat([b, torch.zeros(r + u, **kw)]).to(dtype)
    input_noise = torch.cat([noise_in, (mix**2) @ noise_in, torch.zeros(u, **kw)]).to(dtype)
    idx = torch.arange(k + r + u)
    return SyntheticProblem(
        X_train,
        y_train,
        X_clean,
        y_clean,
        X_noisy,
        y_noisy,
        X_repeat,
        coef,
        input_noise,
        noise_out,
        idx[:k],
        idx[k : k + r],
        idx[k + r :],
    )

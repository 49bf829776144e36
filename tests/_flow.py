"""The identification stages on prepared logs in one call, for the tests: `fit`, then
`make_consistent` unless ``project=False``, with the joint weights and the input noise given
(`NoiseChoice.given`), no bias correction, and the defaults these tests were written for
(Bayesian JFA, the virtual parametrisation, no jackknife, no description prior)."""

from torchjfa.estimators import BayesianJFA
from torchjfa.identification import Compute, NoiseChoice, Options, fit, make_consistent
from torchjfa.identification._noise import noise_vector


def fit_logs(
    model,
    logs,
    *,
    estimator=None,
    project=True,
    parametrization="virtual",
    input_noise=None,
    projection_options=None,
    jackknife=0,
    joint_weights=None,
    description_prior=None,
    **compute,
):
    """The `IdentificationResult` of the stages on ``logs`` (see the module)."""
    noise = None if input_noise is None else noise_vector(input_noise, model.n_params)
    if estimator is None:
        estimator = BayesianJFA(input_noise=noise, fit_intercept=False)
    options = Options(
        estimator=estimator,
        weighting="none",
        jackknife=jackknife,
        bias_correction=0,
        project=project,
        parametrization=parametrization,
        description_prior=description_prior,
        projection_options=dict(projection_options or {}),
        compute=Compute(**compute),
    )
    result = fit(model, logs, NoiseChoice.given(joint_weights, noise), options)
    return make_consistent(result, options) if project else result

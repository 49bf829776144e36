"""`signal_bootstrap` (refits on re-drawn sensor noise through the preparation) and
`torchjfa.data.redrawn_logs` behind it."""

from dataclasses import replace

import pytest
import torch

from torchjfa.data import prepare, redrawn_logs, signal_noise
from torchjfa.identification import (
    IdentificationError,
    Options,
    choose_noise,
    fit,
    load_model,
    prepare_data,
    read,
    signal_bootstrap,
)
from torchjfa.physical import base_parameters
from torchjfa.sim import generate_log

OPTIONS = Options(cutoff=20.0, period=None, project=False, jackknife=0, bias_correction=0)


@pytest.fixture(scope="module")
def head():
    model = load_model("head", ("viscous",))
    log = generate_log("head", n_samples=1200, unmodeled=False, seed=3)
    data = prepare_data(model, read(log, model, OPTIONS), OPTIONS)
    noise = choose_noise(model, data, OPTIONS)
    return model, data, noise


def _scaled(sig, factor):
    return replace(sig, variance={k: v * factor for k, v in sig.variance.items()})


def test_redrawn_logs_keep_the_rows_and_without_noise_are_the_log(head):
    _, data, _ = head
    prep = data.preparation
    base = prepare(data.raw, **prep)
    zero = _scaled(signal_noise(data.raw), 0.0)
    logs = redrawn_logs(data.raw, prep, noise=zero, n_draws=2)
    assert len(logs) == 2 and all(x.n_samples == base.n_samples for x in logs)
    assert torch.equal(logs[0].qdd, base.qdd) and torch.equal(logs[1].tau, base.tau)
    noisy = redrawn_logs(data.raw, prep, n_draws=2, seed=1)
    assert not torch.equal(noisy[0].qdd, noisy[1].qdd)
    with pytest.raises(ValueError, match="n_draws"):
        redrawn_logs(data.raw, prep, n_draws=0)


def test_signal_bootstrap_spread_is_zero_without_noise_and_scales_with_it(head):
    model, data, noise = head
    sig = signal_noise(data.raw)
    est = fit(model, data, noise, OPTIONS).theta_hat
    coefs, std = signal_bootstrap(model, data, noise, OPTIONS, n_draws=3, signal=_scaled(sig, 0))
    assert coefs.shape == (3, model.n_params) and std.shape == (model.n_params,)
    # no added noise: every refit is the estimate itself
    torch.testing.assert_close(coefs, est.expand(3, -1), rtol=1e-10, atol=1e-12)
    # the same draws at twice the noise std: to first order twice the spread of the base
    # parameters (the refit is smooth in the noise; the single parameters are not determined,
    # and the min-norm solve moves them along rounding-level directions whatever the noise).
    # At a tenth of the log's noise std the second-order part is a tenth of what it is at the
    # log's own (tens of per cent: the differentiated acceleration's noise is not small), and
    # 6 draws of 50 combinations give the median ratio to a few per cent: within 10 %.
    base = base_parameters(fit(model, data, noise, OPTIONS).moments, model)
    small = _scaled(sig, 0.01)

    def spread(signal):
        coefs = signal_bootstrap(model, data, noise, OPTIONS, n_draws=6, seed=2, signal=signal)[0]
        return base.values(coefs).std(dim=0)

    ratio = (spread(_scaled(small, 4)) / spread(small)).median()
    assert 1.8 < float(ratio) < 2.2, ratio
    with pytest.raises(IdentificationError, match="at least 2 draws"):
        signal_bootstrap(model, data, noise, OPTIONS, n_draws=1)


def test_signal_bootstrap_refits_with_the_coulomb_term_the_preparation_chose():
    # the loaded model has sign(qd); the preparation's smoothing velocity is what `fit` used,
    # so without added noise every refit is `fit`'s estimate only if the refits use it too
    options = replace(OPTIONS, coulomb_velocity=0.05)
    model = load_model("head", ("viscous", "coulomb"))
    log = generate_log("head", n_samples=1200, seed=4)
    data = prepare_data(model, read(log, model, options), options)
    assert data.coulomb_velocity == 0.05 and model.coulomb_velocity == 0.0
    noise = choose_noise(model, data, options)
    est = fit(model, data, noise, options).theta_hat
    zero = _scaled(signal_noise(data.raw), 0.0)
    coefs, _ = signal_bootstrap(model, data, noise, options, n_draws=2, signal=zero)
    torch.testing.assert_close(coefs, est.expand(2, -1), rtol=1e-10, atol=1e-12)

"""The regression's input and output noise of any log: sensor noise pushed through the flow.

`torchjfa.data.regressor_noise` measures the noise of each regressor column from the spread
between repeated excitation periods; a log without two periods has none. `propagated_noise`
gets the same quantities from the sensor noise alone (`torchjfa.data.signal_noise`, from the
spectrum) by Monte Carlo through exactly what the flow does to the log: white noise of the
estimated variances is added to the raw ``q``, ``qd`` and ``tau``, the noisy log is prepared
with the same keywords of `torchjfa.data.prepare` (resampling, the zero-phase filter, the
derivatives, trimming, decimation; a detected period and start-up transient are held at what
the noiseless log gave, so that the rows line up), and the regressor of each draw is compared
with that of the log prepared without the added noise. The mean square of the difference,
averaged over the rows as `regressor_noise` averages (every sample and joint, each joint's
rows weighted by its joint weight), is the per-column input noise.

The added noise rides on the log's own noise, so the difference is that of a second noise
draw: to first order in the noise (the regressor is smooth in q, qd, qdd) it has the log's
input-noise covariance.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, replace

import torch

from .._validation import check_joint_weights
from ..stats import CHUNK_SIZE
from ._differentiate import DEFAULT_CUTOFF_HZ, edge_seconds
from ._joints import permutation
from ._log import JointLog
from ._prepare import prepare
from ._schema import LogError
from ._spectrum import SignalNoise, signal_noise

__all__ = ["PropagatedNoise", "propagated_noise", "redrawn_logs"]


@dataclass(frozen=True)
class PropagatedNoise:
    """Noise variances of the prepared regression, by Monte Carlo (float64, the model's order).

    The fields it shares with `torchjfa.data.PeriodNoise` (``input_noise``, ``output_noise``,
    ``output_noise_per_joint``, ``column_power``) mean the same, so either can be given to the
    estimators and the projection.

    Attributes:
        input_noise: ``(n_params,)`` per-column variance of the (weighted) regressor rows,
            averaged over every sample and joint of the rows used.
        input_noise_error: ``(n_params,)`` its Monte Carlo standard error (the spread of the
            draws' values over ``sqrt(n_draws)``).
        output_noise: 0-d, the prepared torque's noise variance averaged over joints, N^2 m^2.
        output_noise_per_joint: ``(n_dof,)`` the same per joint.
        column_power: ``(n_params,)`` mean square of each (weighted) column over the same rows.
        signal_noise: the `torchjfa.data.SignalNoise` that was propagated (the log's order).
        n_draws: Monte Carlo draws.
        n_rows: rows (samples x joints) averaged over.
    """

    input_noise: torch.Tensor
    input_noise_error: torch.Tensor
    output_noise: torch.Tensor
    output_noise_per_joint: torch.Tensor
    column_power: torch.Tensor
    signal_noise: SignalNoise
    n_draws: int
    n_rows: int

    def describe(self) -> str:
        """One line on how the estimate was made and its Monte Carlo error."""
        live = self.input_noise > 1e-12 * float(self.input_noise.max())
        rel = (self.input_noise_error[live] / self.input_noise[live]).median()
        return (
            f"propagated by Monte Carlo ({self.n_draws} draws through the preparation, the "
            f"regressor and the joint weights; median error {float(rel):.1%} of a column's "
            f"noise) from {self.signal_noise.describe()}"
        )


def propagated_noise(
    model,
    raw_log: JointLog,
    preparation: dict | None = None,
    *,
    joint_weights=None,
    noise: SignalNoise | None = None,
    samples: int | None = None,
    n_draws: int = 8,
    seed: int = 0,
    chunk_size: int = CHUNK_SIZE,
    compiled: bool | None = None,
) -> PropagatedNoise:
    """The input noise of every regressor column and the torque noise, for any log.

    Args:
        model: a `torchjfa.dynamics.RigidBodyModel` of the robot (the log's columns are
            matched to its joints by name).
        raw_log: the log as recorded (before `torchjfa.data.prepare`), with ``q``, ``tau``
            and, where measured, ``qd``.
        preparation: the keywords of `torchjfa.data.prepare` the flow uses (default its
            defaults; `torchjfa.identification.PreparedData.preparation`).
        joint_weights: ``(n_dof,)`` weights of each joint's equations (model order) when the
            regression is weighted: the noise is then that of the weighted rows.
        noise: the raw signals' white noise, in ``raw_log``'s joint order (default
            `signal_noise` of ``raw_log``).
        samples: use the first this many prepared samples (the training part of a log whose
            tail is held out), default all.
        n_draws: Monte Carlo draws (at least 2, for the error).
        seed: seeds the draws (a `torch.Generator`).
        chunk_size: samples per regressor chunk: memory ``O(chunk_size * n_dof * n_params)``
            for the regressors, besides the ``n_draws`` prepared copies of the log's signals.
        compiled: the regressor's path (`RigidBodyModel.regressor`).

    Returns:
        A `PropagatedNoise`.

    Raises:
        ValueError: on other joints than the model's, ``n_draws < 2`` or ``samples`` out of
            range.
        LogError: from `prepare` or `signal_noise`.
    """
    perm = permutation(raw_log.joint_names, model.joint_names, want_name="the model")
    if isinstance(n_draws, bool) or not isinstance(n_draws, int) or n_draws < 2:
        raise ValueError(f"n_draws must be an int of at least 2, got {n_draws!r}")
    preparation = dict(preparation or {})
    base = prepare(raw_log, **preparation)
    rows = base.n_samples if samples is None else int(samples)
    if not 1 <= rows <= base.n_samples:
        raise ValueError(f"samples must lie in [1, {base.n_samples}], got {samples}")
    fixed = _fixed(preparation, base.info)
    noise = signal_noise(raw_log) if noise is None else noise
    n_dof = len(perm)
    w = None if joint_weights is None else check_joint_weights(joint_weights, n_dof)
    scale = None if w is None else w.sqrt()[:, None]  # (n_dof, 1) on (n_dof, n_params)
    g = torch.Generator().manual_seed(int(seed))

    def state(log):
        return tuple(v[:rows, perm].to(torch.float64) for v in (log.q, log.qd, log.qdd, log.tau))

    q0, qd0, qdd0, tau0 = state(base)
    # the draws' prepared states: n_draws x 4 x (rows, n_dof)
    noisy = [state(log) for log in _redrawn(raw_log, fixed, noise, n_draws, g, base.n_samples)]
    tau_var = torch.stack([(x[3] - tau0).pow(2).mean(dim=0) for x in noisy]).mean(dim=0)
    draws = torch.zeros(n_draws, model.n_params, dtype=torch.float64)
    power = torch.zeros(model.n_params, dtype=torch.float64)
    for s in range(0, rows, int(chunk_size)):
        c = slice(s, min(rows, s + int(chunk_size)))
        Y0 = model.regressor(q0[c], qd0[c], qdd0[c], compiled=compiled)  # (b, n_dof, n_params)
        if scale is not None:
            Y0 = Y0 * scale
        power += torch.einsum("bjp,bjp->p", Y0, Y0)
        for d, (q, qd, qdd, _) in enumerate(noisy):
            dY = model.regressor(q[c], qd[c], qdd[c], compiled=compiled)
            if scale is not None:
                dY.mul_(scale)
            dY.sub_(Y0)
            draws[d] += torch.einsum("bjp,bjp->p", dY, dY)
    n_rows = rows * n_dof
    draws /= n_rows
    return PropagatedNoise(
        input_noise=draws.mean(dim=0),
        input_noise_error=draws.std(dim=0, correction=1) / math.sqrt(n_draws),
        output_noise=tau_var.mean(),
        output_noise_per_joint=tau_var,
        column_power=power / n_rows,
        signal_noise=noise,
        n_draws=n_draws,
        n_rows=n_rows,
    )


def redrawn_logs(
    raw_log: JointLog,
    preparation: dict | None = None,
    *,
    noise: SignalNoise | None = None,
    n_draws: int = 20,
    seed: int = 0,
    lazy: bool = False,
) -> list[JointLog] | Iterator[JointLog]:
    """``n_draws`` copies of the raw log, each with a fresh draw of white sensor noise of the
    estimated variances added to its q, qd and tau, prepared as the log itself is.

    The preparation (`torchjfa.data.prepare` with ``preparation``) holds what it chose from
    the data (a detected period, the start-up transient) at the noiseless log's choice, so every
    draw has the log's prepared rows. The added noise rides on the log's own: to first order in
    the noise, the difference between a draw's prepared signals and the log's is a second draw
    of the log's noise through the preparation (the parametric bootstrap of
    `torchjfa.identification.signal_bootstrap`, the Monte Carlo of `propagated_noise`).

    Args:
        raw_log: the log as recorded (before `prepare`).
        preparation: the keywords of `prepare` (default its defaults).
        noise: the raw signals' white noise (default `signal_noise` of ``raw_log``).
        n_draws: how many copies, at least 1.
        seed: seeds the draws.
        lazy: return an iterator that prepares one copy at a time (memory of one log, not
            ``n_draws``); the log's own preparation and its noise estimate run before it
            returns, so their errors are raised here.

    Returns:
        ``n_draws`` prepared `JointLog` s (a list, or an iterator when ``lazy``), each with
        the samples of ``prepare(raw_log, **preparation)``.

    Raises:
        ValueError: on ``n_draws < 1``.
        LogError: from `prepare` or `signal_noise`, or when a draw prepares to other rows.
    """
    if isinstance(n_draws, bool) or not isinstance(n_draws, int) or n_draws < 1:
        raise ValueError(f"n_draws must be a positive int, got {n_draws!r}")
    preparation = dict(preparation or {})
    base = prepare(raw_log, **preparation)
    noise = signal_noise(raw_log) if noise is None else noise
    g = torch.Generator().manual_seed(int(seed))
    fixed = _fixed(preparation, base.info)
    draws = _redrawn(raw_log, fixed, noise, n_draws, g, base.n_samples)
    return draws if lazy else list(draws)


def _redrawn(raw_log: JointLog, fixed: dict, noise: SignalNoise, n_draws: int, g, n_samples: int):
    """The noisy copies of `redrawn_logs`, prepared with the fixed keywords ``fixed``."""
    for _ in range(n_draws):
        log = prepare(_perturbed(raw_log, noise, g), **fixed)
        if log.n_samples != n_samples:
            raise LogError(
                f"{raw_log.source}: the noisy log prepared to {log.n_samples} samples, the "
                f"log itself to {n_samples}; the preparation depends on the noise"
            )
        yield log


def _fixed(preparation: dict, info: dict) -> dict:
    """The keywords of `prepare` with what it chose from the data (the period, the start-up
    transient) held at the noiseless log's choice, so that every draw gives the same rows."""
    fixed = dict(preparation)
    fixed["period_s"] = info["period_s"]
    if fixed.get("skip_start_s") == "auto":
        rate = info["rate_hz"] * fixed.get("decimate", 1)  # the rate before decimation
        cutoff = fixed.get("cutoff_hz")
        edge_s = fixed.get("edge_s")
        if edge_s is None:
            edge_s = edge_seconds(DEFAULT_CUTOFF_HZ if cutoff is None else cutoff)
        edge = math.ceil(edge_s * rate)
        skip = round(info["dropped_start_s"] * rate) - edge
        # prepare drops ceil(skip_s * rate) samples: half a sample short of `skip` gives it
        fixed["skip_start_s"] = max(skip - 0.5, 0.0) / rate
    return fixed


def _perturbed(log: JointLog, noise: SignalNoise, g: torch.Generator) -> JointLog:
    """``log`` with white Gaussian noise of ``noise``'s variances added to its q, qd, tau."""
    out = {}
    for name, var in noise.variance.items():
        x = getattr(log, name)
        if x is None:
            continue
        std = var.to(x).sqrt()
        out[name] = x + torch.randn(x.shape, generator=g, dtype=x.dtype) * std
    return replace(log, **out)

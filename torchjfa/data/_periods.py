"""Input and output noise of the regression, estimated from the repeated excitation periods.

With a periodic excitation the robot's true motion repeats every period, so at a fixed phase
the measured (and differentiated) signals differ between periods only by noise. The variance
across periods of each regressor entry, averaged over phase and joints, estimates the
per-column input-noise variance ``psi_x`` of the stacked regression (one row per sample and
joint, as `RigidBodyModel.moments` stacks them); the variance across periods of the measured
torque estimates the output noise ``psi_y``. Pass ``input_noise`` to `BayesianJFA` or to the
projection's metric ``X^T X + N diag(input_noise)``.

The estimate is unbiased when the true motion is exactly periodic (the default controller of
`torchjfa.sim.generate_log` sees the true state; a real robot repeating its excitation comes
close) and the noise is independent between periods. Noise is allowed to be correlated within
a period (the differentiation filter makes it so). A real log needs whole-sample periods that
start at its first sample: `torchjfa.data.prepare` resamples and trims it so.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .._util import progress_bar
from .._validation import check_joint_weights
from ._joints import permutation
from ._log import JointLog

__all__ = ["PeriodNoise", "regressor_noise"]


@dataclass(frozen=True)
class PeriodNoise:
    """Noise variances estimated from repeated periods (float64, the model's joint order).

    Attributes:
        input_noise: ``(n_params,)`` per-column variance of the regressor rows, averaged over
            phase and over the rows of every joint (rows where a column is structurally zero
            count, as they do in the stacked regression).
        output_noise: 0-d, the torque noise variance averaged over joints, N^2 m^2.
        output_noise_per_joint: ``(n_dof,)`` torque noise variance per joint.
        signal_noise: per joint ``(n_dof,)`` variance of ``"q"``, ``"qd"``, ``"qdd"``.
        n_periods: whole periods used.
        period_samples: samples per period.
        column_power: ``(n_params,)`` mean square of each regressor column over the same rows
            (weighted as ``input_noise``): the noise of a column is only meaningful below it.
    """

    input_noise: torch.Tensor
    output_noise: torch.Tensor
    output_noise_per_joint: torch.Tensor
    signal_noise: dict[str, torch.Tensor]
    n_periods: int
    period_samples: int
    column_power: torch.Tensor | None = None


def regressor_noise(
    model,
    log: JointLog,
    *,
    max_periods: int | None = None,
    progress: bool = False,
    joint_weights=None,
) -> PeriodNoise:
    """Estimate the regressor's per-column input noise and the torque noise of a log.

    Args:
        model: a `torchjfa.dynamics.RigidBodyModel` of the logged robot (its ``regressor``
            and ``joint_names`` are used; the log's columns are matched by joint name).
        log: a `JointLog` with ``qd``, ``qdd`` and ``period_samples`` (a prepared real log,
            or a `torchjfa.sim.SimulatedLog`; any object with ``q, qd, qdd, tau``
            ``(n, n_dof)``, ``joint_names`` and ``period_samples`` will do) whose first sample
            starts a period.
        max_periods: use at most this many whole periods (default all).
        progress: show a progress bar over the periods.
        joint_weights: ``(n_dof,)`` weights of each joint's equations (model order) when the
            regression is weighted (``NoiseChoice.joint_weights`` of
            `torchjfa.identification`): the input noise is then that of the weighted rows.

    Returns:
        A `PeriodNoise`; the unbiased variance across periods (divisor ``n_periods - 1``).

    Raises:
        ValueError: if the log has fewer than two whole periods or other joints than the model.
    """
    perm = permutation(log.joint_names, model.joint_names, want_name="the model")
    if log.qd is None or log.qdd is None:
        raise ValueError(
            "the log has no velocities or accelerations; prepare it first "
            "(torchjfa.data.prepare differentiates the positions)"
        )
    if log.period_samples is None:
        raise ValueError(
            "the log has no period_samples; the noise is estimated from the spread between "
            "periods (prepare a periodic log with torchjfa.data.prepare)"
        )
    P = int(log.period_samples)
    n_per = log.q.shape[0] // P
    if max_periods is not None:
        if max_periods < 2:
            raise ValueError(f"max_periods must be at least 2, got {max_periods}")
        n_per = min(n_per, int(max_periods))
    if n_per < 2:
        raise ValueError(
            f"the log has {log.q.shape[0]} samples, fewer than two periods of {P}; the noise "
            "is estimated from the spread between periods"
        )
    n_dof = len(perm)

    def periods(x):
        x = torch.as_tensor(x, dtype=torch.float64)[: n_per * P, perm]
        return x.reshape(n_per, P, n_dof)

    q, qd, qdd, tau = (periods(v) for v in (log.q, log.qd, log.qdd, log.tau))
    # Welford over periods: mean and sum of squared deviations of each (phase, joint, column)
    mean = M2 = None
    with progress_bar(total=n_per, desc="period noise", enabled=progress, unit="period") as bar:
        for k in range(n_per):
            Y = model.regressor(q[k], qd[k], qdd[k])  # (P, n_dof, n_params)
            if mean is None:
                mean = Y.clone()
                M2 = torch.zeros_like(Y)
            else:
                delta = Y - mean
                mean += delta / (k + 1)
                M2 += delta * (Y - mean)
            bar.update(1)
    var = M2 / (n_per - 1)  # (P, n_dof, n_params)
    if joint_weights is not None:
        w = check_joint_weights(joint_weights, n_dof)
        var = var * w[None, :, None]
        mean = mean * w.sqrt()[None, :, None]
    input_noise = var.mean(dim=(0, 1))
    # mean square over every row of the periods: mean^2 + (biased) variance at each phase
    power = (mean * mean + var * ((n_per - 1) / n_per)).mean(dim=(0, 1))
    tau_var = tau.var(dim=0, correction=1).mean(dim=0)
    signal = {
        name: v.var(dim=0, correction=1).mean(dim=0)
        for name, v in (("q", q), ("qd", qd), ("qdd", qdd))
    }
    return PeriodNoise(
        input_noise=input_noise,
        output_noise=tau_var.mean(),
        output_noise_per_joint=tau_var,
        signal_noise=signal,
        n_periods=n_per,
        period_samples=P,
        column_power=power,
    )

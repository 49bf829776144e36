"""The input noise of a floating-base robot's regression: the sensors' noise pushed through the
flow, for the estimators that model noise in the inputs (Bayesian JFA, JFA).

A floating base's velocity and acceleration come from its pose (a state estimator, motion
capture) or an IMU, far noisier than the joint encoders, and every row of the regression
carries them: errors in the variables. As for a fixed base (`torchjfa.data.propagated_noise`),
the noise of each regressor column is found by Monte Carlo through exactly what the flow does:

1. each raw signal's white-noise variance is read from its spectrum's floor
   (`torchjfa.data.floor_variance`): the base position, the quaternion's components (its sign
   made continuous), the joint positions, the logged velocities and the IMU's readings;
2. each of ``n_draws`` copies of the log gets fresh white noise of those variances (the
   quaternion normalised again), is prepared at the flow's cut-off, and its rows
   (`contact_equations`: the contact projector moves with the noisy pose too) are compared
   with those of the log prepared without it, over at most ``max_samples`` training samples;
3. the mean square of the difference over the samples and rows, each row in the fit's weight,
   is the column's noise variance, in the units of the weighted moments.

The added noise rides on the log's own, so the difference is that of a second draw of the
log's noise (to first order). The torques' and wrenches' noise is the output's, which the
estimators learn.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from ..data import LeggedLog, LogError, floor_variance
from ..data._legged import continuous_quaternion
from ..data._spectrum import NO_FLOOR
from ._contacts import contact_equations
from ._noise import cap_period_noise, noise_vector
from ._options import IdentificationError, Options

__all__ = ["LeggedNoise", "legged_input_noise", "legged_signal_noise", "propagated_legged_noise"]

#: each perturbed raw signal: its name in the report, and its unit
_SIGNALS = {
    "base_position": "m",
    "base_quaternion": "",
    "joint_position": "rad",
    "velocity": "m/s, rad/s",
    "gyro": "rad/s",
    "accelerometer": "m/s^2",
}
#: the IMU's signals (`torchjfa.data.LeggedLog.imu` keys) by their names in `_SIGNALS`
_IMU_SIGNALS = {"w": "gyro", "a": "accelerometer"}
#: Welch segment of the noise spectra, samples (fewer where the log is short)
_SEGMENT = 256


@dataclass(frozen=True)
class LeggedNoise:
    """The input noise of a legged robot's weighted regression rows, by Monte Carlo (float64,
    the model's parameter order). ``input_noise`` and ``column_power`` mean what they mean in
    `torchjfa.data.PropagatedNoise`, so `cap_period_noise` and the estimators take it.

    Attributes:
        input_noise: ``(n_params,)`` each column's noise variance over the weighted rows.
        input_noise_error: ``(n_params,)`` its Monte Carlo standard error.
        column_power: ``(n_params,)`` each column's mean square over the same rows.
        stds: each perturbed raw signal (`legged_signal_noise`) -> its white-noise standard
            deviations, per column of the signal (of the first log; each log's own are used).
        n_draws: Monte Carlo draws.
        n_samples: samples the rows were compared over.
    """

    input_noise: torch.Tensor
    input_noise_error: torch.Tensor
    column_power: torch.Tensor
    stds: dict[str, np.ndarray]
    n_draws: int
    n_samples: int

    def describe(self) -> str:
        """One line: the raw noise that was propagated, and the Monte Carlo's error."""
        live = self.input_noise > 1e-12 * float(self.input_noise.max())
        rel = float((self.input_noise_error[live] / self.input_noise[live]).median())
        raw = ", ".join(
            f"{name.replace('_', ' ')} {float(np.sqrt(np.mean(s**2))):.3g}"
            + (f" {_SIGNALS[name]}" if _SIGNALS[name] else "")
            for name, s in self.stds.items()
        )
        return (
            f"propagated by Monte Carlo ({self.n_draws} draws through the preparation and the "
            f"weighted rows over {self.n_samples} samples; median error {rel:.1%} of a "
            f"column's noise) from the white noise of the spectra's floors: {raw}"
        )


def _signals(log: LeggedLog) -> dict[str, np.ndarray]:
    """The raw signals whose noise is propagated, as ``(T, k)`` arrays."""
    out = {
        "base_position": log.q[:, :3],
        "base_quaternion": continuous_quaternion(log.q[:, 3:7]),
        "joint_position": log.q[:, 7:],
    }
    if log.v is not None:
        out["velocity"] = log.v
    out.update({_IMU_SIGNALS[k]: x for k, x in log.imu.items()})
    return out


def legged_signal_noise(log: LeggedLog) -> dict[str, np.ndarray]:
    """Each raw signal's white-noise standard deviation, per column, from its spectrum's
    floor (`torchjfa.data.floor_variance`): ``"base_position"`` (m), ``"base_quaternion"``,
    ``"joint_position"`` (rad), ``"velocity"`` (where logged), ``"gyro"`` (rad/s) and
    ``"accelerometer"`` (m/s^2, where the log has an IMU).

    Raises:
        LogError: on a log too short for a spectrum, or a signal whose spectrum does not
            flatten below the Nyquist frequency.
    """
    n = len(log.t)
    if n < 64:
        raise LogError(f"{log.info.get('source', 'the log')}: {n} samples are too few for a "
                       "noise spectrum")  # fmt: skip
    fs = 1.0 / float(np.median(np.diff(log.t)))
    segment = min(_SEGMENT, 1 << int(math.floor(math.log2(n / 8))))
    out = {}
    for name, x in _signals(log).items():
        var, _ = floor_variance(x, fs, segment)
        if np.isnan(var).any():
            column = int(np.flatnonzero(np.isnan(var))[0])
            raise LogError(
                f"{log.info.get('source', 'the log')}: the spectrum of the "
                f"{name.replace('_', ' ')} (column {column}) {NO_FLOOR.format(nyquist=fs / 2)}"
            )
        out[name] = np.sqrt(var)
    return out


def _perturbed(log: LeggedLog, stds: dict[str, np.ndarray], rng) -> LeggedLog:
    """``log`` with white Gaussian noise of ``stds`` on the signals of `_signals`."""

    def noise(name, shape):
        return rng.standard_normal(shape) * stds[name]

    q = log.q.copy()
    T = len(log.t)
    q[:, :3] += noise("base_position", (T, 3))
    quat = continuous_quaternion(q[:, 3:7]) + noise("base_quaternion", (T, 4))
    q[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    q[:, 7:] += noise("joint_position", q[:, 7:].shape)
    v = None if log.v is None else log.v + noise("velocity", log.v.shape)
    imu = {k: x + noise(_IMU_SIGNALS[k], x.shape) for k, x in log.imu.items()}
    return replace(log, q=q, v=v, imu=imu)


def _rows(model, log: LeggedLog, rows: str, flat, w_sqrt: torch.Tensor) -> torch.Tensor:
    """``(B, r, n_params)`` the weighted regression rows of a prepared log."""
    Y, _ = contact_equations(
        model, log.q, log.v, log.a, log.tau,
        contacts=log.contact or None, wrenches=log.wrench or None, flat=flat, rows=rows,
    )  # fmt: skip
    return Y * w_sqrt[:, None]


def propagated_legged_noise(
    model,
    spans: Sequence[tuple[LeggedLog, float, float]],
    prepare: Callable[[LeggedLog], LeggedLog],
    *,
    rows: str,
    flat: Sequence[str] = (),
    weights: torch.Tensor,
    n_draws: int = 8,
    max_samples: int = 2000,
    seed: int = 0,
) -> LeggedNoise:
    """The input noise of each column of the weighted rows (the module's Monte Carlo).

    Args:
        model: the `torchjfa.dynamics.FloatingBaseModel`.
        spans: ``(raw log, start, stop)``: each raw log (joints in the model's order) and the
            times, s, of its training samples.
        prepare: raw log -> prepared log (the flow's filter and cut-off).
        rows, flat: as `contact_equations`.
        weights: ``(r,)`` each row's weight in the fit.
        n_draws: Monte Carlo draws (at least 2).
        max_samples: the samples compared, spread evenly over the spans.
        seed: seeds the draws.

    Returns:
        A `LeggedNoise` whose variances are averaged as the weighted moments average (each
        row's squares times its weight, over the samples times the weights' sum).

    Raises:
        LogError: as `legged_signal_noise`.
        ValueError: on ``n_draws < 2``.
    """
    if isinstance(n_draws, bool) or not isinstance(n_draws, int) or n_draws < 2:
        raise ValueError(f"n_draws must be an int of at least 2, got {n_draws!r}")
    rng = np.random.default_rng(int(seed))
    w = torch.as_tensor(weights, dtype=torch.float64)
    w_sqrt = w.clamp_min(0.0).sqrt()
    total = sum(int(((r.t >= a) & (r.t <= b)).sum()) for r, a, b in spans)
    stride = max(1, math.ceil(total / max(int(max_samples), 1)))
    draws = torch.zeros(n_draws, model.n_params, dtype=torch.float64)
    power = torch.zeros(model.n_params, dtype=torch.float64)
    n, stds = 0, []
    for raw, start, stop in spans:
        stds.append(legged_signal_noise(raw))
        keep = np.flatnonzero((raw.t >= start) & (raw.t <= stop))[::stride]
        if keep.size == 0:
            continue
        Y0 = _rows(model, prepare(raw).select(keep), rows, flat, w_sqrt)
        power += torch.einsum("brp,brp->p", Y0, Y0)
        for d in range(n_draws):
            dY = _rows(
                model, prepare(_perturbed(raw, stds[-1], rng)).select(keep), rows, flat, w_sqrt
            )
            draws[d] += torch.einsum("brp,brp->p", dY - Y0, dY - Y0)
        n += keep.size
    norm = max(n, 1) * float(w.sum())
    draws /= norm
    return LeggedNoise(
        input_noise=draws.mean(0),
        input_noise_error=draws.std(0, correction=1) / math.sqrt(n_draws),
        column_power=power / norm,
        stds=stds[0],
        n_draws=n_draws,
        n_samples=n,
    )


def legged_input_noise(
    model, options: Options, estimator_takes_noise: bool, propagate: Callable[[], LeggedNoise]
) -> tuple[torch.Tensor | None, str, list[str]]:
    """``(input noise or None, how, warnings)`` of `Options.input_noise` for a floating base:
    ``"auto"`` propagates the sensors' noise (``propagate()``) where the estimator takes an
    input noise, else none; ``"learn"`` gives none; ``"propagated"`` insists on it;
    variances are given as they are; ``"periods"`` is refused (a legged log's excitation has
    no periods to compare).

    Raises:
        IdentificationError: on ``"periods"``, on ``"propagated"`` for an estimator that takes
            no input noise or a log whose noise cannot be read, on bad variances.
    """
    mode = options.input_noise
    if not isinstance(mode, str):
        return noise_vector(mode, model.n_params), "given", []
    if mode == "periods":
        raise IdentificationError(
            "--input-noise periods compares repeated excitation periods, which a floating-base "
            "log does not have: use --input-noise propagated (or learn)"
        )
    if mode == "learn" or (mode == "auto" and not estimator_takes_noise):
        return None, "none given (the estimator learns it, or models none)", []
    if not estimator_takes_noise:
        raise IdentificationError(
            "--input-noise propagated is for an estimator that models the inputs' noise "
            "(--estimator bayes-jfa or jfa)"
        )
    try:
        noise = propagate()
    except LogError as exc:
        if mode != "auto":
            raise IdentificationError(f"--input-noise propagated: {exc}") from None
        return None, "none given", [f"--input-noise auto: {exc}; no input noise is given"]
    noise, capped = cap_period_noise(model, noise, "the propagated sensor noise")
    return noise.input_noise, noise.describe(), capped

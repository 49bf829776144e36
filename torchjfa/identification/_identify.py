"""`identify`: a robot and its raw log in, an `Identification` out, through the stages of
`torchjfa.identification`."""

from __future__ import annotations

import os
import time
import warnings as _warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import torch

from .._util import progress_bar
from ..dynamics import RigidBodyModel
from ..report import IdentificationReport, TorqueFit, estimator_text, verdict
from ..report._result import IdentificationResult
from ._bias import correct_bias
from ._consistent import make_consistent
from ._fit import fit
from ._legged import LeggedIdentification, identify_legged, is_legged_log
from ._noise import NoiseChoice, choose_noise
from ._options import IdentificationWarning, Options
from ._prepare import PreparedData, prepare_data, several
from ._read import RawLog, load_model, read
from ._validate import validate

__all__ = ["Identification", "identify"]


@dataclass(eq=False)
class Identification:
    """What `identify` returns: every stage's output, the report, and the identified model.

    Attributes:
        model: the `RigidBodyModel`.
        raw: the `RawLog` s as read (joints in the model's order), one per log.
        data: the `PreparedData` (training and held-out parts).
        noise: the `NoiseChoice` (joint weights, input noise).
        result: the `torchjfa.identification.IdentificationResult` (theta, the
            unconstrained estimate, spreads, moments, projection).
        report: the `torchjfa.report.IdentificationReport` on the held-out data.
        options: the `Options` used.
        seconds: wall time of the fit (moments, estimator, bias correction, projection), s.
    """

    model: RigidBodyModel
    raw: list[RawLog]
    data: PreparedData
    noise: NoiseChoice
    result: IdentificationResult
    report: IdentificationReport
    options: Options
    seconds: float

    @property
    def theta(self) -> torch.Tensor:
        """``(n_params,)`` the identified (physically consistent) parameters."""
        return self.result.theta

    @property
    def validation_fit(self) -> TorqueFit:
        """How the identified model predicts the held-out torques."""
        return self.report.fits["identified"]

    @property
    def warnings(self) -> list[str]:
        """Everything the stages found that the user should know, in the flow's order."""
        return list(self.report.settings.get("warnings", []))

    @property
    def identified_well(self) -> bool:
        """Whether the model predicts the held-out torques better than their mean (nMSE < 1)."""
        return bool(self.validation_fit.mean_nmse < 1.0)  # NaN: False

    def problem(self) -> str | None:
        """Why the result must not be used (the held-out fit is worse than the mean), or None."""
        if self.identified_well:
            return None
        return (
            f"the identified model predicts the held-out torques worse than their mean (nMSE "
            f"{self.validation_fit.mean_nmse:.3g}): the logs do not identify "
            f"{self.report.settings.get('robot', 'the robot')} ({self.data.train.duration:.3g} s "
            "of training data); check the torque channels' signs and units (the warnings), "
            "or record a longer or richer excitation"
        )

    def inverse_dynamics(self, *, projected: bool = True, trainable: bool | str = False):
        """The identified model as an `InverseDynamics` ``nn.Module`` (see
        `torchjfa.identification.IdentificationResult.inverse_dynamics`)."""
        return self.result.inverse_dynamics(projected=projected, trainable=trainable)

    def write(
        self,
        out_dir: str | os.PathLike,
        *,
        plots: bool = True,
        appendix: bool = False,
        overwrite: bool = False,
        inputs: Iterable[str | os.PathLike] = (),
        command: str = "",
    ) -> dict[str, Path]:
        """Write the report's folder as one unit (`IdentificationReport.write`: ``appendix``,
        the long tables at the end of ``report.md``; ``overwrite``, ``inputs``, ``command``, the
        folder's manifest); returns the paths."""
        return self.report.write(
            out_dir,
            plots=plots,
            appendix=appendix,
            overwrite=overwrite,
            inputs=inputs,
            command=command,
        )

    def headline(self) -> list[str]:
        """Two lines: what was identified, and how it predicts the held-out torques."""
        fit, model = self.validation_fit, self.model
        per_joint = ", ".join(
            f"{j} {float(v):.3g}" for j, v in zip(model.joint_names, fit.nmse, strict=True)
        )
        return [
            f"identified {model.n_params} parameters of {self.report.settings.get('robot')} from "
            f"{self.data.train.n_samples} samples in {self.seconds:.1f} s; physically "
            f"consistent: {verdict(self.report.consistency)}",
            f"held-out torque nMSE {fit.mean_nmse:.4g} against the measured torque (per joint: "
            f"{per_joint})",
        ]


def identify(
    robot,
    logs,
    options: Options | None = None,
    *,
    validation_log=None,
    settings: Mapping[str, object] | None = None,
) -> Identification | LeggedIdentification:
    """Identify a robot from its raw log, with the whole real-log flow.

    `load_model` -> `read` (check the log) -> `prepare_data` (cut-off, filter, derivatives,
    held-out part) -> `choose_noise` (joint weights, input noise from repeated periods) -> `fit`
    (moments, estimator, jackknife) -> `correct_bias` (the sensor noise's bias, SIMEX) ->
    `make_consistent` (the projection onto physically consistent parameters) -> `validate`
    (the report on the held-out data). Each stage is public in `torchjfa.identification`, to
    run one by one (notebooks/real_robot.ipynb). The ``torchjfa identify`` command is this
    call.

    Args:
        robot: a URDF / MJCF path, a shipped or simulated robot's name, or a `RigidBodyModel`.
        logs: the raw log, or a list of them (one identification from all, each prepared on
            its own time base): CSV / NPZ / Parquet paths (columns ``t, q_<joint>,
            [qd_<joint>], tau_<joint>`` or motor currents ``i_<joint>`` with
            ``options.drive_gains``), ROS bags (``.bag``, ``.mcap``, ``.db3`` or a bag folder;
            `torchjfa.data.read_log`) or `torchjfa.data.JointLog` s.
        options: `Options` (default: the defaults, chosen for real robots).
        validation_log: raw logs (one or a list) to hold out instead of the end of each log.
        settings: more entries for the report's record (e.g. the command line).

    Returns:
        An `Identification`; ``.write(folder)`` writes the report. For a floating-base robot
        (``options.floating_base``, by default where the first log has base-pose columns) a
        `torchjfa.identification.LeggedIdentification` (`identify_legged`). Each of its
        ``warnings`` is also issued as an `IdentificationWarning`, and one more when the
        held-out fit is worse than the torques' mean (`Identification.problem`).

    Raises:
        IdentificationError: on options or data that cannot give an identification.
        torchjfa.data.LogError: on a log that cannot be read or identifies nothing.
    """
    options = Options() if options is None else options
    logs = several(logs)
    if options.floating_base or (options.floating_base is None and is_legged_log(logs[0])):
        return identify_legged(robot, logs, options, validation_log=validation_log,
                               settings=settings)  # fmt: skip
    held_logs = [] if validation_log is None else several(validation_log)
    with progress_bar(total=len(STAGES), desc="identify", enabled=options.compute.progress,
                      unit="stage") as bar:  # fmt: skip
        names = iter(enumerate(STAGES))

        def stage() -> None:  # the next of `STAGES`
            k, name = next(names)
            bar.update(1 if k else 0)
            bar.set_description_str(f"identify: {name}")

        stage()
        model = load_model(robot, options.friction, options.fixed_joints, options.transmission)
        raw = [read(log, model, options) for log in logs]
        held = [read(log, model, options) for log in held_logs] or None
        stage()
        data = prepare_data(model, raw, options, held)
        model = data.model_for(model)  # the Coulomb term as the preparation chose it
        stage()
        noise = choose_noise(model, data, options)
        started = time.perf_counter()
        stage()
        result = fit(model, data, noise, options)
        stage()
        result = correct_bias(result, data, noise, options)
        stage()
        if options.project:
            result = make_consistent(result, options)
        seconds = time.perf_counter() - started
        stage()
        record = _record(robot, logs, data, noise, result, options, seconds, settings)
        report = validate(result, data, noise, record)
    out = Identification(model, raw, data, noise, result, report, options, seconds)
    problem = out.problem()
    for line in out.warnings + ([problem] if problem else []):
        _warnings.warn(line, IdentificationWarning, stacklevel=2)
    return out


def _record(robot, logs, data, noise, result, options, seconds, settings) -> dict:
    """The report's record of how the identification ran."""
    return {
        "robot": _name(robot),
        "log": ", ".join(_name(log) for log in logs),
        "validation": data.split,
        "preparation": data.describe(),
        "cutoff": f"{data.cutoff_hz:g} Hz, {data.cutoff_how}",
        "coulomb_velocity": data.coulomb_velocity,
        **({"armature": data.joint_terms_how} if data.joint_terms_how else {}),
        "prepare": dict(data.preparation),
        "data": dict(data.info),
        "identify_seconds": seconds,
        "input_noise": noise.mode,
        "input_noise_how": noise.how,
        "estimator": estimator_text(result.estimator),
        "weighting": options.weighting,
        **dict(settings or {}),
        "bias_correction": _bias_text(result, options),
        "warnings": data.warnings + noise.warnings + result.warnings,
    }


#: the stages `identify` runs, as its progress bar names them
STAGES = (
    "reading the logs",
    "preparing (cut-off, filter, derivatives)",
    "choosing the noise",
    "fitting",
    "correcting the bias",
    "projecting onto consistent parameters",
    "validating",
)


def _name(thing) -> str:
    """How the report names a robot or a log given as a path, a name or an object."""
    if isinstance(thing, str | os.PathLike):
        return str(thing)
    return getattr(thing, "source", None) or getattr(thing, "name", None) or type(thing).__name__


def _bias_text(result: IdentificationResult, options: Options) -> str:
    """One line on the bias correction for the report's settings."""
    b, n = result.theta_hat_bias, options.bias_refits(result.estimator)
    if not n:
        why = "auto: least squares only" if options.bias_correction == "auto" else "0"
        return f"none (bias_correction={why})"
    if b is None:
        return "none (the sensor noise could not be read from the log; see the warnings)"
    text = (
        f"SIMEX, {n} refits on the raw log with re-drawn sensor noise "
        "(torchjfa.identification.simex_bias)"
    )
    std = result.theta_hat_std
    if std is not None:
        z = (b.abs() / std)[std > 0]
        if z.numel():
            text += (
                f"; the correction is {float(z.median()):.2g} jackknife stds (median over "
                f"the parameters, largest {float(z.max()):.2g})"
            )
    return text

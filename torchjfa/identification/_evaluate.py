"""`evaluate`: an identified model judged on logs it was not identified from.

Each log is read as `identify` reads it (`read`: the same reading options, currents with their
drive gains, ROS bags), its rest at the ends dropped, and prepared with one cut-off for every
model judged (the identification's own, stored in its ``model.npz``, unless one is given): the
prediction uses the prepared q, qd, qdd; the target is the measured torque, unfiltered
(`torchjfa.identification.measured_torque`), so that models identified with different cut-offs
are judged on the same target. The description's parameters (its inertials, no joint terms)
are judged beside the identified ones. With ``rollouts``, MuJoCo also rolls the identified
model's MJCF and the description's out open loop on each log's measured torques
(`torchjfa.sim.replay`): does the simulator move like the robot?
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch

from .._util import output_folder
from ..data import JointLog
from ..dynamics import RigidBodyModel
from ..report import TorqueFit, predicted_torques, torque_errors
from ._options import IdentificationError, Options
from ._prepare import concatenate, identified_model, read_prepared, several
from ._validate import measured_torque

__all__ = ["Evaluation", "evaluate"]


@dataclass(eq=False)
class Evaluation:
    """What `evaluate` returns.

    Attributes:
        model: the identified model's `RigidBodyModel`.
        theta: ``(n_params,)`` its parameters.
        cutoff_hz: the cut-off the logs were prepared with, Hz.
        logs: ``source -> (prepared log with the measured torque as tau, fits)`` per log, the
            fits by name (``"identified"``, and ``"description"`` when the description has
            mass).
        fits: the same fits over all the logs' samples together.
        rollouts: source -> `torchjfa.sim.Replay` per log (``evaluate(..., rollouts=True)``),
            else empty.
    """

    model: RigidBodyModel
    theta: torch.Tensor
    cutoff_hz: float
    logs: dict[str, tuple[JointLog, dict[str, TorqueFit]]]
    fits: dict[str, TorqueFit]
    rollouts: dict = field(default_factory=dict)

    def summary(self) -> dict[str, object]:
        """The numbers as JSON-ready values: ``joint_names``, ``rms``, ``mean_rms``, ``nmse``,
        ``mean_nmse`` (the identified model over all logs), the same under ``description``,
        and per log under ``logs``."""

        def numbers(fit: TorqueFit) -> dict[str, object]:
            return {
                "rms": [float(x) for x in fit.rms],
                "mean_rms": float(fit.rms.mean()),
                "nmse": [float(x) for x in fit.nmse],
                "mean_nmse": float(fit.nmse.mean()),
            }

        out: dict[str, object] = {"joint_names": list(self.model.joint_names)}
        out.update(numbers(self.fits["identified"]))
        if "description" in self.fits:
            out["description"] = numbers(self.fits["description"])
        out["cutoff_hz"] = self.cutoff_hz
        out["target"] = "the measured torque, unfiltered"
        out["logs"] = [
            {
                "log": source,
                "samples": log.n_samples,
                **numbers(fits["identified"]),
                **({"description": numbers(fits["description"])} if "description" in fits else {}),
            }
            for source, (log, fits) in self.logs.items()
        ]
        if self.rollouts:
            out["rollouts"] = {source: r.summary() for source, r in self.rollouts.items()}
        return out

    def lines(self) -> list[str]:
        """A per-joint table of RMS and nMSE, the description's beside the identified model's."""
        names = list(self.fits)
        head = f"{'joint':<22}" + "".join(f"{n + ' RMS':>18}{n + ' nMSE':>18}" for n in names)
        rows = [head]
        for j, joint in enumerate(self.model.joint_names):
            cells = "".join(
                f"{float(self.fits[n].rms[j]):>18.4g}{float(self.fits[n].nmse[j]):>18.4g}"
                for n in names
            )
            rows.append(f"{joint:<22}" + cells)
        rows.append(
            f"{'mean':<22}"
            + "".join(
                f"{float(self.fits[n].rms.mean()):>18.4g}{self.fits[n].mean_nmse:>18.4g}"
                for n in names
            )
        )
        for source, r in self.rollouts.items():
            rows += ["", f"MuJoCo rollouts on {source} ({r.starts} per horizon; mean over joints)"]
            rows += r.lines()
        return rows

    def write(
        self,
        out_dir: str | os.PathLike,
        *,
        plots: bool = True,
        overwrite: bool = False,
        inputs: Iterable[str | os.PathLike] = (),
        command: str = "",
    ) -> dict[str, Path]:
        """``evaluation.json`` and, with ``plots``, one figure of measured and predicted torques
        per log (``torques_<i>.png``) in ``out_dir``, written as one unit
        (`torchjfa.io.output_folder`: ``overwrite``, ``inputs``, ``command``); returns the
        paths."""
        out = Path(out_dir)
        with output_folder(out, overwrite=overwrite, inputs=inputs, command=command) as stage:
            names = self._write_files(stage, plots)
        return {key: out / name for key, name in names.items()}

    def _write_files(self, stage: Path, plots: bool) -> dict[str, str]:
        """The files of `write` into ``stage``; returns key -> file name."""
        from ..report._figures import torques_figure

        names = {"json": "evaluation.json"}
        (stage / names["json"]).write_text(json.dumps(self.summary(), indent=1))
        if plots:
            import matplotlib.pyplot as plt

            kinds = dict(zip(self.model.joint_names, self.model.joint_types, strict=True))
            for i, (_, (log, fits)) in enumerate(self.logs.items()):
                names[f"torques_{i}"] = f"torques_{i}.png"
                fig = torques_figure(log, fits, kinds, stage / names[f"torques_{i}"], seconds=10.0)
                plt.close(fig)
            for i, r in enumerate(self.rollouts.values()):
                names[f"rollouts_{i}"] = f"rollouts_{i}.png"
                plt.close(r.figure(stage / names[f"rollouts_{i}"]))
        return names


def evaluate(
    identified,
    logs,
    options: Options | None = None,
    *,
    cutoff_hz: float | None = None,
    rollouts: bool = False,
) -> Evaluation:
    """Judge an identified model on logs: per-joint RMS and nMSE against the measured torque.

    Args:
        identified: a ``model.npz`` path (`torchjfa.io.read_identified`), or a
            ``(RigidBodyModel, theta)`` pair.
        logs: a log or a list of logs, as `torchjfa.identify` takes them; each is used whole
            (less the rest at its ends with ``options.trim_rest``).
        options: the reading and preparation options (`Options`: columns, time scale, drive
            gains, ROS topic and effort, filter, velocity); the estimation options do not
            apply.
        cutoff_hz: the cut-off to prepare the logs with, Hz (default: the one stored with the
            model, else `torchjfa.data.DEFAULT_CUTOFF_HZ`).
        rollouts: also roll the identified model's MJCF and the description's out in MuJoCo
            on each log (`torchjfa.sim.replay`; needs consistent parameters).

    Raises:
        IdentificationError: on a model file that cannot be read, or logs of other joints.
        LogError: on a log that cannot be read or prepared.
    """
    options = Options() if options is None else options
    ident = identified_model(identified)
    model, theta = ident.model, ident.theta
    cutoff = float(cutoff_hz if cutoff_hz is not None else ident.cutoff_hz)
    if not 0 < cutoff < float("inf"):
        raise IdentificationError(f"the cut-off must be a positive number of Hz, got {cutoff}")
    params = {"identified": theta}
    if bool((model.nominal_theta != 0).any()):  # with the damping and friction it states
        params["description"] = model.description_theta.to(theta)
    per_log = {}
    for source in several(logs):
        raw, data = read_prepared(source, model, options, cutoff)  # its errors name the log
        log = replace(data, tau=measured_torque(raw, data.t))
        name = raw.source if raw.source not in per_log else f"{raw.source} ({len(per_log)})"
        per_log[name] = (log, _fits(model, params, log))
    if not per_log:
        raise IdentificationError("no log to evaluate on")
    everything = concatenate([log for log, _ in per_log.values()])
    replays = _rollouts(model, theta, per_log) if rollouts else {}
    return Evaluation(model, theta, cutoff, per_log, _fits(model, params, everything), replays)


def _rollouts(model, theta, per_log) -> dict:
    """`torchjfa.sim.replay` of the identified and the description's MuJoCo models per log."""
    from ..sim import description_model, mujoco_model, offset_torques, replay

    try:
        models = {"identified": mujoco_model(model, theta), "description": description_model(model)}
    except ValueError as exc:  # inconsistent parameters have no MJCF
        raise IdentificationError(f"no MuJoCo rollouts: {exc}") from None
    offsets = {"identified": offset_torques(model, theta)}
    out = {}
    for source, (log, _) in per_log.items():
        try:
            out[source] = replay(models, log, offsets=offsets)
        except ValueError as exc:
            raise IdentificationError(f"{source}: no MuJoCo rollouts: {exc}") from None
    return out


def _fits(model, params, log: JointLog) -> dict[str, TorqueFit]:
    out = {}
    for name, theta in params.items():
        pred = predicted_torques(model, theta, log.q, log.qd, log.qdd, log.tau)
        nmse, rms = torque_errors(log.tau, pred)
        out[name] = TorqueFit(nmse=nmse, rms=rms, predicted=pred)
    return out

"""The first two stages: `load_model` (the robot) and `read` (its raw log, checked)."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..data import JointLog, LogError, check_log, read_log
from ..data._joints import permutation
from ..dynamics import RigidBodyModel
from ._options import DEFAULT_JOINT_TERMS, IdentificationError, Options, joint_terms

__all__ = ["RawLog", "load_model", "read", "enough", "joint_limits"]


def load_model(
    robot,
    friction: Sequence[str] | None = None,
    fixed_joints: Sequence[str] = (),
    transmission=None,
) -> RigidBodyModel:
    """The `RigidBodyModel` of ``robot``: the first stage.

    Args:
        robot: a URDF / MJCF path, a shipped robot's name (`torchjfa.robots.available`), a
            simulated robot's name (`torchjfa.robots.SIMULATED`) or a `RigidBodyModel`
            (returned as it is).
        friction: the joint terms (`JOINT_TERMS`); None: `DEFAULT_JOINT_TERMS` for a file or
            a name, the model's own for a `RigidBodyModel`.
        fixed_joints: joints of a URDF description held at q = 0 as fixed (a gripper's
            fingers, mimic joints).
        transmission: the drive train (`torchjfa.dynamics.Transmission` or its file), or
            None (a `RigidBodyModel` given as it is keeps its own).

    Raises:
        IdentificationError: on a missing file or one that does not give a model, or joint
            terms that a `RigidBodyModel` given as it is does not have.
    """
    if isinstance(robot, RigidBodyModel):
        if friction is not None and tuple(joint_terms(friction)) != tuple(robot.friction):
            raise IdentificationError(
                f"the model given has the joint terms {tuple(robot.friction)}, not "
                f"{tuple(friction)}: build it with those terms, or leave friction at None"
            )
        if fixed_joints:
            raise IdentificationError(
                "fixed_joints apply to a robot read from a description; build the "
                "RigidBodyModel given with them instead"
            )
        return _geared(robot, transmission)
    from .. import robots

    friction = DEFAULT_JOINT_TERMS if friction is None else joint_terms(friction)
    robot = os.fspath(robot)
    if robot in robots.SIMULATED:
        path, fmt = robots.simulated_path(robot), "mjcf"
    elif robot in robots.available():
        path = robots.path(robot)
        fmt = "urdf" if path.endswith(".urdf") else "mjcf"
    else:
        path = robot
        if not os.path.isfile(path):
            raise IdentificationError(
                f"no robot file {path!r} (give a .urdf or MJCF .xml path, or one of "
                f"{sorted(set(robots.available()) | set(robots.SIMULATED))})"
            )
        fmt = "urdf" if path.lower().endswith(".urdf") else "mjcf"
    if fixed_joints and fmt != "urdf":
        raise IdentificationError(
            f"fixed_joints apply to URDF descriptions; {path!r} is MJCF: fix the joints in the "
            "file (remove them, or give them a range of zero)"
        )
    try:
        if fmt == "urdf":
            model = RigidBodyModel.from_urdf(
                path, friction=tuple(friction), fixed_joints=tuple(fixed_joints)
            )
        else:
            model = RigidBodyModel.from_mjcf(path, friction=tuple(friction))
    except Exception as exc:  # the parsers raise many kinds; all mean "this file is not usable"
        raise IdentificationError(
            f"cannot build a robot model from {path!r}: {type(exc).__name__}: {exc}"
        ) from None
    return _geared(model, transmission)


def _geared(model: RigidBodyModel, transmission) -> RigidBodyModel:
    """``model`` with ``transmission`` (None: as it is), or an `IdentificationError`."""
    if transmission is None:
        return model
    try:
        return model.with_transmission(transmission)
    except (OSError, ValueError) as exc:
        raise IdentificationError(f"transmission: {exc}") from None


@dataclass
class RawLog:
    """What `read` returns.

    Attributes:
        log: the `JointLog` as recorded, its joints in the model's order.
        warnings: what `torchjfa.data.check_log` found that does not stop identification.
    """

    log: JointLog
    warnings: list[str] = field(default_factory=list)


def read(source, model: RigidBodyModel, options: Options | None = None) -> RawLog:
    """Read a raw log (a CSV / NPZ / Parquet path, or a `JointLog`), put its joints in the
    model's order and check it (`torchjfa.data.check_log` with the description's joint limits).

    Raises:
        IdentificationError: on a log too short for the model's parameters.
        LogError: on a log that cannot be read or cannot identify anything (gaps, a robot
            standing still, degrees, scrambled columns).
    """
    options = Options() if options is None else options
    if isinstance(source, JointLog):
        log = source
    else:
        kw = _reading(options, model)
        try:
            log = read_log(source, **kw)
        except LogError as exc:
            foreign = [] if kw["columns"] else _foreign_joints(source, model)
            if not foreign:
                raise
            raise LogError(
                f"{source}: joint(s) {foreign} are in the log but the robot has no joint of that "
                f"name; remove their columns or rename them to the robot's {list(model.joint_names)}"
                f" (reading the log also found: {str(exc).removeprefix(f'{source}: ')})"
            ) from None
    if model.transmission is not None:
        try:
            log = model.transmission.joint_side(log)
        except ValueError as exc:
            raise LogError(str(exc)) from None
    log = log.reorder(model.joint_names)
    enough(log.n_samples, model, "the log has")
    problems = check_log(log, limits=joint_limits(model))
    fatal = [p.message for p in problems if p.fatal]
    if fatal:
        raise LogError(fatal[0])
    if options.max_seconds is not None:  # the first seconds only
        keep = int(torch.searchsorted(log.t, log.t[0] + options.max_seconds)) + 1
        log = log.select(slice(0, min(keep, log.n_samples)))
    notes = [f"{log.source}: {n}" for n in log.info.get("read_notes", [])]
    return RawLog(log, notes + [p.message for p in problems])


def _foreign_joints(source, model: RigidBodyModel) -> list[str]:
    """The joints a log file's column names name that the model lacks ([] where the file's
    columns cannot be listed)."""
    from ..data._log import _format, _read_columns
    from ..data._schema import joints_from_columns

    try:
        path = Path(source)
        raw, _ = _read_columns(path, _format(path, None))
    except Exception:  # the original error says what is wrong with the file
        return []
    return [j for j in joints_from_columns(raw) if j not in model.joint_names]


def _reading(options: Options, model: RigidBodyModel) -> dict:
    """The keywords of `torchjfa.data.read_log` that ``options`` set."""
    kw: dict = {
        "columns": None if options.columns is None else dict(options.columns),
        "drop_nan": options.drop_nan,
        "drop_outliers": options.drop_outliers,
        "drop_cut_line": options.drop_cut_line,
    }
    if options.time_scale is not None:
        kw["time_scale"] = options.time_scale
    if options.topic is not None or options.effort != "torque":
        kw["topic"], kw["effort"] = options.topic, options.effort
    gains = gains_per_joint(options.drive_gains, model.joint_names)
    if gains is not None:
        motors = () if model.transmission is None else model.transmission.motors
        unknown = sorted(set(gains) - set(model.joint_names) - set(motors))
        if unknown:
            raise IdentificationError(
                f"drive gains for {unknown}, which are not joints of the model "
                f"({', '.join(model.joint_names)})" + (" or motors" if motors else "")
            )
        kw["drive_gains"] = gains
    return kw


def gains_per_joint(
    gains, joint_names: Sequence[str], error: type[Exception] = IdentificationError
):
    """``Options.drive_gains`` as name -> N m/A (a sequence is in ``joint_names``' order), or
    None; ``error`` on a sequence of another length."""
    if gains is None:
        return None
    if not isinstance(gains, Mapping):
        gains = list(gains)
        if len(gains) != len(joint_names):
            raise error(
                f"{len(gains)} drive gains for the {len(joint_names)} joints "
                f"{', '.join(joint_names)}: give one per joint in this order, or joint=G,..."
            )
        gains = dict(zip(joint_names, gains, strict=True))
    return {str(k): float(v) for k, v in gains.items()}


def enough(n_samples: int, model: RigidBodyModel, where: str) -> None:
    """At least as many equations (samples x joints) as parameters, else an error."""
    rows = n_samples * model.n_dof
    if rows < model.n_params:
        raise IdentificationError(
            f"{where} {n_samples} samples: with {model.n_dof} joints that is {rows} equations "
            f"for {model.n_params} parameters; record a longer log"
        )


def joint_limits(model: RigidBodyModel) -> np.ndarray | None:
    """``(n_dof, 2)`` position limits of the description in the model's joint order, or None."""
    if model.chain is None:
        return None
    lo, hi = model.chain.get_joint_limits()
    order = list(model.chain.get_joint_parameter_names())
    if sorted(order) != sorted(model.joint_names):
        return None
    lim = np.stack([np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)], axis=1)
    return lim[permutation(order, model.joint_names, have_name="the description's limits")]

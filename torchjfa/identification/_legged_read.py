"""Reading a floating-base robot for `identify_legged`: its model (`load_floating`), its logs
(`read_legged`, joints matched to the model's and contact frames checked), which rows the
logs give (`choose_rows`) and which options apply."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import fields
from pathlib import Path

import numpy as np
import torch

from ..data import BASE_POSE, LeggedLog, LogError, is_uniform, read_legged_log
from ..dynamics import FloatingBaseModel
from ._options import DEFAULT_JOINT_TERMS, IdentificationError, Options
from ._read import gains_per_joint

__all__ = [
    "check_legged_options",
    "choose_rows",
    "flat_frames",
    "is_legged_log",
    "load_floating",
    "read_legged",
]

#: the Coulomb term's smoothing velocity of ``coulomb_velocity="auto"`` for a floating base, rad/s
LEGGED_COULOMB_VELOCITY = 0.05
#: options the floating-base flow does not take (their defaults are ignored; another value
#: is an error)
_ARM_ONLY = (
    "columns", "drop_nan", "drop_outliers", "drop_cut_line", "topic", "effort",
    "velocity", "period", "skip_start", "decimate", "armature", "transmission",
    "jackknife", "bias_correction", "parametrization", "projection_options",
)  # fmt: skip


def is_legged_log(source) -> bool:
    """Whether ``source`` is a log with base-pose columns (`torchjfa.data.BASE_POSE`): a
    `torchjfa.data.LeggedLog`, or a CSV, ``.npz`` or Parquet file whose header holds
    ``base_x``."""
    if isinstance(source, LeggedLog):
        return True
    if not isinstance(source, str | os.PathLike):
        return False
    path = Path(source)
    if not path.is_file():
        return False
    suffix = path.suffix.lower()
    try:
        if suffix == ".csv":
            with open(path, encoding="utf-8", errors="replace") as fh:
                header = fh.readline()
            return BASE_POSE[0] in [h.strip() for h in header.split(",")]
        if suffix == ".npz":
            with np.load(path) as z:
                return BASE_POSE[0] in z.files
        if suffix == ".parquet":
            import pyarrow.parquet as pq

            return BASE_POSE[0] in pq.read_schema(path).names
    except (OSError, ValueError, ImportError):
        return False
    return False


def load_floating(robot, options: Options) -> FloatingBaseModel:
    """The floating-base model of a URDF or MJCF file, with the options' joint terms."""
    if isinstance(robot, FloatingBaseModel):
        return robot
    from .. import robots

    path = os.fspath(robot)
    if path in robots.available():
        path = robots.path(path)
    if not os.path.isfile(path):
        raise IdentificationError(
            f"no robot file {path!r}: a floating-base robot is given by its URDF or MJCF file"
        )
    terms = DEFAULT_JOINT_TERMS if options.friction is None else options.friction
    if "armature" in terms:
        raise IdentificationError("the armature term is not taken for a floating-base robot")
    v_c = options.coulomb_velocity
    kw = {
        "friction": terms,
        "coulomb_velocity": LEGGED_COULOMB_VELOCITY if v_c == "auto" else float(v_c),
    }
    try:
        if path.lower().endswith(".urdf"):
            return FloatingBaseModel.from_urdf(path, fixed_joints=options.fixed_joints, **kw)
        if options.fixed_joints:
            raise IdentificationError("fixed_joints apply to a URDF description")
        return FloatingBaseModel.from_mjcf(path, **kw)
    except ValueError as exc:
        raise IdentificationError(f"{path}: {exc}") from None


def check_legged_options(options: Options) -> None:
    default = Options()
    changed = [f.name for f in fields(Options) if f.name in _ARM_ONLY
               and getattr(options, f.name) != getattr(default, f.name)]  # fmt: skip
    if changed:
        raise IdentificationError(
            f"the options {changed} are not taken for a floating-base robot; leave them at "
            "their defaults"
        )


def read_legged(source, model: FloatingBaseModel, options: Options) -> LeggedLog:
    """A legged log, its joints in the model's order and its contact frames checked."""
    name = source if isinstance(source, str | os.PathLike) else "the log"
    gains = gains_per_joint(options.drive_gains, model.joint_names, LogError)
    if isinstance(source, LeggedLog):
        if gains is not None:
            raise LogError(
                "drive gains turn a log file's motor currents (i_<joint>) into torques; a "
                "LeggedLog holds torques already"
            )
        log = source
    else:
        log = read_legged_log(source, time_scale=options.time_scale, drive_gains=gains)
    if options.max_seconds is not None:
        log = log.select(log.t <= log.t[0] + float(options.max_seconds))
    have, want = list(log.joint_names), list(model.joint_names)
    missing = [j for j in want if j not in have]
    foreign = [j for j in have if j not in want]
    problems = []
    if missing:
        problems.append(f"no columns for the joints {missing}")
    if foreign:
        problems.append(f"columns for {foreign}, which are not joints of the robot ({want})")
    frames = set(model.joints.frame_names)
    unknown = sorted({f for f in (*log.contact, *log.wrench) if f not in frames})
    if unknown:
        problems.append(f"contact frames {unknown} that the description does not have")
    dt = np.diff(log.t)
    if dt.size and not is_uniform(torch.as_tensor(log.t)):
        problems.append(
            f"time steps from {dt.min():.4g} to {dt.max():.4g} s: a legged log must be sampled "
            "at a fixed rate (resample it first)"
        )
    if not log.contact and not log.wrench:
        problems.append("no contact columns (contact_<frame> flags or f_<frame>_x/_y/_z forces)")
    if problems:
        raise LogError(f"{name}: " + "; ".join(problems))
    order = [have.index(j) for j in want]
    q = np.concatenate([log.q[:, :7], log.q[:, 7:][:, order]], 1)
    v = None if log.v is None else np.concatenate([log.v[:, :6], log.v[:, 6:][:, order]], 1)
    tau = None if log.tau is None else log.tau[:, order]
    out = LeggedLog(log.t, q, v, None, tau, log.contact, log.wrench, tuple(want), dict(log.info),
                    log.imu)  # fmt: skip
    out.info["source"] = str(name)
    _imu_frame(out, model, options, name)
    return out


def _imu_frame(log: LeggedLog, model: FloatingBaseModel, options: Options, name) -> None:
    """Where the log's IMU sits (``options.imu_frame``, or the base), in ``log.info``
    (``imu_frame``, ``imu_pose``, ``gravity``) for `torchjfa.data.prepare_legged`."""
    if not log.imu:
        if options.imu_frame is not None:
            raise LogError(f"{name}: --imu-frame is given, but the log has no IMU columns "
                           "(imu_wx, imu_wy, imu_wz and imu_ax, imu_ay, imu_az)")  # fmt: skip
        return
    frame = options.imu_frame or model.base_name
    try:
        pose = model.base_frame(frame)
    except ValueError as exc:
        raise LogError(f"{name}: --imu-frame {frame}: {exc}") from None
    log.info.update(imu_frame=frame, imu_pose=pose, gravity=model.gravity.tolist())


def choose_rows(logs: Sequence[LeggedLog], options: Options) -> str:
    """Which rows the logs and options give (every log must hold what they need)."""
    forces = all(log.wrench for log in logs)
    torques = all(log.tau is not None for log in logs)
    if options.base_rows_only:
        if not forces:
            raise IdentificationError(
                "base_rows_only needs the contact forces (f_<frame>_x/_y/_z) in every log"
            )
        return "base"
    if not torques:
        raise IdentificationError(
            "the logs have no joint torques (tau_<joint>): with force sensors, regress the "
            "base rows alone (--base-rows-only)"
        )
    if forces:
        return "all"
    if not all(log.contact for log in logs):
        raise IdentificationError(
            "some logs have neither contact forces nor contact flags (contact_<frame>)"
        )
    return "projected"


def flat_frames(logs: Sequence[LeggedLog], options: Options) -> tuple[str, ...]:
    frames = {f for log in logs for f in log.contact}
    unknown = sorted(set(options.flat_contacts) - frames)
    if unknown:
        raise IdentificationError(f"flat_contacts {unknown} are not contact frames of the logs")
    return tuple(options.flat_contacts)


def imu_text(raw) -> str:
    """What the log's IMU gave the base's motion, or that it has none."""
    if not raw.imu:
        return "none (the base's motion differentiated from its pose)"
    if "a" not in raw.imu:
        return f"gyroscope in frame {raw.info['imu_frame']}: the base's angular motion"
    return (
        f"gyroscope and accelerometer in frame {raw.info['imu_frame']}: the base's angular "
        "motion and linear acceleration"
    )


def gains_text(raws) -> str:
    """The drive gains the logs' currents were read with, or that the logs hold torques."""
    gains = raws[0].info.get("drive_gains")
    if not gains:
        return "none (the logs hold joint torques)"
    return "motor currents times " + ", ".join(f"{j} {g:g}" for j, g in gains.items()) + " N m/A"

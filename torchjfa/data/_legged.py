"""Logs of legged robots: a floating base, joints, and feet that touch the ground.

Columns (CSV, ``.npz`` or Parquet; names as written here, time in seconds or a unit found as
for joint logs):

* ``t``; the base pose in the world ``base_x, base_y, base_z`` (m) and ``base_qx, base_qy,
  base_qz, base_qw`` (a unit quaternion);
* optionally the base twist in base axes ``base_vx, base_vy, base_vz`` (m/s) and
  ``base_wx, base_wy, base_wz`` (rad/s), Pinocchio's free-flyer velocity (all six or none;
  without them `prepare_legged` differentiates the pose);
* per joint ``q_<joint>``, optionally ``qd_<joint>`` (every joint or none) and ``tau_<joint>``
  (N m; every joint or none: without torques only the base rows can be regressed), or the
  motor currents ``i_<joint>`` (A) with drive gains (N m/A) that turn them into torques;
* per contact frame ``contact_<frame>`` (0 or 1), and where measured the ground's force on it
  ``f_<frame>_x/_y/_z`` (N, world axes) and moment ``m_<frame>_x/_y/_z`` (N m, about the
  frame's origin, world axes);
* optionally an IMU fixed to the base: ``imu_wx, imu_wy, imu_wz`` (its gyroscope, rad/s) and
  ``imu_ax, imu_ay, imu_az`` (its accelerometer's specific force, m/s^2), in its own axes;
  `prepare_legged` then takes the base's angular velocity, angular and linear acceleration
  from them instead of differentiating the pose twice.

`read_legged_log` names every missing or contradictory column in one error; `prepare_legged`
filters every signal with one zero-phase low-pass filter and differentiates the motion (the
base's angular velocity from the quaternion, ``w = 2 vec(q* dq/dt)`` in base axes).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .._util import atomic_file
from ._columns import seconds
from ._differentiate import DEFAULT_CUTOFF_HZ, differentiate
from ._log import _format, _read_columns
from ._schema import TIME_COLUMN, LogError

__all__ = ["LeggedLog", "read_legged_log", "prepare_legged", "BASE_POSE", "BASE_TWIST"]

BASE_POSE = ("base_x", "base_y", "base_z", "base_qx", "base_qy", "base_qz", "base_qw")
BASE_TWIST = ("base_vx", "base_vy", "base_vz", "base_wx", "base_wy", "base_wz")
#: an IMU's columns: its gyroscope (rad/s) and its accelerometer (the specific force, m/s^2:
#: the acceleration minus gravity, +9.81 up at rest), each in the IMU's own axes
IMU_COLUMNS = {"w": ("imu_wx", "imu_wy", "imu_wz"), "a": ("imu_ax", "imu_ay", "imu_az")}
_QUAT_TOL = 1e-3
_AXES = ("x", "y", "z")


@dataclass
class LeggedLog:
    """A legged robot's log, in the state convention of `torchjfa.dynamics.FloatingBaseModel`.

    Attributes:
        t: ``(T,)`` s.
        q: ``(T, 7 + n)`` base position (m), base quaternion ``(x, y, z, w)``, joint positions.
        v: ``(T, 6 + n)`` base linear and angular velocity in base axes, joint velocities; or
            None (not logged: `prepare_legged` differentiates ``q``).
        a: ``(T, 6 + n)`` the time derivatives of ``v``, or None.
        tau: ``(T, n)`` joint torques, N m, or None (not logged).
        contact: frame -> ``(T,)`` 0/1 flags.
        wrench: frame -> ``(T, 3)`` force (N) or ``(T, 6)`` force and moment (N, N m about the
            frame's origin), world axes.
        joint_names: the joints, in the columns' order.
        info: what reading and preparing did (``format``, ``time_scale``, ``cutoff_hz``).
        imu: ``"w"`` -> ``(T, 3)`` gyroscope (rad/s), ``"a"`` -> ``(T, 3)`` accelerometer
            (specific force, m/s^2), in the IMU's axes (`IMU_COLUMNS`); empty without an IMU.
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray | None
    a: np.ndarray | None
    tau: np.ndarray | None
    contact: dict[str, np.ndarray]
    wrench: dict[str, np.ndarray]
    joint_names: tuple[str, ...]
    info: dict = field(default_factory=dict)
    imu: dict[str, np.ndarray] = field(default_factory=dict)

    def columns(self) -> dict[str, np.ndarray]:
        """The log as the named columns of the module (``a`` is not written)."""
        out = {TIME_COLUMN: self.t}
        out.update({name: self.q[:, i] for i, name in enumerate(BASE_POSE)})
        if self.v is not None:
            out.update({name: self.v[:, i] for i, name in enumerate(BASE_TWIST)})
        for i, j in enumerate(self.joint_names):
            out[f"q_{j}"] = self.q[:, 7 + i]
            if self.v is not None:
                out[f"qd_{j}"] = self.v[:, 6 + i]
            if self.tau is not None:
                out[f"tau_{j}"] = self.tau[:, i]
        for frame, flags in self.contact.items():
            out[f"contact_{frame}"] = flags
        for frame, w in self.wrench.items():
            for i, axis in enumerate(_AXES):
                out[f"f_{frame}_{axis}"] = w[:, i]
                if w.shape[1] == 6:
                    out[f"m_{frame}_{axis}"] = w[:, 3 + i]
        for key, x in self.imu.items():
            out.update({name: x[:, i] for i, name in enumerate(IMU_COLUMNS[key])})
        return out

    def select(self, keep: np.ndarray) -> LeggedLog:
        """The samples where the ``(T,)`` boolean ``keep`` holds (or at the indices it
        gives), every signal alike."""

        def take(x):
            return None if x is None else x[keep]

        return replace(
            self, t=self.t[keep], q=self.q[keep], v=take(self.v), a=take(self.a),
            tau=take(self.tau), contact={k: c[keep] for k, c in self.contact.items()},
            wrench={k: w[keep] for k, w in self.wrench.items()},
            imu={k: x[keep] for k, x in self.imu.items()},
        )  # fmt: skip

    def save(self, path: str | os.PathLike) -> None:
        """Write the columns as ``.csv`` (a header line, then one line per sample, every digit
        of float64) or ``.npz`` (one array per column), whole or not at all."""
        cols = self.columns()
        suffix = Path(path).suffix.lower()
        if suffix not in (".csv", ".npz"):
            raise ValueError(f"a legged log is written as .csv or .npz, got {os.fspath(path)!r}")
        with atomic_file(path) as tmp:
            if suffix == ".npz":
                with open(tmp, "wb") as fh:
                    np.savez(fh, **cols)
            else:
                table = np.column_stack(list(cols.values()))
                header = ",".join(cols)
                np.savetxt(tmp, table, delimiter=",", header=header, comments="", fmt="%.17g")


def _numeric(raw: dict, name: str, problems: list[str]) -> np.ndarray | None:
    value = raw.get(name)
    if name in raw and value is None:
        problems.append(f"column {name!r} is not numeric")
    return None if value is None else np.asarray(value, dtype=np.float64)


def _prefixed(names, prefix: str, suffixes: tuple[str, ...] = ("",)) -> list[str]:
    """The ``X`` of columns ``<prefix>X<suffix>``, in order of first appearance."""
    found: list[str] = []
    for name in names:
        for suffix in suffixes:
            if (
                name.startswith(prefix)
                and name.endswith(suffix)
                and len(name) > len(prefix) + len(suffix)
            ):
                x = name[len(prefix) : len(name) - len(suffix)]
                if x not in found:
                    found.append(x)
    return found


def _all_or_none(raw, names: list[str], what: str, problems: list[str]) -> np.ndarray | None:
    present = [n for n in names if n in raw]
    if not present:
        return None
    missing = [n for n in names if n not in raw]
    if missing:
        problems.append(f"{what}: {len(present)} of {len(names)} columns, missing {missing}")
        return None
    cols = [_numeric(raw, n, problems) for n in names]
    return None if any(c is None for c in cols) else np.column_stack(cols)


def read_legged_log(
    path: str | os.PathLike,
    *,
    time_scale: float | None = None,
    format: str | None = None,
    drive_gains: Mapping[str, float] | None = None,
) -> LeggedLog:
    """Read a legged robot's log (the columns of the module).

    Args:
        path: a ``.csv``, ``.npz`` or ``.parquet`` file.
        time_scale: seconds per unit of ``t`` (None: seconds, or a unit found from the step).
        format: ``"csv"``, ``"npz"`` or ``"parquet"`` (default from the suffix).
        drive_gains: N m/A per joint name, for a log with motor currents ``i_<joint>`` (A)
            instead of joint torques: ``tau = gain * i``, one gain for every joint with a
            current column.

    Returns:
        A `LeggedLog` (``a`` None; ``v`` None unless the twist and every ``qd_`` are logged).

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        LogError: naming, in one message, every missing or contradictory column (no time, an
            incomplete base pose or twist, a joint velocity or torque for some joints only, a
            force or moment without all three axes, a text column), then on NaN or inf rows,
            time not strictly increasing, a base quaternion that is not unit, or contact
            flags other than 0 and 1.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no log file {str(path)!r}")
    fmt = _format(path, format)
    if fmt == "ros":
        raise LogError(f"{path}: a legged log is read from CSV, .npz or Parquet, not a ROS bag")
    raw, info = _read_columns(path, fmt)
    problems: list[str] = []
    t = _numeric(raw, TIME_COLUMN, problems)
    if TIME_COLUMN not in raw:
        problems.append(f"no time column {TIME_COLUMN!r}")
    pose = _all_or_none(raw, list(BASE_POSE), "the base pose", problems)
    if pose is None and not any(n in raw for n in BASE_POSE):
        problems.append(f"no base pose (columns {list(BASE_POSE)})")
    twist = _all_or_none(raw, list(BASE_TWIST), "the base twist", problems)
    joints = _prefixed(raw, "q_")
    if not joints:
        problems.append("no joint positions (columns q_<joint>)")
    q = _all_or_none(raw, [f"q_{j}" for j in joints], "joint positions", problems)
    qd = _all_or_none(raw, [f"qd_{j}" for j in joints], "joint velocities", problems)
    tau = _all_or_none(raw, [f"tau_{j}" for j in joints], "joint torques", problems)
    currents = _all_or_none(raw, [f"i_{j}" for j in joints], "motor currents", problems)
    tau = _torques(tau, currents, joints, drive_gains, problems, info)
    stray = sorted(
        set(_prefixed(raw, "qd_") + _prefixed(raw, "tau_") + _prefixed(raw, "i_")) - set(joints)
    )
    if stray:
        problems.append(f"velocities or torques of joints without a position column: {stray}")
    if (twist is None) != (qd is None) and not problems:
        given = "base twist" if qd is None else "joint velocities"
        problems.append(f"the {given} without the other: log both velocities or neither")
    contact = {}
    for frame in _prefixed(raw, "contact_"):
        flags = _numeric(raw, f"contact_{frame}", problems)
        if flags is not None:
            contact[frame] = flags
    wrench = {}
    for frame in _prefixed(raw, "f_", tuple(f"_{a}" for a in _AXES)):
        f = _all_or_none(raw, [f"f_{frame}_{a}" for a in _AXES], f"the force on {frame}", problems)
        m = _all_or_none(raw, [f"m_{frame}_{a}" for a in _AXES], f"the moment on {frame}", problems)
        if f is not None:
            wrench[frame] = f if m is None else np.column_stack([f, m])
    imu = {}
    for key, names in IMU_COLUMNS.items():
        x = _all_or_none(
            raw,
            list(names),
            "the IMU's " + ("gyroscope" if key == "w" else "accelerometer"),
            problems,
        )
        if x is not None:
            imu[key] = x
    if "a" in imu and "w" not in imu:
        problems.append("an accelerometer (imu_a*) without the gyroscope (imu_w*)")
    if problems:
        raise LogError(f"{path}: " + "; ".join(problems))
    signals = [pose, q, twist, qd, tau, *contact.values(), *wrench.values(), *imu.values()]
    bad = ~np.isfinite(t)
    for s in signals:
        if s is not None:
            bad |= ~np.isfinite(s.reshape(len(t), -1)).all(axis=1)
    if bad.any():
        rows = np.flatnonzero(bad)
        raise LogError(f"{path}: {rows.size} rows hold NaN or inf (rows {rows[:8].tolist()}...)")
    if t.size < 2 or np.any(np.diff(t) <= 0):
        raise LogError(f"{path}: the time column must increase strictly over at least 2 rows")
    t, time_info = seconds(t, time_scale, path)
    info.update(time_info)
    norm = np.linalg.norm(pose[:, 3:7], axis=1)
    off = np.flatnonzero(np.abs(norm - 1.0) > _QUAT_TOL)
    if off.size:
        raise LogError(
            f"{path}: the base quaternion (base_qx, base_qy, base_qz, base_qw) is not unit in "
            f"{off.size} rows (row {off[0]}: norm {norm[off[0]]:.6g})"
        )
    for frame, flags in contact.items():
        if not np.isin(flags, (0.0, 1.0)).all():
            raise LogError(f"{path}: contact_{frame} must hold 0 or 1 only")
    q_full = np.column_stack([pose[:, :3], pose[:, 3:7] / norm[:, None], q])
    v = None if twist is None else np.column_stack([twist, qd])
    return LeggedLog(t, q_full, v, None, tau, contact, wrench, tuple(joints), info, imu)


def _torques(tau, currents, joints, gains, problems: list[str], info: dict):
    """The joint torques: the logged ones, or the currents times ``gains`` (N m/A); every
    contradiction (both, currents without gains, gains without currents, gains for other
    joints) added to ``problems``."""
    if gains is None:
        if currents is not None and tau is None:
            problems.append(
                "motor currents (i_<joint>) without drive gains: give one per joint (N m/A)"
            )
        return tau
    gains = {str(k): float(v) for k, v in dict(gains).items()}
    bad = {k: v for k, v in gains.items() if not (np.isfinite(v) and v != 0.0)}
    foreign = sorted(set(gains) - set(joints))
    if foreign:
        problems.append(f"drive gains for {foreign}, which are not joints of the log {joints}")
    if bad:
        problems.append(f"drive gains must be finite and nonzero, got {bad}")
    if currents is None:
        problems.append("drive gains without motor-current columns i_<joint>")
        return tau
    if tau is not None:
        problems.append("both joint torques (tau_) and motor currents (i_): log one of them")
        return tau
    missing = [j for j in joints if j not in gains]
    if missing:
        problems.append(f"no drive gains for the joints {missing}")
    if foreign or bad or missing:
        return None
    info["drive_gains"] = {j: gains[j] for j in joints}
    return currents * np.array([gains[j] for j in joints])


def _quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton products of ``(T, 4)`` quaternions in ``(x, y, z, w)`` order."""
    pv, pw, qv, qw = p[:, :3], p[:, 3:], q[:, :3], q[:, 3:]
    return np.column_stack(
        [pw * qv + qw * pv + np.cross(pv, qv), pw * qw - (pv * qv).sum(1, keepdims=True)]
    )


def _rotate_to_base(quat: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``R(quat)^T x`` for ``(T, 4)`` quaternions and ``(T, 3)`` world vectors."""
    conj = quat * np.array([-1.0, -1.0, -1.0, 1.0])
    xq = np.column_stack([x, np.zeros(len(x))])
    return _quat_mul(_quat_mul(conj, xq), quat)[:, :3]


def continuous_quaternion(quat: np.ndarray) -> np.ndarray:
    """``(T, 4)`` unit quaternions with their signs made continuous (``q`` and ``-q`` are one
    orientation): a copy, each sample's sign flipped where it points away from the last."""
    quat = np.array(quat, dtype=float)
    flip = np.cumsum(np.r_[0, (quat[1:] * quat[:-1]).sum(1) < 0]) % 2 == 1
    quat[flip] *= -1.0
    return quat


def prepare_legged(
    log: LeggedLog,
    *,
    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ,
    method: str = "butterworth",
    imu_pose: tuple[np.ndarray, np.ndarray] | None = None,
    gravity=(0.0, 0.0, -9.81),
) -> LeggedLog:
    """Filter every signal of a legged log with one zero-phase low-pass filter and fill in its
    velocities (where not logged) and accelerations.

    The base's linear velocity in base axes is ``R^T dp/dt`` and its angular velocity
    ``w = 2 vec(q* dq/dt)``; their derivatives ``R^T d2p/dt2 - w x v`` and ``2 vec(q*
    d2q/dt2)``. A logged twist and joint velocities are filtered and differentiated once
    instead. The quaternion's sign is made continuous first (``q`` and ``-q`` are one
    orientation) and it is normalised after filtering.

    With an IMU (``log.imu``), its gyroscope turned into base axes is the angular velocity
    (filtered, and differentiated once for the angular acceleration), and its accelerometer
    gives the linear acceleration: the IMU point's acceleration is the specific force plus
    gravity, the base origin's ``a_p - dw x p - w x (w x p)`` (``p`` the IMU's position on the
    base), and the velocity's derivative in base axes that minus ``w x v``.

    Args:
        log: a `LeggedLog` with uniform time steps.
        cutoff_hz: the filter's cut-off, Hz (None: no filter), as `differentiate`.
        method: ``"butterworth"`` or ``"savgol"``, as `differentiate`.
        imu_pose: ``(R, p)``: the IMU frame's ``(3, 3)`` rotation and ``(3,)`` position (m) in
            the base frame (`torchjfa.dynamics.FloatingBaseModel.base_frame`); None: the base
            frame itself.
        gravity: ``(3,)`` m/s^2 in world axes, for the accelerometer.

    Returns:
        A new `LeggedLog` with ``v`` and ``a``, its signals filtered (contact flags as they
        are); ``info["cutoff_hz"]`` records the cut-off.

    Raises:
        ValueError: as `differentiate` (non-uniform time, a log too short for the filter).
    """
    kw = {"method": method, "cutoff_hz": cutoff_hz}
    t = log.t
    quat = continuous_quaternion(log.q[:, 3:7])
    pos = differentiate(t, log.q[:, :3], **kw)
    rot = differentiate(t, quat, **kw)
    joints = differentiate(t, log.q[:, 7:], **kw)
    quat_f = rot.value.numpy()
    quat_f /= np.linalg.norm(quat_f, axis=1, keepdims=True)
    conj = quat_f * np.array([-1.0, -1.0, -1.0, 1.0])
    if log.v is None:
        w = 2.0 * _quat_mul(conj, rot.first.numpy())[:, :3]
        dw = 2.0 * _quat_mul(conj, rot.second.numpy())[:, :3]
        v_lin = _rotate_to_base(quat_f, pos.first.numpy())
        a_lin = _rotate_to_base(quat_f, pos.second.numpy()) - np.cross(w, v_lin)
        v = np.column_stack([v_lin, w, joints.first.numpy()])
        a = np.column_stack([a_lin, dw, joints.second.numpy()])
    else:
        vel = differentiate(t, log.v, **kw)
        v, a = vel.value.numpy(), vel.first.numpy()
    sensed = {k: differentiate(t, x, **kw) for k, x in log.imu.items()}
    if sensed:
        v, a = _imu_motion(sensed, quat_f, v, a, imu_pose, gravity)
    q = np.column_stack([pos.value.numpy(), quat_f, joints.value.numpy()])
    tau = None if log.tau is None else differentiate(t, log.tau, **kw).value.numpy()
    wrench = {k: differentiate(t, w_, **kw).value.numpy() for k, w_ in log.wrench.items()}
    imu = {k: d.value.numpy() for k, d in sensed.items()}
    info = {**log.info, "cutoff_hz": cutoff_hz}
    return replace(log, q=q, v=v, a=a, tau=tau, wrench=wrench, info=info, imu=imu)


def _imu_motion(sensed: dict, quat, v, a, pose, gravity):
    """``(v, a)`` with the base's angular velocity and accelerations from the IMU's filtered
    signals ``sensed`` (`differentiate`'s, in the IMU's axes; see `prepare_legged`)."""
    R, p = (np.eye(3), np.zeros(3)) if pose is None else (np.asarray(pose[0]), np.asarray(pose[1]))
    # the filter and the derivative are linear: turned into base axes after them
    w, dw = sensed["w"].value.numpy() @ R.T, sensed["w"].first.numpy() @ R.T
    v, a = v.copy(), a.copy()
    v[:, 3:6], a[:, 3:6] = w, dw
    if "a" in sensed:
        f = sensed["a"].value.numpy() @ R.T
        g = _rotate_to_base(quat, np.broadcast_to(np.asarray(gravity, float), f.shape).copy())
        origin = f + g - np.cross(dw, p) - np.cross(w, np.cross(w, p))
        a[:, :3] = origin - np.cross(w, v[:, :3])
    return v, a

"""A robot's drive train: motors that turn joints through gearboxes, coupled or not.

A `Transmission` relates the motors' velocities to the joints' velocities by a square ratio
matrix ``R`` (motor velocity = ``R @`` joint velocity, joint torque = ``R^T @`` motor torque).
An ordinary gearbox is a diagonal entry (the reduction, negative when the motor turns the
other way); a coupled wrist, a differential or a tendon drive has off-diagonal entries: a motor
whose row has several entries turns several joints.

With a transmission, a model's joint terms (viscous, Coulomb and offset friction, armature)
belong to the motors rather than the joints, and reach the joints through the gearing:

    tau += R^T (I_m R qdd + f_v R qd + f_c sign(R qd) + f_o)

one set of terms per motor, linear in them, in units of the motor side (kg m^2, N m s/rad, N m
at the motor shaft). Motor ``k`` keeps its terms where joint ``joints[k]`` keeps its own
without a transmission, so theta's length does not change; `ParameterLayout` names them after
the motor. Joints the transmission does not list keep their own terms.

Files are JSON or YAML objects::

    {"joints": ["j1", "j2", "j3"],
     "ratio": [[32, 0, 0], [0, 32, 0], [0, 32, 45]],
     "motors": ["m1", "m2", "m3"]}

``motors`` is optional (default ``<joint>_motor``); it names the motor-side columns of a log
(``q_<motor>``, ``tau_<motor>``, ``i_<motor>``), which `Transmission.joint_side` converts.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ._parameters import ParameterLayout

__all__ = ["Transmission", "read_transmission", "apply_joint_terms", "layout_for"]

#: the largest condition number of a ratio matrix taken as invertible
_MAX_CONDITION = 1e10


@dataclass(frozen=True, eq=False)
class Transmission:
    """Motors driving joints through a ratio matrix: ``qd_motor = ratio @ qd_joints``.

    Args:
        joints: the ``n`` joints the motors drive, in the order of ``ratio``'s columns.
        ratio: ``(n, n)`` motor velocity per joint velocity (rad/rad, or rad/m for a
            prismatic joint); square and invertible. Row ``k`` is motor ``k``.
        motors: the ``n`` motors' names (default ``<joint>_motor`` of ``joints``).

    Raises:
        ValueError: on repeated or missing names, a ratio that is not square, not finite or
            not invertible.
    """

    joints: tuple[str, ...]
    ratio: np.ndarray
    motors: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        joints = tuple(str(j) for j in self.joints)
        if not joints:
            raise ValueError("a transmission needs at least one joint")
        try:
            ratio = np.array(self.ratio, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(
                f"the transmission's ratio must be a square matrix of numbers, got {self.ratio!r}"
            ) from None
        n = len(joints)
        if ratio.shape != (n, n):
            raise ValueError(
                f"the transmission's ratio must be {n} x {n} (one row per motor, one column per "
                f"joint of {list(joints)}), got shape {ratio.shape}"
            )
        if not np.isfinite(ratio).all():
            raise ValueError("the transmission's ratio has entries that are not finite")
        cond = np.linalg.cond(ratio)
        if not cond < _MAX_CONDITION:
            raise ValueError(
                "the transmission's ratio is not invertible (condition number "
                f"{cond:.3g}): every joint must be driven, by motors that do not move together"
            )
        motors = tuple(str(m) for m in self.motors) or tuple(f"{j}_motor" for j in joints)
        for what, names in (("joints", joints), ("motors", motors)):
            if len(set(names)) != len(names):
                raise ValueError(f"the transmission's {what} repeat: {list(names)}")
        if len(motors) != n:
            raise ValueError(f"the transmission names {len(motors)} motors for {n} joints")
        if set(motors) & set(joints):
            raise ValueError(
                f"motors and joints must have different names, both have {sorted(set(motors) & set(joints))}"
            )
        ratio.setflags(write=False)
        object.__setattr__(self, "joints", joints)
        object.__setattr__(self, "ratio", ratio)
        object.__setattr__(self, "motors", motors)

    def __eq__(self, other) -> bool:
        return (
            isinstance(other, Transmission)
            and self.joints == other.joints
            and self.motors == other.motors
            and np.array_equal(self.ratio, other.ratio)
        )

    def __hash__(self) -> int:
        return hash((self.joints, self.motors, self.ratio.tobytes()))

    @property
    def coupled(self) -> tuple[str, ...]:
        """The motors that turn more than one joint."""
        return tuple(
            m for m, row in zip(self.motors, self.ratio, strict=True) if (row != 0).sum() > 1
        )

    def to_dict(self) -> dict:
        """``{"joints", "ratio", "motors"}`` as plain lists (JSON-ready)."""
        return {
            "joints": list(self.joints),
            "ratio": self.ratio.tolist(),
            "motors": list(self.motors),
        }

    @classmethod
    def from_dict(cls, data: Mapping) -> Transmission:
        """From ``{"joints": [...], "ratio": [[...]], "motors": [...] (optional)}``."""
        if not isinstance(data, Mapping):
            raise ValueError(
                "a transmission is an object with 'joints' and 'ratio' (and optionally "
                f"'motors'), got {type(data).__name__}"
            )
        unknown = sorted(set(data) - {"joints", "ratio", "motors"})
        missing = [k for k in ("joints", "ratio") if k not in data]
        if unknown or missing:
            raise ValueError(
                "a transmission has the keys 'joints', 'ratio' and optionally 'motors'"
                + (f"; missing {missing}" if missing else "")
                + (f"; unknown {unknown}" if unknown else "")
            )
        joints = data["joints"]
        if isinstance(joints, str) or not isinstance(joints, Sequence):
            raise ValueError(f"the transmission's joints must be a list of names, got {joints!r}")
        return cls(tuple(joints), data["ratio"], tuple(data.get("motors") or ()))

    def indices(self, joint_names: Sequence[str]) -> list[int]:
        """Each transmission joint's index in ``joint_names`` (a model's joints).

        Raises:
            ValueError: naming the joints the model does not have.
        """
        names = list(joint_names)
        unknown = [j for j in self.joints if j not in names]
        if unknown:
            raise ValueError(
                f"the transmission names joints {unknown} that the robot does not have "
                f"(its joints: {', '.join(names)})"
            )
        return [names.index(j) for j in self.joints]

    def joint_side(self, log):
        """A `torchjfa.data.JointLog` recorded at the motors, as the joints see it.

        The log's ``joint_names`` must include every motor (``q_<motor>``, ``tau_<motor>``
        or ``i_<motor>`` columns, motor-side positions in rad, torques in N m at the motor
        shaft) and none of the transmission's joints; those columns are replaced by the
        joints' ``q = R^-1 q_m`` (likewise velocities and accelerations) and
        ``tau = R^T tau_m``, the other joints kept. A log without motor columns is returned
        as it is.

        Raises:
            ValueError: on a log that has some motors but not all, or both a motor and a
                joint it drives.
        """
        names = list(log.joint_names)
        have = [m for m in self.motors if m in names]
        if not have:
            return log
        if len(have) != len(self.motors) or any(j in names for j in self.joints):
            raise ValueError(
                f"{log.source}: a log recorded at the motors needs the columns of every motor "
                f"({', '.join(self.motors)}) and none of the joints they drive "
                f"({', '.join(self.joints)}); it has {', '.join(names)}"
            )
        m_idx = [names.index(m) for m in self.motors]
        keep = [i for i in range(len(names)) if i not in m_idx]
        ratio = torch.tensor(self.ratio, dtype=torch.float64)

        def convert(x, to_joint):
            if x is None:
                return None
            return torch.cat([x[:, keep], to_joint(x[:, m_idx])], dim=1)

        inverse = torch.linalg.inv(ratio)
        position = lambda v: v @ inverse.T  # noqa: E731 - v rows are motor values
        info = dict(log.info)
        info["read_notes"] = list(info.get("read_notes", [])) + [
            "positions and torques recorded at the motors "
            f"({', '.join(self.motors)}) converted to the joints through the transmission"
        ]
        return type(log)(
            t=log.t,
            q=convert(log.q, position),
            tau=convert(log.tau, lambda v: v @ ratio),
            joint_names=[names[i] for i in keep] + list(self.joints),
            qd=convert(log.qd, position),
            qdd=convert(log.qdd, position),
            period_samples=log.period_samples,
            source=log.source,
            info=info,
        )


def read_transmission(source) -> Transmission:
    """A `Transmission` from a JSON or YAML file, a mapping, or a `Transmission` (as it is).

    Raises:
        FileNotFoundError: if the file does not exist.
        ValueError: on a file that is neither JSON nor YAML or does not describe a
            transmission (the message says what is wrong).
    """
    if source is None or isinstance(source, Transmission):
        return source
    if isinstance(source, Mapping):
        return Transmission.from_dict(source)
    path = Path(os.fspath(source))
    if not path.is_file():
        raise FileNotFoundError(f"no transmission file {str(path)!r}")
    text = path.read_text(encoding="utf-8")
    try:
        data = json.loads(text)
    except json.JSONDecodeError:
        import yaml  # PyYAML, installed with jsonargparse

        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise ValueError(
                f"{path}: neither JSON nor YAML ({str(exc).splitlines()[0]})"
            ) from None
    try:
        return Transmission.from_dict(data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def apply_joint_terms(
    Y: torch.Tensor,
    qd: torch.Tensor,
    qdd: torch.Tensor,
    layout,
    coulomb_velocity: float,
    transmission: Transmission | None,
) -> None:
    """Finish the joint-term columns of a regressor ``Y (B, n, n_params)`` in place.

    Every regressor path writes each joint's terms as ``[qd, sign(qd), 1, qdd]`` in its own
    row. This smooths the Coulomb column to ``tanh(qd / v_c)`` for ``coulomb_velocity`` > 0,
    and, with a transmission, replaces the columns of the transmission's joints by the motors'
    ``R^T [R qd, sign(R qd), 1, R qdd]`` (the Coulomb term smoothed with ``v_c`` times the
    motor's largest ratio, so that it switches over the same band of joint velocities).

    Args:
        qd, qdd: ``(B, n)`` joint velocities and accelerations.
        layout: the model's `ParameterLayout`; ``coulomb_velocity``: ``v_c`` >= 0, rad/s.
    """
    kinds = layout.friction
    if not kinds or (transmission is None and not (coulomb_velocity and "coulomb" in kinds)):
        return
    n, per = layout.n_joints, layout.params_per_joint
    view = Y.view(Y.shape[0], n, n, per)
    if coulomb_velocity and "coulomb" in kinds:
        view.diagonal(0, 1, 2)[:, kinds.index("coulomb") + 10] = torch.tanh(qd / coulomb_velocity)
    if transmission is None:
        return
    idx = torch.as_tensor(transmission.indices(layout.joint_names), device=Y.device)
    ratio = torch.tensor(transmission.ratio, dtype=Y.dtype, device=Y.device)
    qd_m = qd[:, idx] @ ratio.T  # (B, n_m) motor velocities
    signal = {"viscous": qd_m, "offset": torch.ones_like(qd_m), "armature": qdd[:, idx] @ ratio.T}
    if "coulomb" in kinds:
        if coulomb_velocity:
            width = coulomb_velocity * ratio.abs().amax(dim=1)
            signal["coulomb"] = torch.tanh(qd_m / width)
        else:
            signal["coulomb"] = torch.sign(qd_m)
    rows, slots = idx[:, None], idx[None, :]  # joint rows x motor slots
    for k, kind in enumerate(kinds):
        # entry (row j, motor m) = R[m, j] * signal_m
        view[:, rows, slots, 10 + k] = ratio.T * signal[kind][:, None, :]


def layout_for(joint_names, friction, transmission: Transmission | None) -> ParameterLayout:
    """The `ParameterLayout` of a robot's joints, the motors of ``transmission`` (if any)
    naming the terms they carry."""
    owners = list(joint_names)
    if transmission is not None:
        for i, motor in zip(transmission.indices(owners), transmission.motors, strict=True):
            owners[i] = motor
    return ParameterLayout(tuple(joint_names), friction, tuple(owners))

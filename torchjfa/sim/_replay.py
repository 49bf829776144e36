"""Does the identified model make MuJoCo move like the robot? Short open-loop rollouts on a log.

From measured states spread over a log, MuJoCo integrates a model driven by the log's measured
torques alone (no feedback) for a short horizon, and the simulated positions and velocities
are compared with the measured ones at the end of each horizon. A model whose dynamics match
the robot's drifts slowly; the description's own parameters (CAD inertials, its own or no
friction) beside it say how much the identification bought.

`mujoco_model` builds the identified model's MuJoCo model from its MJCF export
(`torchjfa.dynamics.RigidBodyModel.write_mjcf`: inertials, armature, damping, friction loss, a
transmission's tendons), `description_model` the description's; `replay` runs the rollouts.
Contacts and the description's actuators are off in both (the log's torques drive the joints),
joint limits stay on.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import torch

__all__ = ["HORIZONS", "Replay", "mujoco_model", "description_model", "offset_torques", "replay"]

#: the rollouts' horizons, s
HORIZONS = (0.05, 0.2, 0.5)
#: the largest integration step, s (the log's period is divided into steps no longer)
MAX_STEP = 1e-3


def _prepared(mj: mujoco.MjModel) -> mujoco.MjModel:
    mj.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    mj.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
    return mj


def mujoco_model(model, theta) -> mujoco.MjModel:
    """The MuJoCo model of ``model`` (a `torchjfa.dynamics.RigidBodyModel`) with parameters
    ``theta`` (consistent), from its MJCF export; contacts and actuators off."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "identified.xml"
        model.write_mjcf(theta, path)
        return _prepared(mujoco.MjModel.from_xml_path(str(path)))


def description_model(model) -> mujoco.MjModel:
    """The MuJoCo model of ``model``'s description as it is (its inertials and its own joint
    friction, damping and armature, if any); contacts and actuators off."""
    if model.source_format == "urdf":
        from ..dynamics._mjcf import mjcf_from_urdf

        return _prepared(mujoco.MjModel.from_xml_string(mjcf_from_urdf(model.source_xml)))
    path = model.source_path
    if path and os.path.isfile(path) and Path(path).read_text() == model.source_xml:
        return _prepared(mujoco.MjModel.from_xml_path(path))
    return _prepared(mujoco.MjModel.from_xml_string(model.source_xml))


@dataclass(frozen=True)
class Replay:
    """Open-loop rollouts' errors at the end of each horizon.

    Attributes:
        horizons: ``(n_h,)`` s.
        joint_names: ``(n_dof,)``.
        starts: rollouts per horizon (measured states spread evenly over the log).
        position: model name -> ``(n_h, n_dof)`` RMS position error, rad (m for prismatic).
        velocity: model name -> ``(n_h, n_dof)`` RMS velocity error, rad/s (m/s).
        diverged: model name -> rollouts that left the finite numbers (counted out of the RMS).
    """

    horizons: tuple[float, ...]
    joint_names: tuple[str, ...]
    starts: int
    position: dict[str, np.ndarray]
    velocity: dict[str, np.ndarray]
    diverged: dict[str, int]

    def summary(self) -> dict[str, object]:
        """JSON-ready: horizons, starts and per model the errors per horizon and joint."""
        return {
            "horizons_s": list(self.horizons),
            "starts": self.starts,
            "models": {
                name: {
                    "position_rms": self.position[name].tolist(),
                    "velocity_rms": self.velocity[name].tolist(),
                    "mean_position_rms": self.position[name].mean(axis=1).tolist(),
                    "diverged": self.diverged[name],
                }
                for name in self.position
            },
        }

    def lines(self) -> list[str]:
        """One row per model and horizon: the mean position and velocity error over joints."""
        rows = [f"{'rollout':<26}{'horizon s':>10}{'position RMS':>14}{'velocity RMS':>14}"]
        for name in self.position:
            for h, horizon in enumerate(self.horizons):
                rows.append(
                    f"{name:<26}{horizon:>10.3g}{self.position[name][h].mean():>14.4g}"
                    f"{self.velocity[name][h].mean():>14.4g}"
                )
        return rows

    def figure(self, path: str | os.PathLike):
        """Position error per joint against the horizon, one line per model; saved to ``path``."""
        import matplotlib.pyplot as plt

        n = len(self.joint_names)
        cols = min(n, 4)
        rows = math.ceil(n / cols)
        fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows), squeeze=False)
        for j, joint in enumerate(self.joint_names):
            ax = axes[j // cols][j % cols]
            for name, err in self.position.items():
                ax.plot(self.horizons, err[:, j], marker="o", label=name)
            ax.set_title(joint, fontsize=9)
            ax.set_xlabel("horizon, s")
            ax.set_ylabel("position RMS, rad")
            ax.set_yscale("log")
        for k in range(n, rows * cols):
            axes[k // cols][k % cols].axis("off")
        axes[0][0].legend(fontsize=8)
        fig.suptitle("open-loop MuJoCo rollouts from measured states under measured torques")
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        return fig


def substeps(period: float, timestep: float) -> int:
    """Physics steps per sample ``period``: the model's own ``timestep`` where the period holds
    a whole number of them, else steps of at most `MAX_STEP`."""
    own = period / timestep
    if abs(own - round(own)) < 1e-6 * own and timestep <= MAX_STEP:
        return round(own)
    return max(1, math.ceil(period / MAX_STEP - 1e-9))


def _addresses(mj: mujoco.MjModel, joints: Sequence[str]) -> tuple[list[int], list[int]]:
    qpos, dof = [], []
    for name in joints:
        j = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, name)
        if j < 0:
            raise ValueError(f"the MuJoCo model has no joint {name!r}")
        qpos.append(int(mj.jnt_qposadr[j]))
        dof.append(int(mj.jnt_dofadr[j]))
    return qpos, dof


def replay(
    models: Mapping[str, mujoco.MjModel],
    log,
    *,
    horizons: Sequence[float] = HORIZONS,
    starts: int = 40,
    offsets: Mapping[str, np.ndarray] | None = None,
) -> Replay:
    """Roll each MuJoCo model out from measured states under the log's measured torques.

    Args:
        models: name -> ``mujoco.MjModel`` (`mujoco_model`, `description_model`), each with
            the log's joints by name.
        log: a `torchjfa.data.JointLog` with velocities (a prepared log: filtered ``q``,
            ``qd``, evenly sampled), ``tau`` the torques that drive the rollouts, N m.
        horizons: s, each at least one sample period and at most the log's length.
        starts: rollouts per horizon, their first states spread evenly over the log.
        offsets: name -> ``(n_dof,)`` constant torques a model holds outside MuJoCo's fields
            (the identified offsets), subtracted from the drive of that model, N m.

    Returns:
        A `Replay`.

    Raises:
        ValueError: on a log without velocities, horizons it cannot hold, or a model without
            the log's joints.
    """
    if log.qd is None:
        raise ValueError("the rollouts start from measured states: the log needs velocities")
    t = log.t.numpy()
    period = float(np.median(np.diff(t)))
    steps = [int(round(h / period)) for h in horizons]
    longest = max(steps)
    if min(steps) < 1 or longest >= len(t) - 1:
        raise ValueError(
            f"horizons {list(horizons)} s do not fit a log of {t[-1] - t[0]:.3g} s sampled "
            f"every {period:.3g} s"
        )
    first = np.linspace(0, len(t) - 1 - longest, max(1, int(starts))).astype(int)
    q, qd, tau = (x.numpy() for x in (log.q, log.qd, log.tau))
    position, velocity, diverged = {}, {}, {}
    for name, mj in models.items():
        n_sub = substeps(period, float(mj.opt.timestep))
        mj.opt.timestep = period / n_sub
        qadr, dadr = _addresses(mj, log.joint_names)
        data = mujoco.MjData(mj)
        offset = np.zeros(len(dadr)) if not offsets or name not in offsets else offsets[name]
        errors = np.full((len(first), len(steps), 2, len(dadr)), np.nan)
        for r, s in enumerate(first):
            mujoco.mj_resetData(mj, data)
            data.qpos[qadr], data.qvel[dadr] = q[s], qd[s]
            for k in range(1, longest + 1):
                data.qfrc_applied[dadr] = tau[s + k - 1] - offset
                for _ in range(n_sub):
                    mujoco.mj_step(mj, data)
                if k in steps:
                    h = steps.index(k)
                    errors[r, h, 0] = data.qpos[qadr] - q[s + k]
                    errors[r, h, 1] = data.qvel[dadr] - qd[s + k]
        finite = np.isfinite(errors).all(axis=(1, 2, 3))
        diverged[name] = int((~finite).sum())
        kept = errors[finite] if finite.any() else errors
        rms = np.sqrt(np.mean(kept**2, axis=0))  # (n_h, 2, n_dof)
        position[name], velocity[name] = rms[:, 0], rms[:, 1]
    return Replay(
        tuple(float(h) for h in horizons),
        tuple(log.joint_names),
        len(first),
        position,
        velocity,
        diverged,
    )


def offset_torques(model, theta) -> np.ndarray:
    """``(n_dof,)`` the constant joint torques of theta's offset terms (0 without them), N m."""
    if "offset" not in model.friction:
        return np.zeros(model.n_dof)
    only = torch.zeros_like(theta, dtype=torch.float64)
    _, terms = model.layout.split(torch.arange(model.n_params))
    idx = terms[:, model.friction.index("offset")]
    only[idx] = theta.to(torch.float64)[idx]
    zero = torch.zeros(model.n_dof, dtype=torch.float64)
    return (model.regressor(zero, zero, zero, compiled=False) @ only).numpy()

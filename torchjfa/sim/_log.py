"""`SimulatedLog`: a simulated joint log with its ground truth, saved to and loaded from ``.npz``.

A simulated log is a `torchjfa.data.JointLog` (what identification uses: noisy measured q, qd,
tau and the differentiated qdd) plus the noiseless signals of the same samples for evaluation
and how it was made (robot, rates, noise, seed, unmodeled effects, excitation), so that
everything that takes a `JointLog` takes it. `torchjfa.sim.generate_log` makes one.

The ``.npz`` format (``numpy.savez_compressed``, no pickled objects, read with
``allow_pickle=False``), version 1:

==========================  ===================  ==========================================
key                         shape, dtype         meaning
==========================  ===================  ==========================================
``format``                  (), str              ``"torchjfa.SimulatedLog"``
``version``                 (), int64            1
``robot``                   (), str              robot name (``"head"``, ``"arm"``)
``joint_names``             (n_dof,), str        joint order of every ``(n, n_dof)`` array
``t``                       (n,), float64        sample times, s
``q qd qdd tau``            (n, n_dof), float64  measured/derived signals, rad, rad/s,
                                                 rad/s^2, N m
``q_true qd_true``          (n, n_dof), float64  noiseless state
``qdd_true``                (n, n_dof), float64  the simulator's acceleration (``qacc``)
``tau_true``                (n, n_dof), float64  the torque commanded at each sample (held
                                                 over the next step)
``period_samples``          (), int64            samples per excitation period (-1: None)
``control_rate``            (), float64          sampling (= control) rate, Hz
``seed``                    (), int64            seed, -1 when None
``noise_position``          (n_dof,), float64    position noise std, rad
``noise_velocity``          (n_dof,), float64    velocity noise std, rad/s
``noise_torque``            (n_dof,), float64    torque noise std, N m
``effect_<name>``           (n_dof,), float64    joint effects the simulation had, for
                                                 damping, armature, frictionloss, stiffness
``traj_base_frequency``     (), float64          excitation f0, Hz
``traj_offset``             (n_dof,), float64    see `SinusoidTrajectory`
``traj_amplitude``          (n_dof, K), float64
``traj_harmonic``           (n_dof, K), int64
``traj_phase``              (n_dof, K), float64
``velocity_source``         (), str              ``"sensor"`` or ``"differentiate"``
``diff_method``             (), str              differentiation method
``diff_cutoff_hz``          (), float64          cut-off, Hz (NaN: none)
==========================  ===================  ==========================================
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
import torch

from .._util import atomic_file
from ..data import JointLog, NpzArchive, read_log
from ._trajectory import SinusoidTrajectory

__all__ = ["SensorNoise", "SimulatedLog", "load_log"]

_FORMAT = "torchjfa.SimulatedLog"
_VERSION = 1
_TRUTH = ("q_true", "qd_true", "qdd_true", "tau_true")
_SIGNALS = ("q", "qd", "qdd", "tau", *_TRUTH)
_NOISE_FIELDS = ("position_std", "velocity_std", "torque_std")
_EFFECTS = ("damping", "armature", "frictionloss", "stiffness")


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations of the additive white Gaussian sensor noise.

    Each is a float (every joint) or a per-joint sequence. The defaults (1e-3 rad, 0.02 rad/s,
    0.02 N m) make the differentiated acceleration noticeably noisy (about 0.4 rad/s^2 after
    the default 20 Hz filter at 420 Hz) while positions stay accurate.

    Attributes:
        position_std: rad.
        velocity_std: rad/s (the velocity sensor; unused when velocities are differentiated).
        torque_std: N m.
    """

    position_std: float | tuple[float, ...] = 1e-3
    velocity_std: float | tuple[float, ...] = 2e-2
    torque_std: float | tuple[float, ...] = 2e-2

    @classmethod
    def zero(cls) -> SensorNoise:
        """No noise at all."""
        return cls(0.0, 0.0, 0.0)

    def scaled(self, factor: float) -> SensorNoise:
        """The same noise with every standard deviation multiplied by ``factor``."""
        factor = float(factor)

        def mul(v):
            return float(v) * factor if np.ndim(v) == 0 else tuple(float(x) * factor for x in v)

        return SensorNoise(mul(self.position_std), mul(self.velocity_std), mul(self.torque_std))

    def permuted(self, perm: list[int]) -> SensorNoise:
        """The same noise with its per-joint sequences in ``perm`` order (floats stay)."""

        def take(v):
            return v if np.ndim(v) == 0 else tuple(np.asarray(v, dtype=np.float64)[perm].tolist())

        return SensorNoise(*(take(getattr(self, k)) for k in _NOISE_FIELDS))

    def per_joint(self, n_dof: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The three standard deviations as ``(n_dof,)`` arrays.

        Raises:
            ValueError: on a wrong length, negative or non-finite value.
        """
        out = []
        for name in _NOISE_FIELDS:
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.ndim == 0:
                v = np.full(n_dof, float(v))
            if v.shape != (n_dof,):
                raise ValueError(f"{name} must be a float or have {n_dof} entries, got {v.shape}")
            if not np.all(np.isfinite(v)) or np.any(v < 0):
                raise ValueError(f"{name} must be finite and non-negative, got {v.tolist()}")
            out.append(v)
        return out[0], out[1], out[2]


@dataclass(eq=False, kw_only=True)
class SimulatedLog(JointLog):
    """A simulated robot log: a `JointLog` of noisy signals for identification plus the truth.

    Every ``(n, n_dof)`` tensor is float64 on the CPU, columns in `joint_names` order, and
    the first sample is at the start of an excitation period (phase 0), so that sample ``k``
    has phase ``k % period_samples``. `JointLog.select` and `JointLog.reorder` return a
    `SimulatedLog` whose ground truth (the ``*_true`` arrays; with `reorder` also the noise,
    the effects and the trajectory) stays aligned with the measured signals. Construct it
    with keywords.

    Attributes:
        robot: the robot's name.
        joint_names: ``(n_dof,)`` joint names.
        t: ``(n,)`` times, s.
        q: ``(n, n_dof)`` measured positions (true + noise), rad.
        qd: ``(n, n_dof)`` velocities, rad/s: measured, or differentiated from q.
        qdd: ``(n, n_dof)`` accelerations from numerical differentiation, rad/s^2 (they
            differ from qdd_true by the sample-and-hold ripple, see `generate_log`).
        tau: ``(n, n_dof)`` measured torques, N m: the applied torque averaged over the
            sampling interval centred on each sample, plus noise (`generate_log`).
        q_true, qd_true: ``(n, n_dof)`` the noiseless state.
        qdd_true: ``(n, n_dof)`` the simulator's acceleration at each sample (``data.qacc``).
        tau_true: ``(n, n_dof)`` the torque commanded at each sample and held over the next
            step, exact with ``q_true``, ``qd_true`` and ``qdd_true``.
        period_samples: samples per excitation period (None after a `select` that is not a
            contiguous slice).
        control_rate: sampling and control rate, Hz.
        noise: the `SensorNoise` used.
        seed: the seed, or None.
        effects: joint effects in the simulation, name -> ``(n_dof,)`` array.
        trajectory: the excitation.
        velocity_source: ``"sensor"`` or ``"differentiate"``.
        diff_method: the differentiation method.
        diff_cutoff_hz: its cut-off, Hz (None: no filter).
    """

    robot: str
    qd: torch.Tensor
    qdd: torch.Tensor
    q_true: torch.Tensor
    qd_true: torch.Tensor
    qdd_true: torch.Tensor
    tau_true: torch.Tensor
    control_rate: float
    noise: SensorNoise
    seed: int | None
    effects: dict[str, np.ndarray] = field(default_factory=dict)
    trajectory: SinusoidTrajectory | None = None
    velocity_source: str = "sensor"
    diff_method: str = "butterworth"
    diff_cutoff_hz: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.qd is None or self.qdd is None:
            raise ValueError("a SimulatedLog has velocities and accelerations: pass qd and qdd")
        n_dof = len(self.joint_names)
        n = self.t.shape[0]
        for name in _TRUTH:
            v = torch.as_tensor(getattr(self, name), dtype=torch.float64).cpu()
            if tuple(v.shape) != (n, n_dof):
                raise ValueError(f"{name} must have shape ({n}, {n_dof}), got {tuple(v.shape)}")
            setattr(self, name, v)
        if self.period_samples is not None and self.period_samples < 1:
            raise ValueError(f"period_samples must be positive, got {self.period_samples}")

    def _sample_arrays(self) -> dict[str, torch.Tensor]:
        return {**super()._sample_arrays(), **{k: getattr(self, k) for k in _TRUTH}}

    def _joint_fields(self, perm: list[int]) -> dict:
        out = super()._joint_fields(perm)
        out["noise"] = self.noise.permuted(perm)
        out["effects"] = {k: np.asarray(v)[perm] for k, v in self.effects.items()}
        if self.trajectory is not None:
            tr = self.trajectory
            out["trajectory"] = SinusoidTrajectory(
                tr.base_frequency,
                tr.offset[perm],
                tr.amplitude[perm],
                tr.harmonic[perm],
                tr.phase[perm],
            )
        return out

    def save(self, path: str | os.PathLike) -> None:
        """Write the log to ``path`` in the module's ``.npz`` format (compressed)."""
        n_dof = self.n_dof
        pos, vel, trq = self.noise.per_joint(n_dof)
        period = -1 if self.period_samples is None else self.period_samples
        arrays: dict[str, np.ndarray] = {
            "format": np.array(_FORMAT),
            "version": np.array(_VERSION, dtype=np.int64),
            "robot": np.array(self.robot),
            "joint_names": np.array(self.joint_names, dtype=np.str_),
            "t": self.t.detach().cpu().numpy(),
            "period_samples": np.array(period, dtype=np.int64),
            "control_rate": np.array(self.control_rate, dtype=np.float64),
            "seed": np.array(-1 if self.seed is None else self.seed, dtype=np.int64),
            "noise_position": pos,
            "noise_velocity": vel,
            "noise_torque": trq,
            "velocity_source": np.array(self.velocity_source),
            "diff_method": np.array(self.diff_method),
            "diff_cutoff_hz": np.array(
                np.nan if self.diff_cutoff_hz is None else self.diff_cutoff_hz, dtype=np.float64
            ),
        }
        for name in _SIGNALS:
            arrays[name] = getattr(self, name).detach().cpu().numpy()
        for name in _EFFECTS:
            if name in self.effects:
                arrays[f"effect_{name}"] = np.asarray(self.effects[name], dtype=np.float64)
        if self.trajectory is not None:
            tr = self.trajectory
            arrays["traj_base_frequency"] = np.array(tr.base_frequency, dtype=np.float64)
            arrays["traj_offset"] = tr.offset
            arrays["traj_amplitude"] = tr.amplitude
            arrays["traj_harmonic"] = tr.harmonic.astype(np.int64)
            arrays["traj_phase"] = tr.phase
        with atomic_file(path) as tmp, open(tmp, "wb") as fh:  # whole, or not at all
            np.savez_compressed(fh, **arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> SimulatedLog:
        """Read a log written by `save`.

        Raises:
            FileNotFoundError: if the file does not exist.
            ValueError: if the file is not a `SimulatedLog` file of a known version.
        """
        archive = NpzArchive(path)
        if not _is_simulated(archive):
            raise ValueError(f"{os.fspath(path)!r} is not a torchjfa SimulatedLog .npz file")
        data = archive.arrays()
        if int(data["version"]) != _VERSION:
            raise ValueError(f"unsupported SimulatedLog version {int(data['version'])}")
        period = int(data["period_samples"])
        seed = int(data["seed"])
        cutoff = float(data["diff_cutoff_hz"])
        trajectory = None
        if "traj_offset" in data:
            trajectory = SinusoidTrajectory(
                base_frequency=float(data["traj_base_frequency"]),
                offset=data["traj_offset"],
                amplitude=data["traj_amplitude"],
                harmonic=data["traj_harmonic"],
                phase=data["traj_phase"],
            )

        def tensor(k):
            return torch.as_tensor(data[k], dtype=torch.float64)

        return cls(
            robot=str(data["robot"]),
            joint_names=tuple(str(s) for s in data["joint_names"]),
            t=tensor("t"),
            **{k: tensor(k) for k in _SIGNALS},
            period_samples=None if period < 0 else period,
            control_rate=float(data["control_rate"]),
            noise=SensorNoise(
                tuple(data["noise_position"].tolist()),
                tuple(data["noise_velocity"].tolist()),
                tuple(data["noise_torque"].tolist()),
            ),
            seed=None if seed < 0 else seed,
            effects={k: data[f"effect_{k}"] for k in _EFFECTS if f"effect_{k}" in data},
            trajectory=trajectory,
            velocity_source=str(data["velocity_source"]),
            diff_method=str(data["diff_method"]),
            diff_cutoff_hz=None if np.isnan(cutoff) else cutoff,
            source=archive.path,
        )


def _is_simulated(archive: NpzArchive) -> bool:
    return "format" in archive and str(archive.arrays(["format"])["format"]) == _FORMAT


def load_log(path: str | os.PathLike, **read_options) -> JointLog:
    """Read a log file: a `SimulatedLog` file as a `SimulatedLog`, any other as a `JointLog`.

    Args:
        path: a `SimulatedLog.save` file, or a CSV, NPZ or Parquet log.
        read_options: keywords of `torchjfa.data.read_log` (``columns``, ``time_scale``, ...)
            for a file that is not a `SimulatedLog`.

    Raises:
        FileNotFoundError, ValueError: as `SimulatedLog.load` and `torchjfa.data.read_log`.
    """
    path = os.fspath(path)
    if path.lower().endswith(".npz") and _is_simulated(NpzArchive(path)):
        return SimulatedLog.load(path)
    return read_log(path, **read_options)

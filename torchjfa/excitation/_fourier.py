"""Periodic excitation trajectories as finite Fourier series (Swevers et al. 1997).

Joint j follows

    q_j(t) = c_j + sum_{k=1..H} a_jk / (w k) sin(w k t) - b_jk / (w k) cos(w k t),   w = 2 pi f0,

so ``qd_j = sum_k a_jk cos(w k t) + b_jk sin(w k t)`` and
``qdd_j = sum_k w k (b_jk cos(w k t) - a_jk sin(w k t))``, periodic with period ``1 / f0``.
The trajectory starts and ends each period at rest at the posture ``q0``: `constrain_coefficients`
maps free coefficients to ones with ``sum_k a_jk = 0`` (qd(0) = 0) and ``sum_k k b_jk = 0``
(qdd(0) = 0) by an orthogonal projection (linear, so autograd sees it), and the offset is
``c_j = q0_j + sum_k b_jk / (w k)`` (q(0) = q0). These hold to rounding for every coefficient
vector, so the optimiser never has to enforce them.

Swevers, Ganseman, Tukel, De Schutter and Van Brussel, *Optimal robot excitation and
identification*, IEEE Trans. Robotics and Automation 13(5), 1997.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import torch

from .._validation import as_tensor
from ..data._joints import permutation
from ..sim import SinusoidTrajectory

__all__ = ["FourierTrajectory", "constrain_coefficients", "fourier_states"]

_FORMAT = "torchjfa.FourierTrajectory"


def constrain_coefficients(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Project free coefficients onto those of a trajectory at rest at t = 0.

    Args:
        a: ``(..., n_dof, H)`` free sine coefficients, rad/s (H >= 2).
        b: ``(..., n_dof, H)`` free cosine coefficients, rad/s.

    Returns:
        ``(a, b)`` of the same shape with ``sum_k a_jk = 0`` and ``sum_k k b_jk = 0`` for every
        joint: the closest such coefficients in the Euclidean norm.
    """
    H = a.shape[-1]
    k = torch.arange(1, H + 1, dtype=b.dtype, device=b.device)
    a = a - a.mean(-1, keepdim=True)
    b = b - k * ((b * k).sum(-1, keepdim=True) / (k * k).sum())
    return a, b


def fourier_states(
    t: torch.Tensor, posture: torch.Tensor, a: torch.Tensor, b: torch.Tensor, base_frequency
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """q, qd, qdd of the Fourier series at times t (differentiable in every tensor).

    Args:
        t: ``(n,)`` s.
        posture: ``(n_dof,)`` q0, rad (or m).
        a: ``(n_dof, H)`` sine coefficients (as given; see `constrain_coefficients`).
        b: ``(n_dof, H)`` cosine coefficients.
        base_frequency: f0, Hz.

    Returns:
        ``(q, qd, qdd)``, each ``(n, n_dof)``.
    """
    H = a.shape[-1]
    w = 2.0 * math.pi * float(base_frequency)
    wk = w * torch.arange(1, H + 1, dtype=a.dtype, device=a.device)  # (H,) rad/s
    arg = t[:, None] * wk  # (n, H)
    s, c = torch.sin(arg), torch.cos(arg)
    offset = posture + (b / wk).sum(-1)  # (n_dof,)
    q = offset + s @ (a / wk).T - c @ (b / wk).T
    qd = c @ a.T + s @ b.T
    qdd = c @ (b * wk).T - s @ (a * wk).T
    return q, qd, qdd


@dataclass(frozen=True)
class FourierTrajectory:
    """A periodic Fourier-series joint trajectory at rest at ``posture`` at t = 0 (and T, 2T...).

    Attributes:
        base_frequency: f0, Hz; the period is ``1 / f0``.
        posture: ``(n_dof,)`` q0, rad (m for prismatic joints).
        a: ``(n_dof, H)`` sine coefficients, rad/s (constrained: see the module).
        b: ``(n_dof, H)`` cosine coefficients, rad/s.
        joint_names: the joints, in the order of the columns.
    """

    base_frequency: float
    posture: np.ndarray
    a: np.ndarray
    b: np.ndarray
    joint_names: tuple[str, ...]

    def __post_init__(self) -> None:
        f0 = float(self.base_frequency)
        if not math.isfinite(f0) or f0 <= 0:
            raise ValueError(f"base_frequency must be positive, got {self.base_frequency}")
        q0 = np.asarray(self.posture, dtype=np.float64)
        a = np.asarray(self.a, dtype=np.float64)
        b = np.asarray(self.b, dtype=np.float64)
        if q0.ndim != 1 or a.ndim != 2 or a.shape != b.shape or a.shape[0] != q0.shape[0]:
            raise ValueError(
                f"posture must be (n_dof,), a and b (n_dof, H); got {q0.shape}, {a.shape}, "
                f"{b.shape}"
            )
        if a.shape[1] < 2:
            raise ValueError("a trajectory at rest at t = 0 needs at least 2 harmonics")
        names = tuple(str(n) for n in self.joint_names)
        if len(names) != q0.shape[0]:
            raise ValueError(f"{len(names)} joint names for {q0.shape[0]} joints")
        for name, v in (("posture", q0), ("a", a), ("b", b)):
            if not np.all(np.isfinite(v)):
                raise ValueError(f"{name} has NaN or infinite entries")
        object.__setattr__(self, "base_frequency", f0)
        object.__setattr__(self, "posture", q0)
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "joint_names", names)

    @property
    def n_dof(self) -> int:
        return self.posture.shape[0]

    @property
    def harmonics(self) -> int:
        return self.a.shape[1]

    @property
    def period(self) -> float:
        """T = 1 / f0, s."""
        return 1.0 / self.base_frequency

    def __call__(self, t) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """q, qd, qdd at times ``t (n,)`` s, each ``(n, n_dof)``, in t's dtype (float64 default)."""
        t = as_tensor(t, name="t")
        if t.ndim != 1:
            raise ValueError(f"t must be 1-D with shape (n,), got {tuple(t.shape)}")
        kw = {"dtype": t.dtype, "device": t.device}
        return fourier_states(
            t,
            torch.as_tensor(self.posture, **kw),
            torch.as_tensor(self.a, **kw),
            torch.as_tensor(self.b, **kw),
            self.base_frequency,
        )

    def evaluate_numpy(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, qd, qdd at times ``t (n,)`` as float64 numpy arrays ``(n, n_dof)``."""
        out = self(torch.as_tensor(np.asarray(t, dtype=np.float64)))
        return tuple(v.numpy() for v in out)

    def scaled(self, factor: float) -> FourierTrajectory:
        """The same motion shrunk about the posture: ``q - q0``, qd and qdd times ``factor``."""
        return FourierTrajectory(
            self.base_frequency,
            self.posture,
            self.a * factor,
            self.b * factor,
            self.joint_names,
        )

    def reorder(self, joint_names, *, owner: str = "the robot") -> FourierTrajectory:
        """The same trajectory with its joints in the order of ``joint_names``.

        Args:
            joint_names: ``(n_dof,)`` the joint order wanted (a robot's).
            owner: whose joints they are, for the message.

        Raises:
            ValueError: if the two lists are not the same joints (the message names them).
        """
        perm = permutation(
            self.joint_names, joint_names, have_name="the trajectory", want_name=owner
        )
        names = tuple(self.joint_names[i] for i in perm)
        return FourierTrajectory(
            self.base_frequency, self.posture[perm], self.a[perm], self.b[perm], names
        )

    def to_sinusoid(self) -> SinusoidTrajectory:
        """The same trajectory as a `torchjfa.sim.SinusoidTrajectory` (what `generate_log` runs).

        ``a/(wk) sin x - b/(wk) cos x = A sin(x + phi)`` with ``A = hypot(a, b) / (wk)`` and
        ``phi = atan2(-b, a)``.
        """
        w = 2.0 * np.pi * self.base_frequency
        k = np.arange(1, self.harmonics + 1)
        wk = w * k
        return SinusoidTrajectory(
            base_frequency=self.base_frequency,
            offset=self.posture + (self.b / wk).sum(-1),
            amplitude=np.hypot(self.a, self.b) / wk,
            harmonic=np.broadcast_to(k, self.a.shape).copy(),
            phase=np.arctan2(-self.b, self.a),
        )

    # ------------------------------------------------------------------ files
    def arrays(self) -> dict[str, np.ndarray]:
        """The coefficients as the ``.npz`` keys `save` writes."""
        return {
            "format": np.array(_FORMAT),
            "base_frequency": np.array(self.base_frequency),
            "posture": self.posture,
            "a": self.a,
            "b": self.b,
            "coefficient_joint_names": np.array(self.joint_names),
        }

    def save(self, path: str | os.PathLike, **extra) -> None:
        """Write the coefficients (and any ``extra`` arrays) to an ``.npz`` file."""
        np.savez(path, **self.arrays(), **extra)

    @classmethod
    def load(cls, path: str | os.PathLike) -> FourierTrajectory:
        """Read a trajectory written by `save` (or by ``torchjfa excite``).

        Raises:
            ValueError: if the file holds no Fourier trajectory.
        """
        with np.load(path, allow_pickle=False) as z:
            if "format" not in z.files or str(z["format"]) != _FORMAT:
                raise ValueError(
                    f"{os.fspath(path)!r} is not a trajectory written by torchjfa excite "
                    f"(no format key {_FORMAT!r})"
                )
            return cls(
                float(z["base_frequency"]),
                z["posture"],
                z["a"],
                z["b"],
                tuple(str(s) for s in z["coefficient_joint_names"]),
            )

"""Physical consistency checks of a parameter vector theta, body by body.

`check` tells whether identified parameters describe real rigid bodies: positive mass, a
positive semidefinite inertia at the centre of mass, the triangle inequalities of its principal
moments, a positive definite pseudo-inertia (Wensing, Kim and Slotine, "Linear matrix
inequalities for physically consistent inertial parameter identification", RA-L 2018) and
non-negative viscous and Coulomb friction. Use it on any estimator's output, before and after
`torchjfa.physical.project`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ._parameters import inertia_about_origin, pseudo_inertia
from ._parametrizations import (
    _check_theta,
    _parallel_axis_term,
    _power_of_two_scale,
    resolve_layout,
)

__all__ = ["ConsistencyReport", "check"]


@dataclass(frozen=True)
class ConsistencyReport:
    """Result of `check`; per-body tensors have a leading dimension ``n_joints``.

    Attributes:
        joint_names: the joints, in layout order.
        mass: ``(n_joints,)`` kg.
        principal_moments: ``(n_joints, 3)`` eigenvalues of the inertia at the centre of mass,
            ascending, kg m^2 (NaN where the mass is not positive).
        triangle_margin: ``(n_joints,)`` ``I1 + I2 - I3`` of the sorted principal moments, the
            binding triangle inequality (NaN where the mass is not positive).
        pseudo_inertia_min_eig: ``(n_joints,)`` smallest eigenvalue of the 4x4 pseudo-inertia.
        friction: ``(n_joints, n_friction)``.
        mass_ok, inertia_ok, triangle_ok, pseudo_inertia_ok, friction_ok: ``(n_joints,)`` bool.
        tol: the relative tolerance used.
    """

    joint_names: tuple[str, ...]
    friction_names: tuple[str, ...]
    mass: torch.Tensor
    principal_moments: torch.Tensor
    triangle_margin: torch.Tensor
    pseudo_inertia_min_eig: torch.Tensor
    friction: torch.Tensor
    mass_ok: torch.Tensor
    inertia_ok: torch.Tensor
    triangle_ok: torch.Tensor
    pseudo_inertia_ok: torch.Tensor
    friction_ok: torch.Tensor
    tol: float

    @property
    def body_ok(self) -> torch.Tensor:
        """``(n_joints,)`` every condition holds for the body (full physical consistency)."""
        return (
            self.mass_ok
            & self.inertia_ok
            & self.triangle_ok
            & self.pseudo_inertia_ok
            & self.friction_ok
        )

    @property
    def body_weakly_ok(self) -> torch.Tensor:
        """``(n_joints,)`` mass, inertia at the centre of mass and friction hold (what the
        paper's eq. 5 guarantees; the triangle inequalities are not required)."""
        return self.mass_ok & self.inertia_ok & self.friction_ok

    @property
    def ok(self) -> bool:
        """All conditions hold for all bodies."""
        return bool(self.body_ok.all())

    @property
    def weakly_ok(self) -> bool:
        """`body_weakly_ok` holds for all bodies."""
        return bool(self.body_weakly_ok.all())

    def table(self) -> str:
        """A readable table, one row per body."""
        head = (
            f"{'joint':<16} {'mass':>10} {'min I_c eig':>12} {'triangle':>11} "
            f"{'min J eig':>11} {'friction':>9}  ok"
        )
        lines = [head, "-" * len(head)]
        for j, name in enumerate(self.joint_names):
            fr = "yes" if bool(self.friction_ok[j]) else "NEG"
            flags = [
                ("m", self.mass_ok[j]),
                ("I", self.inertia_ok[j]),
                ("tri", self.triangle_ok[j]),
                ("J", self.pseudo_inertia_ok[j]),
                ("f", self.friction_ok[j]),
            ]
            failed = [k for k, v in flags if not bool(v)]
            verdict = "yes" if not failed else "no (" + ",".join(failed) + ")"
            lines.append(
                f"{name[:16]:<16} {float(self.mass[j]):>10.4g} "
                f"{float(self.principal_moments[j, 0]):>12.4g} "
                f"{float(self.triangle_margin[j]):>11.4g} "
                f"{float(self.pseudo_inertia_min_eig[j]):>11.4g} {fr:>9}  {verdict}"
            )
        n_bad = int((~self.body_ok).sum())
        lines.append(
            f"physically consistent: {'yes' if self.ok else 'no'} "
            f"({n_bad} of {len(self.joint_names)} bodies fail; tol={self.tol:g})"
        )
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.table()


def check(theta, layout, *, tol: float = 1e-9) -> ConsistencyReport:
    """Check the physical consistency of every body of ``theta``.

    Conditions per body (``tol`` is relative to the body's own scale, so that parameters on the
    boundary of the consistent set, e.g. after a projection, pass despite rounding):

    - mass ``m > 0`` (strict; the centre of mass is undefined otherwise);
    - inertia at the centre of mass ``I_c = I_o - m (|c|^2 1 - c c^T)`` positive semidefinite:
      smallest eigenvalue ``>= -tol * s`` with ``s = max |eig(I_c)| + m |c|^2`` (the size of
      the terms whose difference is I_c);
    - triangle inequalities of the principal moments ``I1 + I2 >= I3`` (sorted):
      ``I1 + I2 - I3 >= -tol * s``;
    - pseudo-inertia ``J = [[tr(I_o)/2 1 - I_o, m c], [m c^T, m]]`` positive definite:
      smallest eigenvalue ``> -tol * max eig`` (with ``tol=0``, strictly positive);
    - viscous and Coulomb friction ``>= -tol * max |friction|`` (an offset may have any sign).

    Any magnitude works: each body is checked in units of its largest entry, and the condition
    on ``I_c`` is tested as ``m I_c = m I_o - (|h|^2 1 - h h^T)`` (``h = m c``), with no
    division by m, so that a mass of 5e-181 kg whose first moment stayed O(1) (a centre of mass
    1e180 m away: what a relevance prior leaves of an unidentifiable link) is reported
    inconsistent, with principal moments of -1e179 kg m^2, instead of overflowing.

    Args:
        theta: shape ``(n_params,)``.
        layout: a `ParameterLayout` or an object with a ``.layout`` attribute.
        tol: relative tolerance, non-negative.

    Returns:
        A `ConsistencyReport`; ``report.ok`` is True when every condition holds for every body,
        ``str(report)`` is a table.
    """
    layout = resolve_layout(layout)
    theta = _check_theta(theta, layout).detach()
    if not float(tol) >= 0:
        raise ValueError(f"tol must be non-negative, got {tol}")
    tol = float(tol)
    inertial, friction = layout.split(theta.to(torch.float64))
    mass = inertial[:, 0]
    mass_ok = mass > 0
    # each body in units of its largest entry (a power of two: exact), so that a body of 1e300
    # kg, or one whose mass the data shrank to 5e-181 kg while its first moment h stayed O(1),
    # neither overflows nor underflows; moments and eigenvalues are scaled back at the end
    unit = _power_of_two_scale(inertial)  # (n_joints,)
    pi = inertial / unit[:, None]
    m, h = pi[:, 0], pi[:, 1:4]
    # m I_c = m I_o - (|h|^2 1 - h h^T) with no division by m (the centre of mass h / m
    # overflows for a vanishing mass): for m > 0 it is PSD exactly when I_c is, and its
    # eigenvalues are m times I_c's
    k = m[:, None, None] * inertia_about_origin(pi) - _parallel_axis_term(h)
    k_eigs = torch.linalg.eigvalsh(0.5 * (k + k.transpose(-1, -2)))  # (n_joints, 3)
    # I_c is I_o minus the parallel-axis term m |c|^2: rounding errors scale with both (times m)
    scale = k_eigs.abs().amax(-1) + (h * h).sum(-1)
    inertia_ok = mass_ok & (k_eigs[:, 0] >= -tol * scale)
    k_margin = k_eigs[:, 0] + k_eigs[:, 1] - k_eigs[:, 2]
    triangle_ok = mass_ok & (k_margin >= -tol * scale)
    per_mass = unit / torch.where(mass_ok, m, torch.ones_like(m))  # kg m^2 per unit of k
    nan = torch.full_like(k_eigs, float("nan"))
    moments = torch.where(mass_ok[:, None], k_eigs * per_mass[:, None], nan)
    margin = torch.where(mass_ok, k_margin * per_mass, nan[:, 0])

    J = pseudo_inertia(pi)
    j_eigs = torch.linalg.eigvalsh(0.5 * (J + J.transpose(-1, -2)))
    pseudo_ok = j_eigs[:, 0] > -tol * j_eigs[:, -1].clamp_min(0)

    signed = torch.tensor(
        [kind != "offset" for kind in layout.friction], dtype=torch.bool, device=theta.device
    )
    fscale = friction.abs().amax() if friction.numel() else friction.new_zeros(())
    friction_ok = ((friction >= -tol * fscale) | ~signed).all(-1)

    return ConsistencyReport(
        joint_names=layout.joint_names,
        friction_names=layout.friction,
        mass=mass,
        principal_moments=moments,
        triangle_margin=margin,
        pseudo_inertia_min_eig=j_eigs[:, 0] * unit,
        friction=friction,
        mass_ok=mass_ok,
        inertia_ok=inertia_ok,
        triangle_ok=triangle_ok,
        pseudo_inertia_ok=pseudo_ok,
        friction_ok=friction_ok,
        tol=tol,
    )

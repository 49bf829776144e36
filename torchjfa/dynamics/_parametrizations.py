"""Parametrisations of theta that are physically consistent for every value of their variables.

Two ``nn.Module`` s map free (unconstrained) variables to the parameter vector theta of a
`ParameterLayout` (see `torchjfa.dynamics`), so that a gradient-based optimiser on the free
variables can never leave the set of consistent parameters:

- `VirtualParameters`: the paper's eq. 5 (Ting, Mistry, Peters, Schaal and Nakanishi,
  "A Bayesian approach to nonlinear parameter identification for rigid body dynamics", 2006),
  11 "virtual" parameters per joint: mass ``m = phi1^2``, centre of mass ``c = (phi2, phi3,
  phi4)``, inertia at the centre of mass ``I_c = L L^T`` with
  ``L = [[phi5, 0, 0], [phi6, phi8, 0], [phi7, phi9, phi10]]`` and viscous friction
  ``fv = phi11^2``. Guarantees ``m >= 0``, ``I_c`` positive semidefinite and ``fv >= 0``; it does
  *not* guarantee the triangle inequalities of the principal moments.
- `LogCholeskyParameters`: the log-Cholesky parametrisation of the pseudo-inertia (Rucker and
  Wensing, "Smooth parameterization of rigid-body inertia", IEEE RA-L 2022):
  ``J = U U^T`` with ``U = exp(alpha) [[e^d1, s12, s13, t1], [0, e^d2, s23, t2],
  [0, 0, e^d3, t3], [0, 0, 0, 1]]``, 10 variables per body in the order
  ``(alpha, d1, d2, d3, s12, s23, s13, t1, t2, t3)``. ``J`` is positive definite for every value,
  which is full physical consistency: positive mass, positive definite inertia and the triangle
  inequalities.

In both, friction terms follow the 10 inertial variables: viscous and Coulomb friction are
squares of their variable, an offset term is the variable itself. Use these modules directly to
learn consistent dynamics parameters by gradient descent; use `torchjfa.physical.project` to turn
an unconstrained estimate into a consistent one.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .._validation import as_tensor, check_finite
from ._parameters import (
    ParameterLayout,
    inertia_about_origin,
    pseudo_inertia,
)

__all__ = [
    "VirtualParameters",
    "LogCholeskyParameters",
    "inertial_from_virtual",
    "inertial_from_log_cholesky",
    "inertial_from_pseudo_inertia",
    "resolve_layout",
]

# relative floors used to move an inconsistent theta to a nearby interior point
_MIN_MASS_FRACTION = 1e-3
_MIN_EIG_FRACTION = 1e-3
_MIN_FRICTION_FRACTION = 1e-3


def resolve_layout(layout) -> ParameterLayout:
    """A `ParameterLayout`, or any object with a ``.layout`` attribute (e.g. a robot model)."""
    if isinstance(layout, ParameterLayout):
        return layout
    inner = getattr(layout, "layout", None)
    if isinstance(inner, ParameterLayout):
        return inner
    raise TypeError(
        "layout must be a ParameterLayout or an object with a .layout ParameterLayout "
        f"(e.g. a RigidBodyModel), got {type(layout).__name__}"
    )


def _check_theta(theta, layout: ParameterLayout, name: str = "theta") -> torch.Tensor:
    theta = as_tensor(theta, name=name)
    if theta.ndim != 1 or theta.shape[0] != layout.n_params:
        raise ValueError(
            f"{name} must have shape ({layout.n_params},) for this layout "
            f"({layout.n_joints} joints x {layout.params_per_joint} parameters), "
            f"got {tuple(theta.shape)}"
        )
    check_finite(theta, name)
    return theta


def _power_of_two_scale(x: torch.Tensor, dim=-1) -> torch.Tensor:
    """The even power of two nearest ``max |x|`` over ``dim`` (1 where that is 0 or not finite).

    Dividing by it is exact, and so is its square root, so normalising a body (or a whole
    theta) by it and scaling back changes no digit; it brings the largest entry to [0.5, 2], so
    that products, squares and eigen-decompositions of bodies of 1e-300 or 1e300 kg neither
    underflow nor overflow.
    """
    big = x.abs().amax(dim)
    ok = torch.isfinite(big) & (big > 0)
    exponent = 2 * torch.round(0.5 * torch.log2(torch.where(ok, big, torch.ones_like(big))))
    return torch.where(ok, torch.exp2(exponent), torch.ones_like(big))


# ---------------------------------------------------------------------------------- friction
def _friction_signs(layout: ParameterLayout) -> list[bool]:
    """For each friction term of a joint: True when it must be non-negative (a square)."""
    return [kind != "offset" for kind in layout.friction]


def _friction_forward(psi: torch.Tensor, layout: ParameterLayout) -> torch.Tensor:
    """``(..., n_joints, n_friction)`` free variables -> friction parameters."""
    if all(_friction_signs(layout)):
        return psi * psi
    squared = torch.tensor(_friction_signs(layout), device=psi.device)
    return torch.where(squared, psi * psi, psi)


def _friction_inverse(friction: torch.Tensor, layout: ParameterLayout) -> torch.Tensor:
    """Friction parameters -> free variables; negative viscous/Coulomb terms are raised to a
    small positive value (a fraction of the mean magnitude of that term over the joints)."""
    cols = []
    for k, squared in enumerate(_friction_signs(layout)):
        f = friction[..., k]
        if squared:
            scale = f.abs().mean()
            floor = _MIN_FRICTION_FRACTION * torch.where(scale > 0, scale, torch.ones_like(scale))
            f = torch.where(f < 0, floor.expand_as(f), f)
            cols.append(f.sqrt())
        else:
            cols.append(f)
    if not cols:
        return friction
    return torch.stack(cols, -1)


# ---------------------------------------------------------------------------------- eq. 5
def _parallel_axis_term(com: torch.Tensor) -> torch.Tensor:
    """``|c|^2 1 - c c^T`` for ``com (..., 3)`` -> ``(..., 3, 3)``."""
    eye = torch.eye(3, dtype=com.dtype, device=com.device)
    return (com * com).sum(-1)[..., None, None] * eye - com[..., :, None] * com[..., None, :]


_TRIL = ((0, 0), (1, 0), (2, 0), (1, 1), (2, 1), (2, 2))  # phi5..phi10 -> L entries
# flat 3x3 index -> column of (phi5..phi10), upper entries masked to zero
_L_GATHER = (0, 0, 0, 1, 3, 0, 2, 4, 5)
_L_MASK = (1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 1.0, 1.0, 1.0)
# flat 3x3 indices of xx, xy, yy, xz, yz, zz (Pinocchio's order)
_SIX_FLAT = (0, 1, 4, 2, 5, 8)


def _lower_from_six(v: torch.Tensor) -> torch.Tensor:
    """``(..., 6)`` = (phi5, phi6, phi7, phi8, phi9, phi10) -> lower triangular ``(..., 3, 3)``."""
    idx = torch.tensor(_L_GATHER, device=v.device)
    mask = torch.tensor(_L_MASK, dtype=v.dtype, device=v.device)
    return (v[..., idx] * mask).reshape(*v.shape[:-1], 3, 3)


def inertial_from_virtual(phi: torch.Tensor) -> torch.Tensor:
    """Eq. 5 of the paper: ``(..., 10)`` virtual parameters -> ``(..., 10)`` inertial
    parameters ``[m, m c, I_o]`` (Pinocchio's order), with ``m = phi1^2``, ``c = phi2..4``,
    ``I_c = L L^T`` and ``I_o = I_c + m (|c|^2 1 - c c^T)``."""
    mass = phi[..., :1] ** 2  # (..., 1)
    com = phi[..., 1:4]
    lower = _lower_from_six(phi[..., 4:10])
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device)
    # I_o = L L^T + m (|c|^2 1 - c c^T)
    inertia = lower @ lower.transpose(-1, -2) + mass[..., None] * (
        (com * com).sum(-1, keepdim=True)[..., None] * eye - com[..., :, None] * com[..., None, :]
    )
    six = inertia.reshape(*phi.shape[:-1], 9)[..., torch.tensor(_SIX_FLAT, device=phi.device)]
    return torch.cat([mass, mass * com, six], -1)


def _lower_factor(psd: torch.Tensor) -> torch.Tensor:
    """A lower triangular ``L`` with ``L L^T = psd`` for positive semidefinite ``(..., 3, 3)``.

    Cholesky where it succeeds (exact for positive definite matrices); otherwise from a
    symmetric square root ``B`` (``B B^T = psd``) by a QR decomposition ``B^T = Q R``, so that
    ``psd = R^T R`` with ``R^T`` lower triangular.
    """
    lower, info = torch.linalg.cholesky_ex(psd)
    bad = info != 0
    if bool(bad.any()):
        evals, evecs = torch.linalg.eigh(psd[bad])
        root = evecs * evals.clamp_min(0).sqrt()[..., None, :]
        _, r = torch.linalg.qr(root.transpose(-1, -2))
        lower = lower.clone()
        lower[bad] = r.transpose(-1, -2)
    return lower


def virtual_from_inertial(pi: torch.Tensor) -> torch.Tensor:
    """Inverse of `inertial_from_virtual` for ``pi (n_bodies, 10)``; exact for consistent bodies.

    A body is left exactly as it is when ``m > 0`` and ``I_c`` is positive semidefinite.
    Otherwise it is moved to a nearby consistent point: the mass is raised to at least a small
    fraction (1e-3) of the mean absolute mass over the bodies; a mass too small for the body's
    first moment ``h`` (the centre of mass ``h / m`` outside the radius ``sqrt(tr(I_o) / (2 m))``
    beyond which ``tr(I_c) < 0``, e.g. a mass the data shrank to 5e-181 kg while ``h`` stayed
    O(1)) is raised to ``4 |h|^2 / tr(I_o)``, which keeps ``h`` and puts the centre of mass at
    ``1/sqrt(2)`` of that radius; a centre of mass that is still outside (``tr(I_o) <= 0``) is
    pulled in to the radius; and the eigenvalues of ``I_c`` are raised to at least 1e-3 of its
    largest absolute eigenvalue. Each body is worked on in units of its largest entry, so that
    no magnitude (0, 1e-300 or 1e300 kg) overflows: the result is always finite.
    """
    unit = _power_of_two_scale(pi)  # (n_bodies,) exact powers of two
    p = pi / unit[..., None]
    mass, h = p[..., 0], p[..., 1:4]
    inertia_o = inertia_about_origin(p)
    trace = torch.diagonal(inertia_o, dim1=-2, dim2=-1).sum(-1)
    scale = pi[..., 0].abs().mean()
    floor = _MIN_MASS_FRACTION * torch.where(scale > 0, scale, torch.ones_like(scale)) / unit
    # in these units |h| <= 1: a floor of 1e-12 keeps h / m <= 1e12 (no overflow in |c|^2)
    floor = floor.clamp(1e-12, 1e12)
    h2 = (h * h).sum(-1)
    # the smallest mass whose centre of mass h / m lies within the trace radius, doubled
    needed = torch.where(trace > 0, 4 * h2 / torch.where(trace > 0, trace, 1.0), 0.0)
    # (a point mass sits on that radius: the 1e-9 spares it from rounding)
    too_small = (mass <= 0) | ((trace > 0) & (2 * mass * (1 + 1e-9) < needed))
    mass0 = torch.where(mass > 0, mass, floor)
    mass0 = torch.where(too_small, torch.maximum(mass0, torch.maximum(needed, floor)), mass0)
    com = h / mass0[..., None]
    # |c|^2 <= tr(I_o) / (2 m) is necessary for tr(I_c) >= 0
    radius = (trace.clamp_min(0) / (2 * mass0)).sqrt()
    norm = com.norm(dim=-1)
    shrink = torch.where(
        ~too_small | (norm <= radius), torch.ones_like(norm), radius / norm.clamp_min(1e-300)
    )
    com = com * shrink[..., None]
    inertia_c = inertia_o - mass0[..., None, None] * _parallel_axis_term(com)
    inertia_c = 0.5 * (inertia_c + inertia_c.transpose(-1, -2))
    evals, evecs = torch.linalg.eigh(inertia_c)
    needs_clip = (evals[..., 0] < 0) | too_small
    if bool(needs_clip.any()):
        big = evals.abs().amax(-1, keepdim=True)
        big = torch.where(big > 0, big, mass0[..., None] * (radius[..., None] ** 2 + 1e-4))
        clipped = torch.maximum(evals, _MIN_EIG_FRACTION * big)
        repaired = (evecs * clipped[..., None, :]) @ evecs.transpose(-1, -2)
        inertia_c = torch.where(needs_clip[..., None, None], repaired, inertia_c)
    lower = _lower_factor(inertia_c)
    six = torch.stack([lower[..., i, j] for i, j in _TRIL], -1)
    root = unit.sqrt()[..., None]  # sqrt(m) and L scale with the square root of the unit
    return torch.cat([(mass0.sqrt()[..., None] * root), com, six * root], -1)


# ---------------------------------------------------------------------------------- log-Cholesky
# U row-major, 16 entries: which variable sits where. Off the diagonal: a column of
# (alpha, d1, d2, d3, s12, s23, s13, t1, t2, t3), masked by _U_OFF; on the first three diagonal
# entries: exp of d1, d2, d3 (_U_DIAG picks which); U[3, 3] = 1.
_U_GATHER = (0, 4, 6, 7, 0, 0, 5, 8, 0, 0, 0, 9, 0, 0, 0, 0)
_U_OFF = (0, 1, 1, 1, 0, 0, 1, 1, 0, 0, 0, 1, 0, 0, 0, 0)
_U_DIAG = (0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 2, 0, 0, 0, 0, 0)
_U_DIAG_MASK = (1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0)
_U_LAST = (0,) * 15 + (1,)


def _upper_from_log_cholesky(p: torch.Tensor) -> torch.Tensor:
    """``(..., 10)`` = (alpha, d1, d2, d3, s12, s23, s13, t1, t2, t3) -> ``U (..., 4, 4)``."""
    kw = {"dtype": p.dtype, "device": p.device}
    off = p[..., torch.tensor(_U_GATHER, device=p.device)] * torch.tensor(_U_OFF, **kw)
    diag = p[..., 1:4].exp()[..., torch.tensor(_U_DIAG, device=p.device)]
    flat = off + diag * torch.tensor(_U_DIAG_MASK, **kw) + torch.tensor(_U_LAST, **kw)
    return p[..., :1, None].exp() * flat.reshape(*p.shape[:-1], 4, 4)


def inertial_from_pseudo_inertia(J: torch.Tensor) -> torch.Tensor:
    """Inverse of `pseudo_inertia`: ``(..., 4, 4)`` -> ``(..., 10)``, with
    ``I = tr(Sigma) 1 - Sigma`` for ``Sigma = J[:3, :3]``."""
    sigma = J[..., :3, :3]
    eye = torch.eye(3, dtype=J.dtype, device=J.device)
    inertia = torch.diagonal(sigma, dim1=-2, dim2=-1).sum(-1)[..., None, None] * eye - sigma
    six = inertia.reshape(*J.shape[:-2], 9)[..., torch.tensor(_SIX_FLAT, device=J.device)]
    return torch.cat([J[..., 3:, 3], J[..., :3, 3], six], -1)


def inertial_from_log_cholesky(p: torch.Tensor) -> torch.Tensor:
    """Rucker and Wensing (2022): ``(..., 10)`` log-Cholesky variables -> inertial parameters of
    the pseudo-inertia ``J = U U^T`` (always positive definite)."""
    upper = _upper_from_log_cholesky(p)
    return inertial_from_pseudo_inertia(upper @ upper.transpose(-1, -2))


def log_cholesky_from_inertial(pi: torch.Tensor) -> torch.Tensor:
    """Inverse of `inertial_from_log_cholesky` for ``pi (n_bodies, 10)``.

    Exact when the pseudo-inertia is positive definite; otherwise its eigenvalues are first
    raised to at least 1e-3 of its largest absolute eigenvalue (a nearby fully consistent body).
    """
    unit = _power_of_two_scale(pi)  # per body, as in virtual_from_inertial: J / unit is O(1)
    J = pseudo_inertia(pi / unit[..., None])
    J = 0.5 * (J + J.transpose(-1, -2))
    flip = torch.flip(torch.flip(J, (-1,)), (-2,))
    lower, info = torch.linalg.cholesky_ex(flip)
    bad = info != 0
    if bool(bad.any()):
        evals, evecs = torch.linalg.eigh(J[bad])
        big = evals.abs().amax(-1, keepdim=True)
        big = torch.where(big > 0, big, torch.ones_like(big))
        clipped = torch.maximum(evals, _MIN_EIG_FRACTION * big)
        repaired = (evecs * clipped[..., None, :]) @ evecs.transpose(-1, -2)
        repaired = 0.5 * (repaired + repaired.transpose(-1, -2))
        lower = lower.clone()
        lower[bad] = torch.linalg.cholesky(torch.flip(torch.flip(repaired, (-1,)), (-2,)))
    # J = P L L^T P with P the reversal: U = P L P is upper triangular and J = U U^T
    upper = torch.flip(torch.flip(lower, (-1,)), (-2,))
    scale = upper[..., 3, 3]
    u = upper / scale[..., None, None]
    diag = torch.diagonal(u, dim1=-2, dim2=-1)[..., :3]
    return torch.stack(
        [
            scale.log() + 0.5 * unit.log(),  # U scales with sqrt(unit): J = unit * J
            diag[..., 0].log(),
            diag[..., 1].log(),
            diag[..., 2].log(),
            u[..., 0, 1],
            u[..., 1, 2],
            u[..., 0, 2],
            u[..., 0, 3],
            u[..., 1, 3],
            u[..., 2, 3],
        ],
        -1,
    )


# ---------------------------------------------------------------------------------- modules
class _ConsistentParameters(nn.Module):
    """Shared machinery: ``phi (n_joints, 10 + n_friction)`` -> theta ``(n_params,)``."""

    _inertial_map = staticmethod(inertial_from_virtual)
    _inverse_map = staticmethod(virtual_from_inertial)
    _variable_names: tuple[str, ...] = ()

    def __init__(
        self,
        layout,
        *,
        phi: torch.Tensor | None = None,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        self.layout = resolve_layout(layout)
        shape = (self.layout.n_joints, self.layout.params_per_joint)
        if phi is None:
            phi = self._default_phi().to(dtype=dtype, device=device)
        else:
            phi = as_tensor(phi, name="phi")
            if tuple(phi.shape) != shape:
                raise ValueError(
                    f"phi must have shape {shape} (n_joints, 10 + n_friction), "
                    f"got {tuple(phi.shape)}"
                )
            check_finite(phi, "phi")
        self.phi = nn.Parameter(phi.detach().clone())

    def _default_phi(self) -> torch.Tensor:  # pragma: no cover - overridden
        raise NotImplementedError

    @property
    def variable_names(self) -> tuple[str, ...]:
        """Names of the columns of ``phi``."""
        return self._variable_names + tuple(f"psi_{f}" for f in self.layout.friction)

    def forward(self) -> torch.Tensor:
        """The consistent parameter vector theta, shape ``(n_params,)``, in ``phi``'s dtype."""
        return self.theta_from_phi(self.phi)

    def theta_from_phi(self, phi: torch.Tensor) -> torch.Tensor:
        """theta for other variables: ``(..., n_joints, 10 + n_friction)`` ->
        ``(..., n_params)``, differentiable (``forward()`` is ``theta_from_phi(self.phi)``)."""
        inertial = self._inertial_map(phi[..., :10])
        friction = _friction_forward(phi[..., 10:], self.layout)
        return self.layout.join(inertial, friction)

    @classmethod
    def from_theta(cls, theta, layout):
        """A module whose `forward` returns ``theta`` (exactly, when ``theta`` is consistent in
        the sense this parametrisation covers) or a nearby consistent point otherwise.

        Args:
            theta: shape ``(n_params,)``; dtype and device are kept (float64 if not floating).
            layout: a `ParameterLayout` or an object with a ``.layout`` attribute.
        """
        layout = resolve_layout(layout)
        theta = _check_theta(theta, layout)
        inertial, friction = layout.split(theta.detach())
        phi = torch.cat([cls._inverse_map(inertial), _friction_inverse(friction, layout)], -1)
        return cls(layout, phi=phi)

    def _scaled_phi(self, unit: float) -> torch.Tensor:
        """phi of the same bodies with theta multiplied by ``unit > 0``, for `project`, which
        solves in units of theta_hat's largest entry."""
        phi = self.phi.detach().clone()
        root = unit**0.5
        self._scale_inertial_phi(phi, unit, root)
        for k, squared in enumerate(_friction_signs(self.layout)):
            phi[:, 10 + k] *= root if squared else unit
        return phi

    def _scale_inertial_phi(self, phi, unit, root) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def extra_repr(self) -> str:
        return f"n_joints={self.layout.n_joints}, friction={self.layout.friction}"


class VirtualParameters(_ConsistentParameters):
    """The virtual parameters of the paper's eq. 5 as an ``nn.Module``.

    Per joint, ``phi`` holds ``(sqrt m, cx, cy, cz, L11, L21, L31, L22, L32, L33)`` (m in kg, c in
    m, L in sqrt(kg) m) then one variable per friction term (squared for viscous and Coulomb
    friction, as is for an offset). Every ``phi`` gives ``m >= 0``, a positive semidefinite
    inertia at the centre of mass ``I_c = L L^T`` and non-negative friction; the triangle
    inequalities are not enforced (use `LogCholeskyParameters` for that).

    Args:
        layout: a `ParameterLayout` or an object with a ``.layout`` attribute.
        phi: initial variables, shape ``(n_joints, 10 + n_friction)``; default: every body 1 kg
            at the origin with ``I_c = 0.01 kg m^2 * 1``, zero friction.
        dtype: of the default ``phi`` (a given ``phi`` keeps its own).
        device: of the default ``phi``.

    Example:
        >>> params = VirtualParameters.from_theta(theta_hat, model)  # doctest: +SKIP
        >>> theta = params()                                         # (n_params,)
    """

    _inertial_map = staticmethod(inertial_from_virtual)
    _inverse_map = staticmethod(virtual_from_inertial)
    _variable_names = ("sqrt_m", "cx", "cy", "cz", "L11", "L21", "L31", "L22", "L32", "L33")

    def _scale_inertial_phi(self, phi, unit, root) -> None:
        phi[:, 0] *= root  # sqrt(m)
        phi[:, 4:10] *= root  # L; the centre of mass is unchanged

    def _default_phi(self) -> torch.Tensor:
        per = torch.zeros(self.layout.params_per_joint, dtype=torch.float64)
        per[0] = 1.0
        per[[4, 7, 9]] = 0.1
        return per.repeat(self.layout.n_joints, 1)


class LogCholeskyParameters(_ConsistentParameters):
    """Log-Cholesky parameters of the pseudo-inertia (Rucker and Wensing, 2022).

    Per joint, ``phi`` holds ``(alpha, d1, d2, d3, s12, s23, s13, t1, t2, t3)`` then one variable
    per friction term (as in `VirtualParameters`). The pseudo-inertia ``J = U U^T`` with
    ``U = e^alpha [[e^d1, s12, s13, t1], [0, e^d2, s23, t2], [0, 0, e^d3, t3], [0, 0, 0, 1]]`` is
    positive definite for every ``phi``: positive mass ``e^(2 alpha)``, positive definite inertia
    and strict triangle inequalities (full physical consistency). Bodies on the boundary (a point
    mass, a thin rod) are limits, reached as some ``d_i -> -inf``.

    Args:
        layout: a `ParameterLayout` or an object with a ``.layout`` attribute.
        phi: initial variables, shape ``(n_joints, 10 + n_friction)``; default: the same body as
            `VirtualParameters`' default.
        dtype: of the default ``phi``.
        device: of the default ``phi``.
    """

    _inertial_map = staticmethod(inertial_from_log_cholesky)
    _inverse_map = staticmethod(log_cholesky_from_inertial)
    _variable_names = ("alpha", "d1", "d2", "d3", "s12", "s23", "s13", "t1", "t2", "t3")

    def _scale_inertial_phi(self, phi, unit, root) -> None:
        phi[:, 0] += 0.5 * math.log(unit)  # J = e^(2 alpha) (...)

    def _default_phi(self) -> torch.Tensor:
        per = torch.zeros(self.layout.params_per_joint, dtype=torch.float64)
        per[1:4] = 0.5 * torch.log(torch.tensor(0.005, dtype=torch.float64))
        return per.repeat(self.layout.n_joints, 1)

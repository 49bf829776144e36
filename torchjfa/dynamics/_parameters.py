"""The parameter layout of a robot and conversions between inertial representations.

theta is laid out joint by joint; for each joint, the 10 inertial parameters of the body it
moves, in Pinocchio's order, about the body frame's origin and expressed in the body frame:

    [m, m*cx, m*cy, m*cz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]

then that joint's joint terms ("friction" in the code's names), in the order of `FRICTION_KINDS`
that are selected: viscous friction ``fv qd`` (the default, the paper's 11th parameter),
Coulomb friction ``fc sign(qd)`` (``fc tanh(qd / v_c)`` with
`RigidBodyModel.coulomb_velocity` ``v_c`` > 0), a constant offset ``fo`` and the armature ``ia qdd`` (the
motor's reflected rotor inertia, MuJoCo's ``armature``). Units: kg, kg m, kg m^2, then N m s/rad,
N m, N m and kg m^2 (N s/m, N, N and kg for prismatic joints).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from .._validation import check_coulomb_velocity as check_coulomb_velocity

__all__ = [
    "BodyInertial",
    "check_coulomb_velocity",
    "INERTIAL_NAMES",
    "FRICTION_KINDS",
    "ParameterLayout",
    "inertial_vector",
    "inertial_from_vector",
    "inertia_about_origin",
    "pseudo_inertia",
    "symmetric_from_six",
    "six_from_symmetric",
]

INERTIAL_NAMES = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
FRICTION_KINDS = ("viscous", "coulomb", "offset", "armature")
_FRICTION_SHORT = {"viscous": "fv", "coulomb": "fc", "offset": "fo", "armature": "ia"}

# index pairs of the 6 inertia entries in Pinocchio's order: xx, xy, yy, xz, yz, zz
_SIX = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))


@dataclass(frozen=True)
class ParameterLayout:
    """Where each parameter of a robot sits in theta.

    Args:
        joint_names: the actuated joints in model order.
        friction: joint terms per joint, a subset of ``FRICTION_KINDS`` (kept in that order):
            viscous, Coulomb and offset friction, armature.
        term_owners: the name each joint's terms go by in `parameter_names` (default: the
            joint's; a motor's under a `torchjfa.dynamics.Transmission`).
    """

    joint_names: tuple[str, ...]
    friction: tuple[str, ...] = ("viscous",)
    term_owners: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        names = tuple(self.joint_names)
        if len(names) == 0:
            raise ValueError("a ParameterLayout needs at least one joint")
        if len(set(names)) != len(names):
            raise ValueError(f"joint names must be unique, got {names}")
        friction = tuple(self.friction)
        unknown = [f for f in friction if f not in FRICTION_KINDS]
        if unknown:
            raise ValueError(f"unknown friction terms {unknown}; choose from {FRICTION_KINDS}")
        owners = names if self.term_owners is None else tuple(self.term_owners)
        if len(owners) != len(names):
            raise ValueError(f"term_owners needs {len(names)} names, got {len(owners)}")
        object.__setattr__(self, "joint_names", names)
        object.__setattr__(self, "friction", tuple(f for f in FRICTION_KINDS if f in friction))
        object.__setattr__(self, "term_owners", owners)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def n_friction(self) -> int:
        return len(self.friction)

    @property
    def params_per_joint(self) -> int:
        return 10 + self.n_friction

    @property
    def n_params(self) -> int:
        return self.n_joints * self.params_per_joint

    @property
    def parameter_names(self) -> tuple[str, ...]:
        terms = tuple(_FRICTION_SHORT[f] for f in self.friction)
        return tuple(
            name
            for j, owner in zip(self.joint_names, self.term_owners, strict=True)
            for name in (*(f"{j}.{p}" for p in INERTIAL_NAMES), *(f"{owner}.{t}" for t in terms))
        )

    def split(self, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``theta (..., n_params)`` -> inertial ``(..., n_joints, 10)``, friction
        ``(..., n_joints, n_friction)``."""
        if theta.shape[-1] != self.n_params:
            raise ValueError(
                f"theta has {theta.shape[-1]} entries, this layout has {self.n_params}"
            )
        per = theta.reshape(*theta.shape[:-1], self.n_joints, self.params_per_joint)
        return per[..., :10], per[..., 10:]

    def join(self, inertial: torch.Tensor, friction: torch.Tensor | None = None) -> torch.Tensor:
        """Inverse of `split`; missing friction is zero."""
        if inertial.shape[-2:] != (self.n_joints, 10):
            raise ValueError(
                f"inertial must have shape (..., {self.n_joints}, 10), got {tuple(inertial.shape)}"
            )
        if friction is None:
            friction = inertial.new_zeros(*inertial.shape[:-1], self.n_friction)
        per = torch.cat([inertial, friction], dim=-1)
        return per.reshape(*per.shape[:-2], self.n_params)

    def index(self, joint: str | int, name: str) -> int:
        """Position in theta of parameter ``name`` (e.g. ``"m"``, ``"fv"``) of ``joint``."""
        j = self.joint_names.index(joint) if isinstance(joint, str) else int(joint)
        per = INERTIAL_NAMES + tuple(_FRICTION_SHORT[f] for f in self.friction)
        return j * self.params_per_joint + per.index(name)


@dataclass(frozen=True)
class BodyInertial:
    """The inertial of the body one joint moves (fixed children lumped in), in its frame.

    Attributes:
        joint: the joint's name.
        body: the body's (URDF link's, MJCF body's) name.
        mass: 0-d tensor, kg.
        com: ``(3,)`` centre of mass in the body frame, m.
        inertia: ``(3, 3)`` rotational inertia about the centre of mass, body axes, kg m^2.
    """

    joint: str
    body: str
    mass: torch.Tensor
    com: torch.Tensor
    inertia: torch.Tensor


def symmetric_from_six(six: torch.Tensor) -> torch.Tensor:
    """``(..., 6)`` in order xx, xy, yy, xz, yz, zz -> symmetric ``(..., 3, 3)``."""
    xx, xy, yy, xz, yz, zz = six.unbind(-1)
    rows = [
        torch.stack([xx, xy, xz], -1),
        torch.stack([xy, yy, yz], -1),
        torch.stack([xz, yz, zz], -1),
    ]
    return torch.stack(rows, -2)


def six_from_symmetric(mat: torch.Tensor) -> torch.Tensor:
    """Symmetric ``(..., 3, 3)`` -> ``(..., 6)`` in order xx, xy, yy, xz, yz, zz."""
    return torch.stack([mat[..., i, j] for i, j in _SIX], -1)


def _skew_sq_term(com: torch.Tensor) -> torch.Tensor:
    """``|c|^2 1 - c c^T`` for ``com (..., 3)`` -> ``(..., 3, 3)``."""
    eye = torch.eye(3, dtype=com.dtype, device=com.device)
    return (com * com).sum(-1)[..., None, None] * eye - com[..., :, None] * com[..., None, :]


def inertial_vector(
    mass: torch.Tensor, com: torch.Tensor, inertia_com: torch.Tensor
) -> torch.Tensor:
    """10 inertial parameters about the body origin from mass, centre of mass and inertia.

    Args:
        mass: ``(...)`` kg.
        com: ``(..., 3)`` centre of mass in the body frame, m.
        inertia_com: ``(..., 3, 3)`` rotational inertia about the centre of mass, in the body
            frame's axes, kg m^2.

    Returns:
        ``(..., 10)``: ``[m, m c, I_o (6)]`` with ``I_o = I_c + m (|c|^2 1 - c c^T)``.
    """
    inertia_origin = inertia_com + mass[..., None, None] * _skew_sq_term(com)
    return torch.cat(
        [mass[..., None], mass[..., None] * com, six_from_symmetric(inertia_origin)], -1
    )


def inertia_about_origin(pi: torch.Tensor) -> torch.Tensor:
    """``(..., 10)`` -> rotational inertia about the body origin, ``(..., 3, 3)``."""
    return symmetric_from_six(pi[..., 4:10])


def inertial_from_vector(pi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Inverse of `inertial_vector`: ``(..., 10)`` -> mass, com ``(..., 3)``, I_c ``(..., 3, 3)``.

    Raises:
        ValueError: if any mass is not positive (the centre of mass is then undefined).
    """
    mass = pi[..., 0]
    if bool((mass <= 0).any()):
        raise ValueError(
            "every body needs a positive mass to define its centre of mass; got "
            f"masses {mass.detach().flatten().tolist()}"
        )
    com = pi[..., 1:4] / mass[..., None]
    inertia_com = inertia_about_origin(pi) - mass[..., None, None] * _skew_sq_term(com)
    return mass, com, inertia_com


def pseudo_inertia(pi: torch.Tensor) -> torch.Tensor:
    """The 4x4 pseudo-inertia ``J = [[tr(I)/2 1 - I, h], [h^T, m]]`` of ``pi (..., 10)``.

    A body is physically consistent (mass, inertia and triangle inequalities) exactly when J
    is positive definite (Wensing, Kim and Slotine, 2018).
    """
    inertia = inertia_about_origin(pi)
    eye = torch.eye(3, dtype=pi.dtype, device=pi.device)
    sigma = 0.5 * torch.diagonal(inertia, dim1=-2, dim2=-1).sum(-1)[..., None, None] * eye - inertia
    h = pi[..., 1:4]
    top = torch.cat([sigma, h[..., :, None]], -1)
    bottom = torch.cat([h, pi[..., :1]], -1)[..., None, :]
    return torch.cat([top, bottom], -2)


def friction_kinds(friction: str | Sequence[str]) -> tuple[str, ...]:
    """Parse ``"viscous,coulomb"`` or a sequence into a tuple of friction kinds."""
    if isinstance(friction, str):
        friction = [f.strip() for f in friction.split(",") if f.strip()]
    return ParameterLayout(("_",), tuple(friction)).friction

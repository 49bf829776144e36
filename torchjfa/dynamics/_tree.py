"""Reading a robot description (URDF or MJCF) into the kinematic tree the regressor runs on.

The tree structure (frames, their parents, joint names, types and order) comes from
pytorch-kinematics (`pk.build_chain_from_urdf` / `pk.build_chain_from_mjcf`). The numbers are read
again in float64 from the same description, because pytorch-kinematics stores its offsets and
axes in float32 (about 1e-7 relative), which is too coarse to agree with MuJoCo to 1e-9:

* URDF: joint ``<origin xyz rpy>`` and ``<axis>``, and each link's ``<inertial>`` (mass,
  ``<origin xyz rpy>``, the 6 inertia entries about the centre of mass in the inertial frame).
* MJCF: MuJoCo's compiled ``MjModel`` (``body_pos``/``body_quat``, ``jnt_pos``/``jnt_axis``,
  ``body_mass``/``body_ipos``/``body_iquat``/``body_inertia``), the real MJCF parser.

pytorch-kinematics' own forward kinematics is not used (`torchjfa.dynamics._kinematics` computes
it from this tree): for MJCF joints with a non-zero ``pos`` it rotates the body about the joint
position without shifting back, which misplaces the body (by 2 cm on ``branched_tree``'s left
arm); here the body frame is MuJoCo's and the joint axis passes through ``pos``. A URDF joint
without ``<axis>`` gets the URDF default ``(1, 0, 0)`` (pytorch-kinematics would use
``(0, 0, 1)``).

Frames attached by fixed joints (URDF ``fixed``, MJCF bodies without joints) are lumped into
the nearest ancestor moved by a joint; frames fixed to the root carry no parameters (they never
move). Every frame keeps its fixed pose in the body that carries it (or in the root frame), so
that forward kinematics can still place it.

A URDF's structure is checked first (`torchjfa.dynamics._urdf`: one tree, defined links, no
loops, no mimic joints) and pytorch-kinematics builds its chain from a minimal, quiet copy;
an MJCF with active ``<equality>`` constraints (coupled joints, closed loops) is refused. Files
and bytes are decoded as their XML declaration says. This module reads URDF and holds what both
formats share (the tree, its maths, the lumping); `torchjfa.dynamics._mjcf` reads MJCF. Use
`RigidBodyModel` rather than these modules; it is the public face of the tree.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

from ._urdf import check_urdf, decode_xml, parse_urdf, pk_chain_from_urdf

__all__ = [
    "KinematicTree",
    "tree_from_urdf",
    "read_description",
    "describe_source",
    "lump",
]

_URDF_JOINT_TYPES = {"revolute": "revolute", "continuous": "revolute", "prismatic": "prismatic"}


@dataclass
class KinematicTree:
    """The moving bodies of a robot, one per joint, in pytorch-kinematics' joint order.

    All arrays are float64 numpy; ``n`` is the number of joints.

    Attributes:
        joint_names: ``n`` names.
        joint_types: ``n`` of ``"revolute"`` or ``"prismatic"``.
        body_names: the frame (URDF link, MJCF body) each joint moves.
        lumped: per joint, names of the frames attached by fixed joints lumped into its body.
        parent: per joint, index of the joint moving its parent body, or -1 (the root).
        rot_fixed: ``(n, 3, 3)`` rotation of the joint frame (before motion) in the parent body.
        pos_fixed: ``(n, 3)`` its position in the parent body, m.
        axis: ``(n, 3)`` unit joint axis in the body frame.
        axis_point: ``(n, 3)`` a point on the axis in the body frame (MJCF ``joint pos``), m.
        inertial: ``(n, 10)`` the lumped inertial parameters of each body (Pinocchio order).
        gravity: ``(3,)`` m/s^2 in the root frame.
        fixed_inertial: per joint, ``{frame name: (10,) inertial in its own frame}`` of the lumped
            frames, for writing back.
        frame_names: every frame of the description (URDF links; MJCF bodies, then named
            sites), the root first, parents before children.
        frame_owner: per frame, the joint whose body carries it, or -1 (fixed to the root).
        frame_rot: ``(n_frames, 3, 3)`` each frame's fixed rotation in its owner's body frame
            (in the root frame for owner -1).
        frame_pos: ``(n_frames, 3)`` its fixed position there, m.
        base_inertial: ``(10,)`` the inertial of the root frame with every frame fixed to it,
            about the root frame's origin in its axes (Pinocchio order): the base body of a
            floating-base robot, unused (it never moves) on a fixed base.
    """

    joint_names: tuple[str, ...]
    joint_types: tuple[str, ...]
    body_names: tuple[str, ...]
    lumped: tuple[tuple[str, ...], ...]
    parent: tuple[int, ...]
    rot_fixed: np.ndarray
    pos_fixed: np.ndarray
    axis: np.ndarray
    axis_point: np.ndarray
    inertial: np.ndarray
    gravity: np.ndarray
    fixed_inertial: list[dict[str, np.ndarray]] = field(default_factory=list)
    frame_names: tuple[str, ...] = ()
    frame_owner: tuple[int, ...] = ()
    frame_rot: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    frame_pos: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    base_inertial: np.ndarray = field(default_factory=lambda: np.zeros(10))

    def ancestors(self) -> tuple[tuple[int, ...], ...]:
        """Per body i, the joints that move it: its ancestors and i itself, root first."""
        out = []
        for i in range(len(self.parent)):
            chain, k = [], i
            while k >= 0:
                chain.append(k)
                k = self.parent[k]
            out.append(tuple(reversed(chain)))
        return tuple(out)


# ----------------------------------------------------------------------------- small maths
def rpy_matrix(rpy) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes X, Y, Z) -> rotation ``Rz(y) Ry(p) Rx(r)``."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def quat_matrix(quat) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` (MuJoCo's order) -> rotation matrix."""
    w, x, y, z = (float(v) for v in np.asarray(quat, dtype=np.float64) / np.linalg.norm(quat))
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def inertial_np(mass: float, com, inertia_com: np.ndarray) -> np.ndarray:
    """``(10,)`` inertial vector about the frame origin from mass, centre of mass, I_c."""
    c = np.asarray(com, dtype=np.float64)
    inertia = inertia_com + mass * (c @ c * np.eye(3) - np.outer(c, c))
    six = [inertia[0, 0], inertia[0, 1], inertia[1, 1], inertia[0, 2], inertia[1, 2], inertia[2, 2]]
    return np.array([mass, *(mass * c), *six])


def transform_inertial_np(pi: np.ndarray, rot: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Re-express ``pi`` (10,) of a frame F in a frame G where F sits at ``(rot, pos)`` in G.

    ``I_G = R I_F R^T - S(p) S(R h) - S(R h) S(p) - m S(p)^2`` (no division by the mass, so
    massless frames pass through).
    """
    m, h = pi[0], pi[1:4]
    i6 = pi[4:10]
    inertia = np.array([[i6[0], i6[1], i6[3]], [i6[1], i6[2], i6[4]], [i6[3], i6[4], i6[5]]])
    rh = rot @ h
    sp, srh = _skew(pos), _skew(rh)
    new = rot @ inertia @ rot.T - sp @ srh - srh @ sp - m * sp @ sp
    h_new = m * pos + rh
    six = [new[0, 0], new[0, 1], new[1, 1], new[0, 2], new[1, 2], new[2, 2]]
    return np.array([m, *h_new, *six])


# ----------------------------------------------------------------------------- reading files
def read_description(source: str | bytes | os.PathLike, kind: str) -> tuple[str, str | None]:
    """Return ``(xml text, path or None)`` for a file path, an XML string or XML bytes.

    Files and bytes are decoded as their byte-order mark or XML declaration says (UTF-8 if
    neither), so a description that starts with ``<?xml version="1.0" encoding="utf-8"?>``
    reads the same from a file, a string and bytes.

    Raises:
        FileNotFoundError: if ``source`` looks like a path and no such file exists.
        TypeError: if ``source`` is neither a string, bytes nor a path.
        ValueError: if the bytes are not in the encoding they declare.
    """
    if isinstance(source, os.PathLike):
        source = os.fspath(source)
    if isinstance(source, (bytes, bytearray)):
        if bytes(source).lstrip(b"\xef\xbb\xbf\xff\xfe \t\r\n").startswith((b"<", b"\x00<")):
            return decode_xml(bytes(source), f"{kind} bytes"), None
        source = os.fsdecode(bytes(source))
    if not isinstance(source, str):
        raise TypeError(
            f"the {kind} must be a file path, an XML string or XML bytes, got {type(source)}"
        )
    if source.lstrip("\ufeff \t\r\n").startswith("<"):
        return source, None
    if not os.path.isfile(source):
        raise FileNotFoundError(f"no {kind} file at {source!r}")
    with open(source, "rb") as fh:
        data = fh.read()
    return decode_xml(data, f"{kind} file {source!r}"), os.path.abspath(source)


def describe_source(kind: str, path: str | None) -> str:
    """How messages name a description: ``URDF file '/a/b.urdf'`` or ``URDF string``."""
    return f"{kind} file {path!r}" if path is not None else f"{kind} string"


@dataclass
class Frame:
    """One frame of the description: a URDF link or an MJCF body."""

    name: str
    parent: int
    rot: np.ndarray  # joint frame (before motion) in the parent frame
    pos: np.ndarray
    joint: str | None = None  # None: fixed to its parent
    joint_type: str = "fixed"
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    axis_point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    inertial: np.ndarray = field(default_factory=lambda: np.zeros(10))


def _floats(text: str | None, n: int, default: tuple[float, ...], what: str) -> np.ndarray:
    if text is None:
        return np.array(default, dtype=np.float64)
    try:
        vals = [float(v) for v in text.split()]
    except ValueError as exc:
        raise ValueError(f"cannot read {n} number(s) from {what}={text!r}") from exc
    if len(vals) != n:
        raise ValueError(f"{what} needs {n} number(s), got {text!r}")
    if not all(np.isfinite(vals)):
        raise ValueError(f"{what}={text!r} is not a finite number; give a number")
    return np.array(vals, dtype=np.float64)


def _origin(elem: ET.Element | None, what: str) -> tuple[np.ndarray, np.ndarray]:
    if elem is None:
        return np.eye(3), np.zeros(3)
    xyz = _floats(elem.get("xyz"), 3, (0.0, 0.0, 0.0), f"{what} origin xyz")
    rpy = _floats(elem.get("rpy"), 3, (0.0, 0.0, 0.0), f"{what} origin rpy")
    return rpy_matrix(rpy), xyz


def _urdf_inertial(link: ET.Element) -> np.ndarray:
    name = link.get("name")
    inertial = link.find("inertial")
    if inertial is None:
        return np.zeros(10)
    what = f"link {name!r} inertial"
    rot, com = _origin(inertial.find("origin"), what)
    mass_el = inertial.find("mass")
    mass = (
        0.0
        if mass_el is None
        else float(_floats(mass_el.get("value"), 1, (0.0,), f"{what} mass")[0])
    )
    if mass < 0:
        raise ValueError(f"link {name!r} has negative mass {mass}")
    ie = inertial.find("inertia")
    keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    v = {
        k: 0.0 if ie is None else float(_floats(ie.get(k), 1, (0.0,), f"{what} inertia {k}")[0])
        for k in keys
    }
    inertia = np.array(
        [
            [v["ixx"], v["ixy"], v["ixz"]],
            [v["ixy"], v["iyy"], v["iyz"]],
            [v["ixz"], v["iyz"], v["izz"]],
        ]
    )
    return inertial_np(mass, com, rot @ inertia @ rot.T)


def pk_children(frame) -> list:
    return list(frame.children)


def tree_from_urdf(text: str, gravity, where: str = "URDF string") -> tuple[KinematicTree, object]:
    """Parse URDF text into a `KinematicTree` and the pytorch-kinematics chain.

    Args:
        text: the URDF (an XML declaration is fine).
        gravity: ``(3,)`` m/s^2 in the root link's frame.
        where: the description's name in error messages (`describe_source`).

    Raises:
        ValueError: for anything `check_urdf` refuses, malformed XML or numbers.
    """
    root = parse_urdf(text, where)
    links, joints = check_urdf(root, where)
    chain = pk_chain_from_urdf(links, joints, where)

    frames: list[Frame] = []

    def visit(pk_frame, parent: int) -> None:
        link_name = pk_frame.link.name
        if parent < 0:
            rec = Frame(link_name, -1, np.eye(3), np.zeros(3))
        else:
            jname = pk_frame.joint.name
            j = joints[jname]
            rot, pos = _origin(j.find("origin"), f"joint {jname!r}")
            rec = Frame(link_name, parent, rot, pos)
            if j.get("type") != "fixed":
                axis_el = j.find("axis")
                axis = _floats(
                    None if axis_el is None else axis_el.get("xyz"),
                    3,
                    (1.0, 0.0, 0.0),
                    f"joint {jname!r} axis",
                )
                norm = float(np.linalg.norm(axis))
                if norm == 0.0:
                    raise ValueError(f"joint {jname!r} has a zero axis")
                rec.joint, rec.joint_type, rec.axis = (
                    jname,
                    _URDF_JOINT_TYPES[j.get("type")],
                    axis / norm,
                )
        rec.inertial = _urdf_inertial(links[link_name])
        frames.append(rec)
        me = len(frames) - 1
        for child in pk_children(pk_frame):
            visit(child, me)

    try:
        visit(chain._root, -1)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    return lump(frames, chain, gravity), chain


# ----------------------------------------------------------------------------- lumping
def lump(frames: list[Frame], chain, gravity) -> KinematicTree:
    """Lump fixed frames into their moving ancestor and order the joints as pk does."""
    n_frames = len(frames)
    owner = [-1] * n_frames  # frame index of the moving frame that carries frame f
    rot_in_owner = [np.eye(3)] * n_frames  # pose of frame f in its owner's frame
    pos_in_owner = [np.zeros(3)] * n_frames
    for f, rec in enumerate(frames):  # parents come before children
        if rec.joint is not None:
            owner[f] = f
            continue
        if rec.parent < 0:
            continue
        p = rec.parent
        owner[f] = owner[p]
        rot_in_owner[f] = rot_in_owner[p] @ rec.rot
        pos_in_owner[f] = pos_in_owner[p] + rot_in_owner[p] @ rec.pos

    moving = [f for f, rec in enumerate(frames) if rec.joint is not None]
    index = {f: k for k, f in enumerate(moving)}
    names = tuple(frames[f].joint for f in moving)
    pk_names = tuple(chain.get_joint_parameter_names())
    if names != pk_names:
        raise ValueError(f"joint order {names} differs from pytorch-kinematics' {pk_names}")
    n = len(moving)
    inertial = np.zeros((n, 10))
    lumped: list[list[str]] = [[] for _ in range(n)]
    fixed_inertial: list[dict[str, np.ndarray]] = [{} for _ in range(n)]
    base_inertial = np.zeros(10)
    for f, rec in enumerate(frames):
        if owner[f] < 0:
            base_inertial += transform_inertial_np(rec.inertial, rot_in_owner[f], pos_in_owner[f])
            continue
        k = index[owner[f]]
        inertial[k] += transform_inertial_np(rec.inertial, rot_in_owner[f], pos_in_owner[f])
        if owner[f] != f:
            lumped[k].append(rec.name)
            fixed_inertial[k][rec.name] = rec.inertial.copy()

    parent, rot_fixed, pos_fixed = [], np.zeros((n, 3, 3)), np.zeros((n, 3))
    for k, f in enumerate(moving):
        p = frames[f].parent
        parent.append(index[owner[p]] if owner[p] >= 0 else -1)
        # pose of the joint frame in the owner of the parent: owner -> parent -> joint frame
        rot_fixed[k] = rot_in_owner[p] @ frames[f].rot
        pos_fixed[k] = pos_in_owner[p] + rot_in_owner[p] @ frames[f].pos

    g = np.asarray(gravity if gravity is not None else (0.0, 0.0, -9.81), dtype=np.float64)
    if g.shape != (3,) or not np.all(np.isfinite(g)):
        raise ValueError(f"gravity must be 3 finite numbers, got {gravity}")
    return KinematicTree(
        joint_names=names,
        joint_types=tuple(frames[f].joint_type for f in moving),
        body_names=tuple(frames[f].name for f in moving),
        lumped=tuple(tuple(x) for x in lumped),
        parent=tuple(parent),
        rot_fixed=rot_fixed,
        pos_fixed=pos_fixed,
        axis=np.stack([frames[f].axis for f in moving]),
        axis_point=np.stack([frames[f].axis_point for f in moving]),
        inertial=inertial,
        gravity=g,
        fixed_inertial=fixed_inertial,
        frame_names=tuple(rec.name for rec in frames),
        frame_owner=tuple(index[o] if o >= 0 else -1 for o in owner),
        frame_rot=np.stack(rot_in_owner),
        frame_pos=np.stack(pos_in_owner),
        base_inertial=base_inertial,
    )

"""Writing identified inertials back into the robot description (URDF or MJCF).

Each joint's body gets the lumped inertial of theta: mass, centre of mass (the inertial frame's
origin, not rotated) and the full inertia about the centre of mass. The frames that were lumped
into it (attached by fixed joints) lose theirs: URDF links drop their ``<inertial>``, MJCF bodies
get an explicit zero mass. Reloading the written file gives the same theta (inertial part).
Joint terms: an MJCF gets each joint's armature (``armature``), viscous friction (``damping``)
and Coulomb friction (``frictionloss``, MuJoCo's dry friction) where theta has them, so the file
simulates the identified robot; a URDF gets each joint's ``<dynamics damping friction>``
(viscous and Coulomb); an offset (and in a URDF the armature) has no field and stays in theta
(`torchjfa.io` keeps it). With a `Transmission`, the motors' terms go into an MJCF as one fixed
tendon per motor (``<tendon><fixed name=motor armature damping frictionloss>`` with the ratio's
row as the joints' ``coef``: MuJoCo then applies exactly ``R^T (I_m R qdd + f_v R qd)`` and the
dry friction on the motor velocity); a URDF gets the joint-side equivalent (``r^2 f_v``,
``|r| f_c``) of each motor that turns one joint alone, and a coupled motor's terms stay in theta.
Everything else in the file is kept. Use
`RigidBodyModel.write_urdf` / `write_mjcf` rather than these functions.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np
import torch

from ._urdf import resolve_mesh

__all__ = ["write_urdf", "write_mjcf"]


def _fmt(v: float) -> str:
    return repr(float(v))


def _values(model, theta: torch.Tensor):
    inertials = model.inertials(theta.detach().to(torch.float64).cpu())
    for b in inertials:
        inertia = b.inertia.numpy()
        eig = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
        if eig.min() < -1e-12 * max(1.0, abs(eig).max()):
            raise ValueError(
                f"the inertia of body {b.body!r} (joint {b.joint!r}) about its centre of mass is "
                f"not positive semi-definite (eigenvalues {eig.tolist()}); project theta onto "
                "physically consistent parameters (torchjfa.physical) before writing it"
            )
    return inertials


def _resolve_meshes(root: ET.Element, source_path: str | None) -> None:
    """Every ``<mesh filename>`` that can be found made absolute (`resolve_mesh`), so that the
    written URDF loads from any folder without ROS; the others are left as they are."""
    for mesh in root.iter("mesh"):
        name = mesh.get("filename")
        found = resolve_mesh(name, source_path) if name else None
        if found is not None:
            mesh.set("filename", found)


def write_urdf(model, theta: torch.Tensor, path: str | os.PathLike) -> None:
    """Write ``model``'s URDF with theta's inertials and joint friction to ``path``.

    Mesh file names that can be found (``package://`` resolved without ROS, relative names
    from the description's folder, `resolve_mesh`) are written as absolute paths, so that the
    file loads in MuJoCo or Pinocchio from any folder.

    Args:
        model: a `RigidBodyModel` read from URDF (`FloatingBaseModel.write_urdf` writes a
            floating-base one).
        theta: ``(n_params,)`` physically consistent parameters (`torchjfa.physical.project`).
        path: the file to write.

    Raises:
        ValueError: for a model read from MJCF, a theta of the wrong shape, a body that is not
            consistent or a negative friction term.
    """
    theta = model._check_theta(theta)
    if model.source_format != "urdf":
        raise ValueError(
            f"write_urdf needs a model read from URDF; this one is {model.source_format}"
        )
    text = _identified_urdf(model, theta)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(text)


def _identified_urdf(model, theta: torch.Tensor) -> str:
    """The text `write_urdf` writes."""
    inertials = _values(model, theta)
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    root = ET.fromstring(model.source_xml, parser=parser)
    links = {link.get("name"): link for link in root.findall("link")}
    for b in inertials:
        _inertial_element(links[b.body], b.com.tolist(), b.mass, b.inertia.numpy())
        for name in model.lumped_bodies[b.joint]:
            for old in links[name].findall("inertial"):
                links[name].remove(old)
    _write_urdf_dynamics(model, theta, root)
    _resolve_meshes(root, model.source_path)
    ET.indent(root, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _inertial_element(link: ET.Element, com, mass, inertia) -> None:
    """``link``'s ``<inertial>`` replaced by one of ``mass`` (kg) at ``com`` (m, link axes)
    with ``inertia`` ``(3, 3)`` about it (kg m^2)."""
    for old in link.findall("inertial"):
        link.remove(old)
    el = ET.SubElement(link, "inertial")
    ET.SubElement(el, "origin", xyz=" ".join(_fmt(v) for v in com), rpy="0 0 0")
    ET.SubElement(el, "mass", value=_fmt(mass))
    keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    pairs = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    values = {k: _fmt(inertia[i, j]) for k, (i, j) in zip(keys, pairs, strict=True)}
    ET.SubElement(el, "inertia", **values)


def _base_inertial(model, theta: torch.Tensor):
    """``(mass, com, inertia about the com)`` of a floating base's 10 parameters, checked."""
    from ._parameters import inertial_from_vector

    mass, com, inertia = inertial_from_vector(theta[:10])
    eig = np.linalg.eigvalsh(inertia.numpy())
    if not float(mass) > 0 or eig.min() < -1e-12 * max(1.0, abs(eig).max()):
        raise ValueError(
            f"the base {model.base_name!r} has mass {float(mass)} and principal inertias "
            f"{eig.tolist()}; project theta onto physically consistent parameters first"
        )
    return float(mass), com.tolist(), inertia.numpy()


def _base_lumped(model) -> list[str]:
    """The frames fixed to a floating base, itself excluded (their inertia is the base's)."""
    tree = model.joints._tree
    return [name for name, owner in zip(tree.frame_names, tree.frame_owner, strict=True)
            if owner < 0 and name != model.base_name]  # fmt: skip


def _parsed(path) -> ET.Element:
    """The root of the XML file written at ``path``, its comments kept."""
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    return ET.parse(path, parser=parser).getroot()


def write_floating_urdf(model, theta: torch.Tensor, path) -> None:
    """`write_urdf` of a `FloatingBaseModel`: the joints' bodies as for a fixed base, then the
    base's inertial on the root link (the links fixed to it lumped into it)."""
    theta = torch.as_tensor(theta).detach().to(torch.float64).cpu()
    mass, com, inertia = _base_inertial(model, theta)
    write_urdf(model.joints, theta[10:], path)
    root = _parsed(path)
    links = {link.get("name"): link for link in root.findall("link")}
    for name in _base_lumped(model):
        for old in links[name].findall("inertial") if name in links else ():
            links[name].remove(old)
    _inertial_element(links[model.base_name], com, mass, inertia)
    ET.indent(root, space="  ")
    with open(path, "w", encoding="utf-8") as fh:
        fh.write('<?xml version="1.0"?>\n')
        fh.write(ET.tostring(root, encoding="unicode"))
        fh.write("\n")


def write_floating_mjcf(model, theta: torch.Tensor, path) -> None:
    """`write_mjcf` of a `FloatingBaseModel`: the joints' bodies as for a fixed base, then the
    base body's inertial (bodies fixed to it massless) and a ``<freejoint>`` on it."""
    theta = torch.as_tensor(theta).detach().to(torch.float64).cpu()
    mass, com, inertia = _base_inertial(model, theta)
    write_mjcf(model.joints, theta[10:], path)
    root = _parsed(path)
    bodies = {el.get("name"): el for el in root.iter("body")}
    if model.base_name not in bodies:
        raise ValueError(f"the base body {model.base_name!r} is not in the MJCF written")
    base = bodies[model.base_name]
    for name in _base_lumped(model):
        if name in bodies:
            for old in bodies[name].findall("inertial"):
                bodies[name].remove(old)
            bodies[name].insert(0, ET.Element("inertial", pos="0 0 0", mass="0",
                                              diaginertia="0 0 0"))  # fmt: skip
    for old in base.findall("inertial"):
        base.remove(old)
    six = (inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2],
           inertia[1, 2])  # fmt: skip
    base.insert(0, ET.Element("inertial", pos=" ".join(_fmt(v) for v in com), mass=_fmt(mass),
                              fullinertia=" ".join(_fmt(v) for v in six)))  # fmt: skip
    base.insert(0, ET.Element("freejoint", name=f"{model.base_name}_free"))
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(ET.tostring(root, encoding="unicode"))
        fh.write("\n")


_MJCF_JOINT_FIELDS = {"armature": "armature", "viscous": "damping", "coulomb": "frictionloss"}
_URDF_DYNAMICS = {"viscous": "damping", "coulomb": "friction"}


def _terms(model, theta: torch.Tensor, kinds) -> torch.Tensor:
    """``(n_dof, len(kinds))`` theta's joint terms of ``kinds``, checked non-negative."""
    _, terms = model.layout.split(theta.detach().to(torch.float64).cpu())
    out = terms[:, [model.friction.index(k) for k in kinds]]
    bad = (out < 0).nonzero().tolist()
    if bad:
        j, k = bad[0]
        raise ValueError(
            f"joint {model.joint_names[j]!r} has a negative {kinds[k]} ({float(out[j, k]):.4g}); "
            "project theta onto physically consistent parameters (torchjfa.physical) before "
            "writing it"
        )
    return out


def _write_urdf_dynamics(model, theta: torch.Tensor, root: ET.Element) -> None:
    """Each joint's ``<dynamics damping="..." friction="...">`` from theta's viscous and Coulomb
    terms (the URDF's only joint terms; an offset and an armature have no field there), the
    joint-side equivalent of a motor that turns that joint alone."""
    kinds = [k for k in model.friction if k in _URDF_DYNAMICS]
    if not kinds:
        return
    values = _terms(model, theta, kinds).numpy()
    # per joint, the slot whose terms it gets and their joint-side factor (r for a lone motor)
    side = {j: (j, 1.0) for j in range(model.n_dof)}
    t = model.transmission
    if t is not None:
        slots = t.indices(model.joint_names)
        for j in slots:
            del side[j]  # a joint a motor drives: only a lone motor's terms have a field
        for slot, row in zip(slots, t.ratio, strict=True):
            turned = np.flatnonzero(row)
            if len(turned) == 1:
                side[slots[int(turned[0])]] = (slot, abs(float(row[turned[0]])))
    power = np.array([2.0 if kind == "viscous" else 1.0 for kind in kinds])
    joints = {el.get("name"): el for el in root.findall("joint")}
    for j, (slot, gear) in side.items():
        el = joints[model.joint_names[j]]
        dyn = el.find("dynamics")
        if dyn is None:
            dyn = ET.SubElement(el, "dynamics")
        for k, kind in enumerate(kinds):
            dyn.set(_URDF_DYNAMICS[kind], _fmt(float(values[slot, k] * gear ** power[k])))


def _write_joint_terms(model, theta: torch.Tensor, root: ET.Element) -> None:
    """Set the MJCF joint attributes of theta's joint terms (armature, damping, frictionloss),
    or, for the joints of a transmission, one fixed tendon per motor carrying them."""
    kinds = [k for k in model.friction if k in _MJCF_JOINT_FIELDS]
    if not kinds:
        return
    values = _terms(model, theta, kinds)
    joints: dict[str, list[ET.Element]] = {}
    for el in root.iter("joint"):
        joints.setdefault(el.get("name", ""), []).append(el)
    t = model.transmission
    driven = set() if t is None else set(t.joints)
    for j, name in enumerate(model.joint_names):
        found = joints.get(name, [])
        if len(found) != 1:
            raise ValueError(
                f"joint {name!r} is not named uniquely in the main MJCF file; cannot write its "
                f"{', '.join(kinds)}"
            )
        if name in driven:
            continue
        for k, kind in enumerate(kinds):
            found[0].set(_MJCF_JOINT_FIELDS[kind], _fmt(float(values[j, k])))
    if t is None:
        return
    tendon = root.find("tendon")
    if tendon is None:
        tendon = ET.SubElement(root, "tendon")
    for slot, motor, row in zip(t.indices(model.joint_names), t.motors, t.ratio, strict=True):
        attrs = {
            _MJCF_JOINT_FIELDS[kind]: _fmt(float(values[slot, k])) for k, kind in enumerate(kinds)
        }
        fixed = ET.SubElement(tendon, "fixed", {"name": motor, **attrs})
        for joint, coef in zip(t.joints, row, strict=True):
            if coef != 0:
                ET.SubElement(fixed, "joint", joint=joint, coef=_fmt(coef))


def _as_mjcf(model, theta: torch.Tensor):
    """A URDF model as the MJCF model MuJoCo makes of it, with theta in that model's order.

    The URDF is converted with theta's inertials already in it: MuJoCo refuses a moving body
    whose description gives it no mass or inertia, which the identified parameters give."""
    from ._mjcf import mjcf_from_urdf

    urdf = _identified_urdf(model, theta)
    try:  # with its collision geometry and motors, unless MuJoCo cannot read a mesh found
        text = mjcf_from_urdf(urdf, source_path=model.source_path, export=True)
    except ValueError:
        text = mjcf_from_urdf(urdf)
    other = (
        type(model)
        .from_mjcf(
            text,
            friction=model.friction,
            gravity=model.gravity.tolist(),
            coulomb_velocity=model.coulomb_velocity,
        )
        .with_transmission(model.transmission)
    )
    inertial, terms = model.layout.split(theta.detach().to(torch.float64).cpu())
    order = [model.joint_names.index(j) for j in other.joint_names]
    return other, other.layout.join(inertial[order], terms[order])


def write_mjcf(model, theta: torch.Tensor, path: str | os.PathLike) -> None:
    """Write ``model.source_xml`` with theta's inertials to ``path`` as MJCF.

    The ``<inertial>`` elements of the joints' bodies are replaced (numbers written in full
    precision); bodies must be named and defined in the main file (not in an ``<include>``).
    A URDF model is first turned into MJCF by MuJoCo's URDF importer
    (`torchjfa.dynamics._mjcf.mjcf_from_urdf` with ``export``: links as bodies, their
    collision geometry where MuJoCo can read it, meshes by absolute paths, and a torque motor
    per joint within the URDF's effort limits), so that MuJoCo simulates it as it is.

    Args:
        model: a `RigidBodyModel`; theta: ``(n_params,)`` physically consistent parameters;
        path: the file to write.

    Raises:
        ValueError: on a theta of the wrong shape, a body that is not consistent, a negative
            friction term, or a description MuJoCo cannot compile.
    """
    theta = model._check_theta(theta)
    if model.source_format == "urdf":
        model, theta = _as_mjcf(model, theta)
    inertials = _values(model, theta)
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    root = ET.fromstring(model.source_xml, parser=parser)
    bodies: dict[str, list[ET.Element]] = {}
    for el in root.iter("body"):
        bodies.setdefault(el.get("name", ""), []).append(el)

    def body_el(name: str) -> ET.Element:
        found = bodies.get(name, [])
        if not name or len(found) != 1:
            raise ValueError(
                f"body {name!r} is not named uniquely in the main MJCF file; cannot write it"
            )
        return found[0]

    def set_inertial(body: ET.Element, **attrs: str) -> None:
        for old in body.findall("inertial"):
            body.remove(old)
        body.insert(0, ET.Element("inertial", attrs))

    for b in inertials:
        inertia = b.inertia.numpy()
        six = (
            inertia[0, 0],
            inertia[1, 1],
            inertia[2, 2],
            inertia[0, 1],
            inertia[0, 2],
            inertia[1, 2],
        )
        set_inertial(
            body_el(b.body),
            pos=" ".join(_fmt(v) for v in b.com.tolist()),
            mass=_fmt(b.mass),
            fullinertia=" ".join(_fmt(v) for v in six),
        )
        for name in model.lumped_bodies[b.joint]:
            set_inertial(body_el(name), pos="0 0 0", mass="0", diaginertia="0 0 0")
    _write_joint_terms(model, theta, root)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(ET.tostring(root, encoding="unicode"))
        fh.write("\n")

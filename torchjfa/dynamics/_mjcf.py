"""Reading an MJCF into the `KinematicTree`: MuJoCo compiles it, pytorch-kinematics orders it.

The numbers come from MuJoCo's compiled ``MjModel`` (``body_pos``/``body_quat``,
``jnt_pos``/``jnt_axis``, ``body_mass``/``body_ipos``/``body_iquat``/``body_inertia``, and
``site_pos``/``site_quat`` for the named sites, which forward kinematics can place), the joint
order from pytorch-kinematics' chain; see `torchjfa.dynamics._tree` for why both, and for the
URDF side. Use `RigidBodyModel.from_mjcf` rather than this module.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import replace

import numpy as np

from ._tree import Frame, KinematicTree, inertial_np, lump, pk_children, quat_matrix

__all__ = ["tree_from_mjcf", "mjcf_from_urdf", "strip_urdf_for_mujoco"]


def tree_from_mjcf(text: str, path: str | None, gravity) -> tuple[KinematicTree, object, object]:
    """Parse MJCF (text, and its path for relative assets) into a tree, the pk chain and the
    compiled ``MjModel``."""
    import mujoco

    if "<!DOCTYPE" in text or "<!ENTITY" in text:
        raise ValueError(
            "the MJCF declares a document type or entities (<!DOCTYPE ...>, <!ENTITY ...>), "
            "which are not read: write their values into the file"
        )
    try:
        model = (
            mujoco.MjModel.from_xml_path(path)
            if path is not None
            else mujoco.MjModel.from_xml_string(text)
        )
    except ValueError as exc:
        # MuJoCo's message spans lines (the error, then the element): one line here
        raise ValueError(f"MuJoCo cannot compile this MJCF: {' '.join(str(exc).split())}") from exc
    _check_mjcf(model)
    if gravity is None:
        gravity = np.array(model.opt.gravity, dtype=np.float64)
    chain = _pk_chain_from_mjcf(text, model)
    frames, bodies = _frames(model, chain)
    return _with_sites(lump(frames, chain, gravity), model, bodies), chain, model


def _with_sites(tree: KinematicTree, model, bodies: list[int]) -> KinematicTree:
    """The tree with each named site as a frame, carried by its body's owner.

    A site named like a body (MuJoCo names them apart) is left out: the body keeps the name.
    """
    names, owner = list(tree.frame_names), list(tree.frame_owner)
    rots, poss = list(tree.frame_rot), list(tree.frame_pos)
    for s in range(model.nsite):
        name = model.site(s).name
        if not name or name in names:
            continue
        f = bodies.index(int(model.site_bodyid[s]))
        names.append(name)
        owner.append(owner[f])
        rots.append(rots[f] @ quat_matrix(model.site_quat[s]))
        poss.append(poss[f] + rots[f] @ np.array(model.site_pos[s], dtype=np.float64))
    return replace(
        tree,
        frame_names=tuple(names),
        frame_owner=tuple(owner),
        frame_rot=np.stack(rots),
        frame_pos=np.stack(poss),
    )


def _check_mjcf(model) -> None:
    """Refuse what the tree cannot hold: free/ball joints, unnamed joints, several joints on a
    body, no joint at all, active equality constraints."""
    import mujoco

    for j in range(model.njnt):
        jt = int(model.jnt_type[j])
        if jt in (int(mujoco.mjtJoint.mjJNT_FREE), int(mujoco.mjtJoint.mjJNT_BALL)):
            kind = "free" if jt == int(mujoco.mjtJoint.mjJNT_FREE) else "ball"
            raise ValueError(
                f"joint {model.joint(j).name!r} is a {kind} joint: ball joints are not "
                "supported, and a floating base is read by FloatingBaseModel.from_mjcf; use "
                "hinge and slide joints on a fixed base here"
            )
        if not model.joint(j).name:
            raise ValueError(f"joint {j} has no name; every joint needs a unique name")
    for b in range(1, model.nbody):
        if model.body_jntnum[b] > 1:
            raise ValueError(
                f"body {model.body(b).name or b!r} has {model.body_jntnum[b]} joints; "
                "one joint per body is supported (split it into nested bodies, one joint each)"
            )
    if model.njnt == 0:
        raise ValueError("the MJCF has no joints; a model needs at least one moving joint")
    active = [e for e in range(model.neq) if model.eq_active0[e]]
    if active:
        kinds = [
            f"{mujoco.mjtEq(int(model.eq_type[e])).name[5:].lower()} "
            + (repr(model.equality(e).name) if model.equality(e).name else f"#{e}")
            for e in active
        ]
        raise ValueError(
            f"the MJCF has {len(active)} active equality constraint(s) ({', '.join(kinds)}): "
            "coupled joints (the MJCF form of a URDF mimic joint) and closed loops are not "
            'supported; remove them from <equality> or mark them active="false"'
        )


def _frames(model, chain) -> tuple[list[Frame], list[int]]:
    """The compiled model's bodies as `Frame` records, parents first, checked against pk's chain,
    and the MuJoCo body id of each."""
    import mujoco

    frames: list[Frame] = []
    bodies: list[int] = []

    def visit(pk_frame, body: int, parent: int) -> None:
        if body > 0:
            rec = Frame(
                model.body(body).name,
                parent,
                quat_matrix(model.body_quat[body]),
                np.array(model.body_pos[body], dtype=np.float64),
            )
        else:
            rec = Frame(model.body(0).name, -1, np.eye(3), np.zeros(3))
        if pk_frame.link.name != rec.name:
            raise ValueError(
                f"pytorch-kinematics and MuJoCo disagree on the tree at body {rec.name!r}"
            )
        if body > 0 and model.body_jntnum[body] == 1:
            j = int(model.body_jntadr[body])
            rec.joint = model.joint(j).name
            rec.joint_type = (
                "revolute"
                if int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE)
                else "prismatic"
            )
            rec.axis = np.array(model.jnt_axis[j], dtype=np.float64)
            rec.axis_point = np.array(model.jnt_pos[j], dtype=np.float64)
            if pk_frame.joint.name != rec.joint:
                raise ValueError(f"pytorch-kinematics and MuJoCo disagree on joint {rec.joint!r}")
        inertia_c = (
            quat_matrix(model.body_iquat[body])
            @ np.diag(model.body_inertia[body])
            @ quat_matrix(model.body_iquat[body]).T
        )
        rec.inertial = inertial_np(float(model.body_mass[body]), model.body_ipos[body], inertia_c)
        frames.append(rec)
        bodies.append(body)
        me = len(frames) - 1
        kids = [c for c in range(body + 1, model.nbody) if model.body_parentid[c] == body]
        pk_kids = pk_children(pk_frame)[: len(kids)]  # pk lists child bodies first, then sites
        for child_frame, child in zip(pk_kids, kids, strict=True):
            visit(child_frame, child, me)

    visit(chain._root, 0, -1)
    return frames, bodies


def _pk_chain_from_mjcf(text: str, model):
    """pytorch-kinematics' chain of an MJCF.

    ``pk.build_chain_from_mjcf`` is used when it works. pytorch-kinematics 0.10 looks joint
    types up with MuJoCo enum keys, which recent MuJoCo versions (4.x) no longer match with the
    integers ``MjModel`` returns (a KeyError), and it recompiles from a string, which loses the
    file's directory; in those cases the same chain is built here from the compiled model with
    pk's own ``Frame``/``Link``/``Joint``/``Chain`` classes, as pk's builder does.
    """
    import mujoco
    import pytorch_kinematics as pk
    import pytorch_kinematics.transforms as tf

    try:
        return pk.build_chain_from_mjcf(text)
    except (KeyError, ValueError):
        pass
    types = {
        int(mujoco.mjtJoint.mjJNT_HINGE): "revolute",
        int(mujoco.mjtJoint.mjJNT_SLIDE): "prismatic",
    }

    def frame_of(b: int):
        body = model.body(b)
        link = pk.frame.Link(body.name, offset=tf.Transform3d(rot=body.quat, pos=body.pos))
        if model.body_jntnum[b] == 1:
            j = model.joint(int(model.body_jntadr[b]))
            joint = pk.frame.Joint(
                j.name,
                offset=tf.Transform3d(pos=j.pos),
                axis=j.axis,
                joint_type=types[int(j.type[0])],
                limits=(j.range[0], j.range[1]),
            )
        else:
            joint = pk.frame.Joint(body.name + "_fixed_joint")
        fr = pk.frame.Frame(name=body.name, link=link, joint=joint)
        kids = [c for c in range(b + 1, model.nbody) if model.body_parentid[c] == b]
        fr.children = [frame_of(c) for c in kids]
        for s in range(model.nsite):
            if model.site_bodyid[s] == b:
                site = model.site(s)
                fr.children.append(
                    pk.frame.Frame(
                        name=site.name,
                        link=pk.frame.Link(
                            site.name, offset=tf.Transform3d(rot=site.quat, pos=site.pos)
                        ),
                    )
                )
        return fr

    root = model.body(0)
    root_frame = pk.frame.Frame(
        root.name,
        link=pk.frame.Link(root.name, offset=tf.Transform3d(rot=root.quat, pos=root.pos)),
        joint=pk.frame.Joint(),
    )
    root_frame.children = frame_of(0).children
    return pk.chain.Chain(root_frame)


#: URDF elements MuJoCo's importer should not see: geometry whose meshes may not be found
#: (contacts are not the identification's business) and tags for other tools
_URDF_DROPPED = ("visual", "collision")
_URDF_TOP_DROPPED = ("gazebo", "transmission", "ros2_control")


def strip_urdf_for_mujoco(root, *, keep: tuple[str, ...] = (), **compiler: str):
    """Prepare a parsed URDF (``xml.etree`` root, changed in place) for MuJoCo's importer:
    remove the other tools' tags and each link's ``<visual>`` and ``<collision>`` (except the
    tags in ``keep``), and set the ``<mujoco><compiler>`` attributes ``compiler`` (e.g.
    ``fusestatic="true"``) beside ``discardvisual="true"``. Returns the root."""
    import xml.etree.ElementTree as ET

    for tag in _URDF_TOP_DROPPED:
        for el in root.findall(tag):
            root.remove(el)
    for link in root.iter("link"):
        for tag in _URDF_DROPPED:
            if tag not in keep:
                for el in link.findall(tag):
                    link.remove(el)
    ext = root.find("mujoco")
    if ext is None:
        ext = ET.SubElement(root, "mujoco")
    element = ext.find("compiler")
    if element is None:
        element = ET.SubElement(ext, "compiler")
    for key, value in {"discardvisual": "true", **compiler}.items():
        element.set(key, value)
    return root


def mjcf_from_urdf(text: str, *, source_path: str | None = None, export: bool = False) -> str:
    """The MJCF of a URDF robot, as MuJoCo's URDF importer compiles it: the same links (bodies,
    fixed links kept as bodies without joints), joints, limits and inertials, gravity
    ``(0, 0, -9.81)`` m/s^2, no geometry (visuals and collisions are dropped, so that no mesh
    needs to be found).

    With ``export``, what a simulation needs is kept: each link's ``<collision>`` and
    ``<visual>`` geometry (primitives, and meshes that MuJoCo reads, STL, OBJ or MSH, found
    from ``source_path`` as `torchjfa.dynamics._urdf.resolve_mesh` finds them and named by
    absolute paths; the others left out; visuals as MuJoCo's importer makes them, geoms that
    take part in no contact), the bodies' masses from the inertials alone, and a torque motor per
    joint (gear 1, its control range the URDF's ``<limit effort>`` where it gives one).

    Raises:
        ValueError: if MuJoCo cannot compile it.
    """
    import xml.etree.ElementTree as ET

    import mujoco

    root = ET.fromstring(text)
    keep, extra, effort = (), {}, {}
    if export:
        mujoco_collisions(root, source_path)
        keep = ("collision", "visual")
        extra = {"inertiafromgeom": "false", "strippath": "false", "discardvisual": "false"}
        for joint in root.iter("joint"):
            limit = joint.find("limit")
            with contextlib.suppress(TypeError, ValueError):
                if limit is not None and float(limit.get("effort")) > 0:
                    effort[joint.get("name")] = float(limit.get("effort"))
    root = strip_urdf_for_mujoco(
        root, keep=keep, fusestatic="false", balanceinertia="false", **extra
    )
    try:
        spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
        if export:
            _add_motors(spec, effort)
        spec.compile()
        return _full_precision(spec.to_xml(), spec)
    except Exception as exc:  # MuJoCo raises ValueError, and others for some specs
        raise ValueError(f"MuJoCo cannot compile this URDF: {exc}") from None


#: the mesh files MuJoCo reads
_MUJOCO_MESHES = (".stl", ".obj", ".msh")


def mujoco_collisions(root, source_path: str | None) -> list[str]:
    """A parsed URDF's ``<collision>`` and ``<visual>`` meshes made readable by MuJoCo
    (``root`` changed in place): each mesh file found (`torchjfa.dynamics._urdf.resolve_mesh`)
    named by its absolute path, each collision or visual whose mesh is not found or not in a
    format MuJoCo reads (STL, OBJ, MSH; a visual's COLLADA, for one) removed. Returns the
    removed ones, ``"link: filename"``."""
    from ._urdf import resolve_mesh

    removed = []
    for link in root.iter("link"):
        for col in link.findall("collision") + link.findall("visual"):
            mesh = col.find("geometry/mesh")
            if mesh is None:
                continue
            found = resolve_mesh(mesh.get("filename", ""), source_path)
            if found is None or not found.lower().endswith(_MUJOCO_MESHES):
                removed.append(f"{link.get('name')}: {mesh.get('filename')}")
                link.remove(col)
            else:
                mesh.set("filename", found)
    return removed


def _add_motors(spec, effort: dict[str, float]) -> None:
    """A torque motor (gear 1) on each hinge and slide joint of ``spec``, named
    ``<joint>_motor``, its control range the joint's effort limit where it has one."""
    import mujoco

    for joint in spec.joints:
        if joint.type not in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            continue
        motor = spec.add_actuator()
        motor.name = f"{joint.name}_motor"
        motor.target = joint.name
        motor.trntype = mujoco.mjtTrn.mjTRN_JOINT
        limit = effort.get(joint.name)
        if limit is not None:
            motor.ctrlrange = [-limit, limit]
            motor.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE


def _full_precision(xml: str, spec) -> str:
    """``xml`` (MuJoCo's ``to_xml`` of ``spec``, which writes 6 significant digits) with every
    body's placement, every joint's position and axis and every inertial written with all the
    digits of float64, from ``spec``."""
    import xml.etree.ElementTree as ET

    def numbers(values) -> str:
        return " ".join(repr(float(v)) for v in values)

    root = ET.fromstring(xml)
    bodies = {b.name: b for b in spec.bodies if b.name}
    joints = {j.name: j for j in spec.joints if j.name}
    for el in root.iter("body"):
        body = bodies.get(el.get("name", ""))
        if body is None:
            continue
        for key, value in (("pos", body.pos), ("quat", body.quat)):
            if key in el.attrib:
                el.set(key, numbers(value))
        inertial = el.find("inertial")
        if inertial is not None and body.explicitinertial:
            inertial.set("pos", numbers(body.ipos))
            if np.all(np.isfinite(body.fullinertia)):  # the URDF's six entries, as given
                for key in ("quat", "diaginertia"):
                    inertial.attrib.pop(key, None)
                inertial.set("fullinertia", numbers(body.fullinertia))
            else:
                inertial.set("quat", numbers(body.iquat))
                inertial.set("diaginertia", numbers(body.inertia))
    for el in root.iter("joint"):
        joint = joints.get(el.get("name", ""))
        if joint is None:
            continue
        for key, value in (("pos", joint.pos), ("axis", joint.axis)):
            if key in el.attrib:
                el.set(key, numbers(value))
    return ET.tostring(root, encoding="unicode")


def fixed_base_mjcf(text: str, path: str | None) -> tuple[str, str]:
    """The MJCF with its free joint removed and the base body placed at the world origin (so
    that the world frame is the base frame), other top-level bodies and keyframes dropped;
    and the base's name. Asset folders become absolute, so that the text compiles alone."""
    import mujoco

    try:
        spec = mujoco.MjSpec.from_file(path) if path else mujoco.MjSpec.from_string(text)
    except Exception as exc:  # MuJoCo's parser: ValueError with its own message
        raise ValueError(f"MuJoCo cannot read this MJCF: {' '.join(str(exc).split())}") from None
    free = [j for j in spec.joints if j.type == mujoco.mjtJoint.mjJNT_FREE]
    if len(free) != 1:
        raise ValueError(
            f"a floating-base MJCF needs exactly one <freejoint> (on the base body), found "
            f"{len(free)}" + (f": {[j.name or '(unnamed)' for j in free]}" if free else "")
        )
    base = free[0].parent
    if base.parent is None or base.parent.name != spec.worldbody.name:
        raise ValueError(f"the free joint's body {base.name!r} must be a body of the world")
    spec.delete(free[0])
    base.pos = [0.0, 0.0, 0.0]
    base.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
    base.quat = [1.0, 0.0, 0.0, 0.0]
    for body in list(spec.worldbody.bodies):
        if body.name != base.name:
            spec.delete(body)
    for key in list(spec.keys):
        spec.delete(key)
    if path:
        folder = os.path.dirname(os.path.abspath(path))
        spec.meshdir = os.path.join(folder, spec.meshdir or "")
        spec.texturedir = os.path.join(folder, spec.texturedir or "")
    try:
        spec.compile()
        return _full_precision(spec.to_xml(), spec), base.name or "base"
    except Exception as exc:
        raise ValueError(f"MuJoCo cannot compile this MJCF: {' '.join(str(exc).split())}") from None


def mjcf_joint_terms(text: str, path: str | None, joints) -> dict[str, np.ndarray]:
    """An MJCF's damping, dry friction (``frictionloss``) and armature of ``joints``, ``(n,)``
    each, as MuJoCo compiles them (defaults classes applied)."""
    import mujoco

    try:
        mj = mujoco.MjModel.from_xml_path(path) if path else mujoco.MjModel.from_xml_string(text)
    except ValueError:  # the joints' text alone (a floating base's): compile it
        mj = mujoco.MjModel.from_xml_string(text)
    dof = [int(mj.jnt_dofadr[mj.joint(name).id]) for name in joints]
    return {
        "damping": np.array(mj.dof_damping[dof], dtype=np.float64),
        "friction": np.array(mj.dof_frictionloss[dof], dtype=np.float64),
        "armature": np.array(mj.dof_armature[dof], dtype=np.float64),
    }

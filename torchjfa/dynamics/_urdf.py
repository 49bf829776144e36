"""Checking a URDF's structure before its tree is built, and the pytorch-kinematics chain of it.

`torchjfa.dynamics._tree` reads the numbers; this module makes sure the description is one
kinematic tree torchjfa can model, and says what is wrong, in which file, when it is not:

* every link and joint named once, every joint's ``<parent>`` and ``<child>`` a defined link;
* one root link, each other link the child of exactly one joint (no second tree, no closed
  kinematic loop);
* at least one moving joint (revolute, continuous, prismatic), none of them a ``<mimic>`` joint
  (a coupled coordinate, which the regressor does not model: lock it with ``fixed_joints``).

pytorch-kinematics parses URDF with its bundled ``urdf_parser_py`` on lxml, which refuses a
Unicode string carrying an encoding declaration (``<?xml ... encoding="utf-8"?>``, the first line
of many public URDFs), prints an "Unknown tag" line for every ``<transmission>``,
``<ros2_control>`` or ``<gazebo>`` detail, and fails on tags it half-knows. It is handed a copy
that holds only what the chain is built from: each link's name and each joint's ``<parent>``,
``<child>``, ``<origin>``, ``<axis>`` and ``<limit>``, with anything it still prints swallowed.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

__all__ = ["check_urdf", "decode_xml", "fix_urdf_joints", "pk_chain_from_urdf"]

MOVING = ("revolute", "continuous", "prismatic")
_PK_JOINT_TAGS = ("parent", "child", "origin", "axis", "limit")
_ENCODING = re.compile(rb"""^\s*<\?xml[^>]*?encoding\s*=\s*["']([A-Za-z0-9._-]+)["']""")


def decode_xml(data: bytes, where: str) -> str:
    """Decode XML bytes as their byte-order mark or encoding declaration says (UTF-8 if neither).

    Raises:
        ValueError: for an unknown encoding or bytes that are not in it.
    """
    for bom, codec in (
        (b"\xef\xbb\xbf", "utf-8-sig"),
        (b"\xff\xfe", "utf-16"),
        (b"\xfe\xff", "utf-16"),
    ):
        if data.startswith(bom):
            encoding = codec
            break
    else:
        found = _ENCODING.match(data)
        encoding = found.group(1).decode("ascii") if found else "utf-8"
    try:
        return data.decode(encoding)
    except LookupError:
        raise ValueError(f"{where}: unknown encoding {encoding!r} in its XML declaration") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{where}: the bytes are not valid {encoding}: {exc}") from None


def parse_urdf(text: str, where: str, *, comments: bool = False) -> ET.Element:
    """The ``<robot>`` element of URDF text (an encoding declaration is fine)."""
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=comments))
    try:
        root = ET.fromstring(text, parser=parser)
    except ET.ParseError as exc:
        raise ValueError(f"{where}: the URDF is not valid XML: {exc}") from exc
    if root.tag != "robot":
        raise ValueError(f"{where}: a URDF's root element must be <robot>, got <{root.tag}>")
    return root


def fix_urdf_joints(text: str, names: str | Sequence[str], where: str) -> str:
    """The URDF text with the named joints turned ``fixed`` (held at q = 0).

    Their ``<axis>``, ``<limit>``, ``<mimic>``, ``<dynamics>``, ``<calibration>`` and
    ``<safety_controller>`` are dropped; comments and everything else are kept (the XML
    declaration is not: the text is Unicode).

    Raises:
        TypeError: if ``names`` is not a string or a sequence of strings.
        ValueError: for a name that is no joint of the description.
    """
    names = (names,) if isinstance(names, str) else tuple(names)
    if not all(isinstance(n, str) for n in names):
        raise TypeError(f"fixed_joints must be joint names (strings), got {names!r}")
    if not names:
        return text
    root = parse_urdf(text, where, comments=True)
    joints = {j.get("name"): j for j in root.findall("joint")}
    unknown = [n for n in names if n not in joints]
    if unknown:
        raise ValueError(
            f"{where}: fixed_joints names {unknown}, which are not joints of this description; "
            f"its joints: {sorted(k for k in joints if k is not None)}"
        )
    for n in names:
        j = joints[n]
        j.set("type", "fixed")
        for tag in ("axis", "limit", "mimic", "dynamics", "calibration", "safety_controller"):
            for e in j.findall(tag):
                j.remove(e)
    return ET.tostring(root, encoding="unicode")


def _link_of(joint: ET.Element, tag: str, where: str) -> str:
    el = joint.find(tag)
    name = None if el is None else el.get("link")
    if not name:
        raise ValueError(
            f'{where}: joint {joint.get("name")!r} has no <{tag} link="..."/>; every joint needs '
            "a parent and a child link"
        )
    return name


def check_urdf(root: ET.Element, where: str) -> tuple[dict[str, ET.Element], dict]:
    """Check that ``root`` describes one fixed-base tree with moving, uncoupled joints.

    Args:
        root: the ``<robot>`` element.
        where: the description's name in messages (``"URDF file '/a/b.urdf'"``).

    Returns:
        ``(links, joints)``: name -> element, in file order.

    Raises:
        ValueError: naming what was found and what is expected, for a link or joint without a
            name or defined twice, a floating, planar or unknown joint type, a joint whose
            parent or child is not a defined link, a link that is the child of two joints, a
            kinematic loop, several root links, no moving joint, or a moving ``<mimic>`` joint.
    """
    links = _links(root, where)
    joints = _joints(root, links, where)
    _check_one_tree(links, joints, where)
    _check_moving(joints, where)
    return links, joints


def check_urdf_elements(root: ET.Element, where: str) -> None:
    """The first part of `check_urdf`: every link and joint named once, joint types supported,
    every joint's links defined (ValueError otherwise, naming them)."""
    _joints(root, _links(root, where), where)


def _links(root: ET.Element, where: str) -> dict[str, ET.Element]:
    """The named ``<link>`` elements, in file order; each name once."""
    links: dict[str, ET.Element] = {}
    for link in root.findall("link"):
        name = link.get("name")
        if not name:
            raise ValueError(f'{where}: a <link> has no name; every link needs name="..."')
        if name in links:
            raise ValueError(f"{where}: link {name!r} is defined twice; link names must be unique")
        links[name] = link
    return links


def _joints(root: ET.Element, links: dict[str, ET.Element], where: str) -> dict[str, ET.Element]:
    """The named ``<joint>`` elements, in file order: supported types, defined links."""
    joints: dict[str, ET.Element] = {}
    for j in root.findall("joint"):
        name, jtype = j.get("name"), j.get("type")
        if not name:
            raise ValueError(f'{where}: a <joint> has no name; every joint needs name="..."')
        if name in joints:
            raise ValueError(
                f"{where}: joint {name!r} is defined twice; joint names must be unique"
            )
        if jtype in ("floating", "planar"):
            raise ValueError(
                f"{where}: joint {name!r} is {jtype!r}: floating and planar joints are not "
                "supported; a fixed base is the root link fixed to the world, and a free-flying "
                "base is the root link itself (FloatingBaseModel.from_urdf)"
            )
        if jtype not in (*MOVING, "fixed"):
            raise ValueError(
                f"{where}: joint {name!r} has unknown type {jtype!r}; supported: revolute, "
                "continuous, prismatic, fixed"
            )
        for tag in ("parent", "child"):
            link = _link_of(j, tag, where)
            if link not in links:
                raise ValueError(
                    f"{where}: joint {name!r} names {tag} link {link!r}, which is not defined "
                    f'(no <link name="{link}">); defined links: {sorted(links)}'
                )
        joints[name] = j
    if not joints:
        raise ValueError(
            f"{where}: the URDF has no joints; a model needs at least one moving joint"
        )
    return joints


def _check_one_tree(
    links: dict[str, ET.Element], joints: dict[str, ET.Element], where: str
) -> None:
    """Every link the child of at most one joint, one root link, no kinematic loop."""
    parent_of: dict[str, str] = {}  # child link -> joint
    for name, j in joints.items():
        child, parent = _link_of(j, "child", where), _link_of(j, "parent", where)
        if child == parent:
            raise ValueError(
                f"{where}: joint {name!r} connects link {child!r} to itself (a kinematic loop)"
            )
        if child in parent_of:
            raise ValueError(
                f"{where}: link {child!r} is the child of two joints, {parent_of[child]!r} and "
                f"{name!r}: a closed kinematic loop. URDF describes a tree (each link the child of "
                "one joint); closed loops are not supported"
            )
        parent_of[child] = name
    children: dict[str, list[str]] = {n: [] for n in links}
    for name, j in joints.items():
        children[_link_of(j, "parent", where)].append(name)

    def subtree_joints(link: str) -> list[str]:
        out, stack = [], [link]
        while stack:
            for jn in children[stack.pop()]:
                out.append(jn)
                stack.append(_link_of(joints[jn], "child", where))
        return out

    roots = [n for n in links if n not in parent_of]
    if len(roots) > 1:
        parts = []
        for r in roots:
            moving = [jn for jn in subtree_joints(r) if joints[jn].get("type") in MOVING]
            parts.append(f"{r!r} ({', '.join(map(repr, moving)) or 'no moving joints'})")
        raise ValueError(
            f"{where}: the URDF has {len(roots)} root links (links that are no joint's child): "
            f"{'; '.join(parts)}. A robot description must be one tree: attach each extra root "
            "to the tree with a joint (a fixed joint, if it does not move), or remove it"
        )
    reached = set(roots) | {
        _link_of(joints[jn], "child", where) for r in roots for jn in subtree_joints(r)
    }
    if len(reached) < len(links):
        start = next(n for n in links if n not in reached)
        path, seen = [], set()
        link = start
        while link not in seen:  # every unreached link has a parent: walk up to the cycle
            seen.add(link)
            path.append(link)
            link = _link_of(joints[parent_of[link]], "parent", where)
        cycle = path[path.index(link) :] + [link]
        loop_joints = [parent_of[n] for n in cycle[:-1]]
        raise ValueError(
            f"{where}: kinematic loop: links {' <- '.join(map(repr, cycle))} (joints "
            f"{', '.join(map(repr, loop_joints))}); URDF describes a tree with one root link, "
            "closed loops are not supported"
        )


def _check_moving(joints: dict[str, ET.Element], where: str) -> None:
    """At least one moving joint, none of them a ``<mimic>`` joint."""
    moving = [n for n, j in joints.items() if j.get("type") in MOVING]
    if not moving:
        raise ValueError(
            f"{where}: every joint is fixed ({', '.join(map(repr, joints))}); a model needs at "
            "least one revolute, continuous or prismatic joint"
        )
    mimics = {
        n: joints[n].find("mimic").get("joint")
        for n in moving
        if joints[n].find("mimic") is not None
    }
    if mimics:
        pairs = ", ".join(f"{n!r} mimics {m!r}" for n, m in mimics.items())
        lock = tuple(dict.fromkeys([*mimics, *(m for m in mimics.values() if m in joints)]))
        held = "hold them at q = 0 (their links are lumped into the parent)"
        if set(lock) >= set(moving):  # fixing the leaders too would leave nothing to move
            lock = tuple(mimics)
            held = "hold the followers at q = 0 while the joints they follow move alone"
        raise ValueError(
            f"{where}: {len(mimics)} mimic joint(s) (a <mimic> element: the position follows "
            f"another joint's): {pairs}; coupled joints are not supported. Pass "
            f"fixed_joints={lock!r} (on the command line: --fixed-joints {','.join(lock)}) to "
            f"{held}, or delete the <mimic> elements to identify each as an independent joint"
        )


def pk_chain_from_urdf(links: dict[str, ET.Element], joints: dict[str, ET.Element], where: str):
    """pytorch-kinematics' chain of a checked URDF, built quietly from a minimal copy.

    Raises:
        ValueError: if pytorch-kinematics cannot parse it (its message included).
    """
    import pytorch_kinematics as pk

    robot = ET.Element("robot", name="torchjfa")
    for name in links:
        ET.SubElement(robot, "link", name=name)
    for j in joints.values():
        copy = ET.SubElement(robot, "joint", name=j.get("name"), type=j.get("type"))
        for tag in _PK_JOINT_TAGS:
            for e in j.findall(tag):
                if tag == "limit" and (e.get("effort") is None or e.get("velocity") is None):
                    continue  # urdf_parser_py requires both; the chain's limits are not used
                copy.append(e)
    text = ET.tostring(robot, encoding="unicode")
    sink = io.StringIO()
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            return pk.build_chain_from_urdf(text)
    except Exception as exc:  # urdf_parser_py raises its own ParseError, lxml others
        said = sink.getvalue().strip()
        extra = f" (it printed: {said})" if said else ""
        raise ValueError(
            f"{where}: pytorch-kinematics cannot build the chain: {type(exc).__name__}: "
            f"{exc}{extra}"
        ) from exc


def resolve_mesh(filename: str, source_path: str | None) -> str | None:
    """The absolute path of a URDF mesh file name, or None where it cannot be found.

    ``package://PKG/REST`` is looked up, without ROS, in the folders of ``$ROS_PACKAGE_PATH``
    (``PKG/REST`` in each) and in the description's own folders: the first ancestor named
    ``PKG`` (``ANCESTOR/REST``), or with a subfolder ``PKG``. A relative name is taken from
    the description's folder; ``file://`` is stripped.
    """
    if filename.startswith("file://"):
        filename = filename[len("file://") :]
    here = Path(source_path).resolve().parent if source_path else None
    if not filename.startswith("package://"):
        found = Path(filename) if os.path.isabs(filename) or here is None else here / filename
        return str(found) if found.is_file() else None
    package, _, rest = filename[len("package://") :].partition("/")
    roots = [
        Path(p) / package for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p
    ]
    if here is not None:
        for folder in (here, *here.parents):
            if folder.name == package:
                roots.append(folder)
            roots.append(folder / package)
    for root in roots:
        if (root / rest).is_file():
            return str((root / rest).resolve())
    return None

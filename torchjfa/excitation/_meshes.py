"""The description's own collision geometry, checked with MuJoCo's collision detection.

`MeshGeometry` loads the robot description into MuJoCo with its collision geometry (URDF
``<collision>`` elements, ``package://`` and relative mesh paths resolved against the folders
above the file, visuals dropped; MJCF geoms that collide, ``contype``/``conaffinity``), adds
the mounting plane as a plane geom, and measures, at each sample, the signed distance
(`mujoco.mj_geomDistance`, up to `_REACH`) between every pair of bodies that MuJoCo would let
collide (their geoms' ``contype``/``conaffinity``; not a parent and its child; not a pair the
description excludes) and between each body and the plane. Meshes count as their convex
hulls, which contain them, so the distances are on the safe side.

Required: the clearance to the plane; between two bodies the clearance, or half their
distance at the posture the trajectory starts from when that is less (parts close by design,
such as a wrist's links); bodies touching at the posture are left out, and so is the plane for
bodies whose height no joint motion changes (the base and what turns on a vertical first
axis). `violations` has the capsules' interface (required less actual distance, m;
`torchjfa.excitation._geometry`).
`mesh_geometry` returns None with the reason when the description has no collision geometry
or MuJoCo cannot load it (a mesh file that is not there, a format it does not read).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import torch

__all__ = ["MeshGeometry", "mesh_geometry"]

#: m: distances are measured up to this; farther pairs count as this far
_REACH = 0.1
#: random postures used to find the bodies whose height no joint motion changes
_N_SAMPLES = 32
#: m (and the axes' z components): a body whose height profile varies by less is mounted
#: (descriptions write pi and vertical axes to a few digits)
_FIXED = 1e-5


def _urdf_for_mujoco(text: str, path: str | None) -> tuple[str, list[str]]:
    """The URDF with visuals dropped, mesh paths made absolute (collisions whose mesh is not
    found dropped: their names returned) and MuJoCo's compiler told to keep the paths."""
    from ..dynamics._mjcf import mujoco_collisions, strip_urdf_for_mujoco

    root = strip_urdf_for_mujoco(
        ET.fromstring(text), keep=("collision",), strippath="false", balanceinertia="true"
    )
    missing = mujoco_collisions(root, path)
    return ET.tostring(root, encoding="unicode"), missing


def _spec(model):
    """A `mujoco.MjSpec` of the description (URDF through `_urdf_for_mujoco`)."""
    import mujoco

    if model.source_format == "urdf":
        text, missing = _urdf_for_mujoco(model.source_xml, model.source_path)
        return mujoco.MjSpec.from_string(text), missing
    if model.source_path:
        return mujoco.MjSpec.from_file(model.source_path), []
    return mujoco.MjSpec.from_string(model.source_xml), []


def mesh_geometry(model, posture, low, high, *, floor, self_collision, clearance):
    """``(MeshGeometry, "")``, or ``(None, why)`` when it cannot be built.

    Args: as `MeshGeometry`.
    """
    try:
        import mujoco

        spec, missing = _spec(model)
        if floor is not None:
            plane = spec.worldbody.add_geom()
            plane.type = mujoco.mjtGeom.mjGEOM_PLANE
            plane.size = [0.0, 0.0, 1.0]
            plane.pos = [0.0, 0.0, float(floor)]
            plane.contype = plane.conaffinity = (1 << 31) - 1  # every geom that collides
            plane.name = "torchjfa_mounting_plane"
        mj = spec.compile()
    except Exception as exc:  # MuJoCo's own errors have no common base class
        return None, f"MuJoCo cannot load the description's collision geometry ({exc})"
    geom = MeshGeometry(
        mj, model, posture, low, high, floor=floor, self_collision=self_collision,
        clearance=clearance,
    )  # fmt: skip
    if not geom.bodies:
        if missing:
            shown = ", ".join(missing[:3]) + (", ..." if len(missing) > 3 else "")
            return None, f"MuJoCo cannot use the description's collision meshes ({shown})"
        return None, "the description has no collision geometry on the moving bodies"
    geom.missing = missing
    return geom, ""


class MeshGeometry:
    """Distances between the description's collision geometry, and to the mounting plane.

    Args:
        mj: the compiled `mujoco.MjModel` (with the plane named
            ``torchjfa_mounting_plane`` when ``floor`` is set).
        model: the `RigidBodyModel` (its joints are matched to MuJoCo's by name).
        posture, low, high, floor, self_collision, clearance: as `CapsuleGeometry`.

    Attributes:
        bodies: MuJoCo's bodies with collision geometry that joints move.
        floor_bodies: those checked against the plane.
        skipped: the pairs left out (touching at the posture), ``"body / body"``.
        missing: mesh files the description names and MuJoCo could not use.
    """

    def __init__(self, mj, model, posture, low, high, *, floor, self_collision, clearance):
        import mujoco

        self._mj, self._mujoco = mj, mujoco
        self.floor, self.clearance = floor, float(clearance)
        self.missing: list[str] = []
        self._data = mujoco.MjData(mj)
        self._adr = []
        for name in model.joint_names:
            jid = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid < 0:
                raise ValueError(f"MuJoCo's model of the description has no joint {name!r}")
            self._adr.append(int(mj.jnt_qposadr[jid]))
        pid = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_GEOM, "torchjfa_mounting_plane")
        self._plane = pid if floor is not None else -1
        self._gbody = np.asarray(mj.geom_bodyid)
        self._geoms = [g for g in range(mj.ngeom) if g != self._plane
                       and (mj.geom_contype[g] != 0 or mj.geom_conaffinity[g] != 0)]  # fmt: skip
        with_geoms = sorted({int(self._gbody[g]) for g in self._geoms})
        self.bodies = [b for b in with_geoms if b > 0 and self._moved(b)]
        self._names = [mj.body(b).name or f"body {b}" for b in range(mj.nbody)]
        q0 = np.asarray(posture, dtype=np.float64)
        rng = np.random.default_rng(0)
        qs = np.asarray(low) + (np.asarray(high) - np.asarray(low)) * rng.random(
            (_N_SAMPLES, len(q0))
        )
        self.floor_bodies = [b for b in self.bodies if floor is not None and self._varies(b, qs)]
        #: per column: the body pair ((-1, b): the plane), its geom pairs, the distance required
        self._keys = [(-1, b) for b in self.floor_bodies]
        self._pairs = [[(self._plane, g) for g in self._geoms if self._gbody[g] == b]
                       for b in self.floor_bodies]  # fmt: skip
        self._need = [self.clearance] * len(self._keys)
        self._n_floor = len(self._keys)
        self.skipped: list[str] = []
        if self_collision:
            self._choose_pairs(with_geoms, q0)

    def _choose_pairs(self, with_geoms: list[int], q0: np.ndarray) -> None:
        """The body pairs checked, and the distance each requires (see the module)."""
        mj = self._mj
        parent = mj.body_parentid
        excluded = {int(x) for x in mj.exclude_signature[: mj.nexclude]}
        cand, geoms = [], []
        for i, a in enumerate(with_geoms):
            for b in with_geoms[i + 1 :]:
                moved = a in self.bodies or b in self.bodies
                if not moved or parent[b] == a or parent[a] == b or (a << 16) + b in excluded:
                    continue
                pairs = [
                    (g, h)
                    for g in self._geoms
                    if self._gbody[g] == a
                    for h in self._geoms
                    if self._gbody[h] == b and self._collide(g, h)
                ]
                if pairs:
                    cand.append((a, b))
                    geoms.append(pairs)
        start = len(self._keys)
        self._keys += cand
        self._pairs += geoms
        at_rest = self._distances(q0[None])[0]
        keep = list(range(start))
        for c in range(start, len(self._keys)):
            a, b = self._keys[c]
            if at_rest[c] > 1e-6:
                keep.append(c)
                self._need.append(min(self.clearance, 0.5 * float(at_rest[c])))
            else:
                self.skipped.append(f"{self._names[a]} / {self._names[b]}")
        self._keys = [self._keys[c] for c in keep]
        self._pairs = [self._pairs[c] for c in keep]

    def _collide(self, g: int, h: int) -> bool:
        mj = self._mj
        return bool(mj.geom_contype[g] & mj.geom_conaffinity[h]
                    or mj.geom_contype[h] & mj.geom_conaffinity[g])  # fmt: skip

    def _moved(self, b: int) -> bool:
        """Does a joint move body ``b`` (directly or through its ancestors)?"""
        mj = self._mj
        while b > 0:
            if mj.body_jntnum[b] > 0:
                return True
            b = int(mj.body_parentid[b])
        return False

    def _varies(self, b: int, qs: np.ndarray) -> bool:
        """Does body ``b``'s height profile (its origin's z and its axes' z components)
        change over the postures ``qs``?"""
        mujoco, mj, d = self._mujoco, self._mj, self._data
        rows = []
        for q in qs:
            d.qpos[self._adr] = q
            mujoco.mj_kinematics(mj, d)
            rows.append(np.r_[d.xpos[b, 2], d.xmat[b, 6:9]])
        rows = np.array(rows)
        return bool(np.any(rows.max(0) - rows.min(0) > _FIXED))

    def _distances(self, qs: np.ndarray) -> np.ndarray:
        """``(n, n_columns)`` the smallest signed distance of each column's geoms at each
        posture, m (up to `_REACH`)."""
        mujoco, mj, d = self._mujoco, self._mj, self._data
        dist = mujoco.mj_geomDistance
        out = np.full((len(qs), len(self._keys)), _REACH)
        for i, q in enumerate(qs):
            d.qpos[self._adr] = q
            mujoco.mj_kinematics(mj, d)
            for c, pairs in enumerate(self._pairs):
                out[i, c] = min(dist(mj, d, g, h, _REACH, None) for g, h in pairs)
        return out

    def body_id(self, name: str | None) -> int:
        """MuJoCo's id of the body ``name`` (None: the world, with the fixed base), or -1."""
        if name is None:
            return 0
        return self._mujoco.mj_name2id(self._mj, self._mujoco.mjtObj.mjOBJ_BODY, name)

    def checks_pair(self, a: int, b: int) -> bool:
        """Are bodies ``a`` and ``b`` (MuJoCo ids) checked against each other?"""
        return (min(a, b), max(a, b)) in self._keys[self._n_floor :]

    def witness(self, q, column: int):
        """The closest points of the pair of column ``column`` of ``violations(q)
        ["collision"]`` at the posture ``q``: ``(body_a, point_a, body_b, point_b)``, each
        point in its body's frame, m (body: MuJoCo's name, None for the world)."""
        mujoco, mj, d = self._mujoco, self._mj, self._data
        d.qpos[self._adr] = np.asarray(q, dtype=np.float64)
        mujoco.mj_kinematics(mj, d)
        best, fromto = None, np.zeros(6)
        for g, h in self._pairs[self._n_floor + column]:
            x = mujoco.mj_geomDistance(mj, d, g, h, _REACH, fromto)
            if best is None or x < best[0]:
                best = (x, (int(self._gbody[g]), int(self._gbody[h])), fromto.copy())
        out = []
        for b, p in zip(best[1], (best[2][:3], best[2][3:]), strict=True):
            R = d.xmat[b].reshape(3, 3)
            out += [None if b == 0 else self._names[b], R.T @ (p - d.xpos[b])]
        return tuple(out)

    def bounding_radius(self, body: int, posture, start, end) -> float | None:
        """The radius of the capsule about the segment ``start end`` (root frame, m, at
        ``posture``) that holds body ``body``'s collision geometry (mesh vertices; the
        bounding sphere of other shapes); None when the body has none."""
        mujoco, mj, d = self._mujoco, self._mj, self._data
        d.qpos[self._adr] = np.asarray(posture, dtype=np.float64)
        mujoco.mj_kinematics(mj, d)
        p, e = np.asarray(start, dtype=np.float64), np.asarray(end, dtype=np.float64)
        seg = e - p
        length2 = float(seg @ seg)
        best = None
        unbounded = (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD)
        for g in (g for g in self._geoms if self._gbody[g] == body):
            if mj.geom_type[g] in unbounded:  # a ground the description brings
                continue
            R = d.geom_xmat[g].reshape(3, 3)
            if mj.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
                m = mj.geom_dataid[g]
                v = mj.mesh_vert[mj.mesh_vertadr[m] : mj.mesh_vertadr[m] + mj.mesh_vertnum[m]]
                pts, extra = d.geom_xpos[g] + v @ R.T, 0.0
            else:
                pts, extra = d.geom_xpos[g][None], float(mj.geom_rbound[g])
            s = np.clip((pts - p) @ seg / length2, 0, 1) if length2 > 0 else np.zeros(len(pts))
            r = float(np.linalg.norm(pts - p - s[:, None] * seg, axis=1).max()) + extra
            best = r if best is None else max(best, r)
        return best

    @property
    def kinds(self) -> tuple[str, ...]:
        """The constraints in use: ``"floor"`` and / or ``"collision"``."""
        n_pairs = len(self._keys) - self._n_floor
        return tuple(k for k, on in (("floor", self._n_floor), ("collision", n_pairs)) if on)

    def labels(self, kind: str) -> list[str]:
        """What each column of ``violations(q)[kind]`` is: a body, or ``"body / body"``."""
        if kind == "floor":
            return [self._names[b] for _, b in self._keys[: self._n_floor]]
        return [f"{self._names[a]} / {self._names[b]}" for a, b in self._keys[self._n_floor :]]

    def required(self, kind: str) -> list[float]:
        """The distance each column of ``violations(q)[kind]`` requires, m."""
        return self._need[: self._n_floor] if kind == "floor" else self._need[self._n_floor :]

    def violations(self, q) -> dict[str, torch.Tensor]:
        """``{"floor": (n, n_bodies), "collision": (n, n_pairs)}`` (those in use): the
        distance required (`required`) less the actual one, m (> 0: violated); pairs farther
        than `_REACH` count as `_REACH` apart. Not differentiable."""
        qn = q.detach().cpu().numpy() if isinstance(q, torch.Tensor) else np.asarray(q)
        v = torch.as_tensor(np.asarray(self._need) - self._distances(qn), dtype=torch.float64)
        out = {}
        if self._n_floor:
            out["floor"] = v[:, : self._n_floor]
        if len(self._keys) > self._n_floor:
            out["collision"] = v[:, self._n_floor :]
        return out

    def describe(self) -> str:
        """One line: what is checked."""
        n_pairs = len(self._keys) - self._n_floor
        floor = (
            f"the floor at z = {self.floor:g} m ({self._n_floor} bodies), " if self._n_floor else ""
        )
        return (
            f"the description's collision geometry (MuJoCo), {self.clearance:g} m clear of "
            f"{floor}{n_pairs} pairs of bodies"
        )

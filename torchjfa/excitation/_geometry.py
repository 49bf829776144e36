"""The mounting plane and self-collision: capsules along the links, differentiable in q.

An excitation must not drive the arm into the surface it is mounted on, nor into itself.
`CapsuleGeometry` models the arm as capsules (segments with a radius) between consecutive
frames of the forward kinematics (`RigidBodyModel.forward_kinematics`):

* the base: from the root frame's origin to the origin of each body the first joints move,
* each moving body: from its origin to the origin of each child body; a body without a child
  body reaches to its farthest frame fixed to it (a flange, a tool link), or is a sphere at
  its origin.

The radius holds the link's collision geometry where the description has some (its mesh
vertices' largest distance from the segment, `torchjfa.excitation._meshes`), else it is one
number for every capsule (`DEFAULT_CAPSULE_RADIUS`, typical of the links of 3-10 kg arms such
as the UR5, the Franka Panda or the xArm7; give the real one for a smaller or larger robot).

Two constraints, in metres, with a clearance ``c`` (default `DEFAULT_CLEARANCE`):

* floor: every capsule end ``p`` (radius ``r``) stays above the plane ``z = h`` of the root
  frame: ``p_z - r >= h + c`` (the lowest point of a capsule is one of its ends). Ends whose
  height no joint motion changes (the base, points on a vertical first axis, points on the
  axis of a joint they are carried by) are mounted where the description puts them and are
  not checked;
* self-collision: two capsules that are not adjacent (not on the same body, not on a body and
  its parent) keep ``|closest points| - r_1 - r_2 >= c``, or half their gap at the posture the
  trajectory starts from where that is less (parts close by design); capsules overlapping at
  the posture are left out (`CapsuleGeometry.skipped`). With collision geometry the pairs are
  those its check keeps, and capsules that overlap at the posture (being larger than the
  geometry) keep their segments no closer than `_KEEP` below their distance there.

`violations` gives, per sample, ``required - actual`` distance (> 0: violated; metres), the
optimiser's penalty. `Geometry` bundles the capsules with the description's collision geometry
(the dense-grid check's, `Geometry.check`) and the cuts added where that geometry came closer
than the capsules allowed (`Geometry.add_witness`); `start_geometry` chooses the posture (the
middle of the limits moves clear of the floor, `safe_posture`) and builds it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

__all__ = ["CapsuleGeometry", "DEFAULT_CAPSULE_RADIUS", "DEFAULT_CLEARANCE", "safe_posture"]

#: m: the distance kept to the floor and between non-adjacent parts of the arm, beyond the
#: capsules' radii (or the collision geometry's surfaces)
DEFAULT_CLEARANCE = 0.02
#: m: the radius of the capsules along the links when the user gives none
DEFAULT_CAPSULE_RADIUS = 0.05
#: random postures used to find the points whose height no joint motion changes
_N_SAMPLES = 64
#: m: a point whose height varies by less than this over those postures is mounted
#: (descriptions write pi and vertical axes to a few digits)
_FIXED_HEIGHT = 1e-5
#: m: a default posture closer than this (beyond the clearance) to the floor or between links
#: is moved until it is this far (`safe_posture`), so the excitation has room to move
_POSTURE_ROOM = 0.05
#: m: capsules closer than their radii and the clearance at the posture, whose collision
#: geometry is not, keep their segments no closer than this below their distance there
_KEEP = 0.01


@dataclass(frozen=True)
class Capsule:
    """A segment between two frames' origins, with a radius.

    Attributes:
        body: the body that carries it (a `RigidBodyModel.body_names` entry, or the root
            frame's name for the base).
        start, end: frames whose origins are its ends.
        radius: m.
    """

    body: str
    start: str
    end: str
    radius: float


def _capsules(model, q0: torch.Tensor, radius: float, meshes=None) -> list[tuple[Capsule, int]]:
    """``[(capsule, owner)]``: the base's (owner -1) and each moving body's (owner: its joint
    index) capsules at the posture ``q0`` (the farthest fixed frame is measured there); their
    radius holds the body's collision geometry where ``meshes`` (a `MeshGeometry`) has some,
    else ``radius``."""
    out = _segments(model, q0, radius)
    if meshes is None:
        return out
    frames = list(dict.fromkeys(f for c, _ in out for f in (c.start, c.end)))
    ends = dict(zip(frames, model.forward_kinematics(q0, frames)[..., :3, 3].numpy(),
                    strict=True))  # fmt: skip
    sized = []
    for cap, k in out:
        body = meshes.body_id(None if k < 0 else cap.body)
        r = (
            meshes.bounding_radius(body, q0.numpy(), ends[cap.start], ends[cap.end])
            if body >= 0
            else None
        )
        sized.append((Capsule(cap.body, cap.start, cap.end, radius if r is None else r), k))
    return sized


def _segments(model, q0: torch.Tensor, radius: float) -> list[tuple[Capsule, int]]:
    """`_capsules` all of ``radius``."""
    names, parents = model.body_names, model.parents
    root = model.frame_names[0]
    out = []
    for k in range(model.n_dof):
        if parents[k] < 0:
            out.append((Capsule(root, root, names[k], radius), -1))
    for k, name in enumerate(names):
        children = [names[c] for c in range(model.n_dof) if parents[c] == k]
        if not children:
            fixed = list(model.lumped_bodies.get(model.joint_names[k], ()))
            if fixed:
                T = model.forward_kinematics(q0, [name, *fixed])[..., :3, 3]
                far = int(torch.argmax((T[1:] - T[0]).norm(dim=-1)))
                children = [fixed[far]]
            else:
                children = [name]
        out.extend((Capsule(name, name, c, radius), k) for c in children)
    return out


def _segment_distance(p1, q1, p2, q2) -> torch.Tensor:
    """Distance between segments ``p1 q1`` and ``p2 q2`` (``(..., 3)`` each), differentiable.

    The closest points' parameters are found without autograd (Ericson, *Real-Time Collision
    Detection*, 5.1.9, with zero-length segments allowed); the distance between the points at
    those parameters has the distance's gradient (the parameters are at an optimum).
    """
    with torch.no_grad():
        d1, d2, r = q1 - p1, q2 - p2, p1 - p2
        a, e = (d1 * d1).sum(-1), (d2 * d2).sum(-1)
        b, c, f = (d1 * d2).sum(-1), (d1 * r).sum(-1), (d2 * r).sum(-1)
        tiny = 1e-18
        denom = a * e - b * b
        s = torch.where(denom > tiny, ((b * f - c * e) / denom.clamp_min(tiny)).clamp(0, 1), 0.0)
        t = torch.where(e > tiny, (b * s + f) / e.clamp_min(tiny), 0.0)
        s_low = torch.where(a > tiny, (-c / a.clamp_min(tiny)).clamp(0, 1), 0.0)
        s_high = torch.where(a > tiny, ((b - c) / a.clamp_min(tiny)).clamp(0, 1), 0.0)
        s = torch.where(t < 0, s_low, torch.where(t > 1, s_high, s))
        t = t.clamp(0, 1)
    gap = p1 + s[..., None] * (q1 - p1) - p2 - t[..., None] * (q2 - p2)
    return ((gap * gap).sum(-1) + 1e-30).sqrt()


class CapsuleGeometry:
    """Capsules along the links of ``model``, checked against a floor and each other.

    Args:
        model: the robot (`RigidBodyModel`).
        posture: ``(n_dof,)`` the posture the trajectory starts from, rad (m): the pairs in
            contact there are left out, and the floor must hold there.
        low, high: ``(n_dof,)`` the position limits, for the random postures that find the
            mounted points.
        floor: the plane's height in the root frame, m; None: no floor.
        self_collision: check pairs of capsules against each other.
        clearance: m, kept beyond the radii.
        radius: m, of the capsules of bodies without collision geometry in ``meshes``.
        meshes: the description's collision geometry (`MeshGeometry`): each body's capsules
            get the radius that holds it (at the posture).

    Attributes:
        capsules: the `Capsule` s.
        floor_points: the frames whose origins (capsule ends) the floor check keeps.
        pairs: ``[(i, j)]`` indices of the capsule pairs checked.
        skipped: the pairs left out, ``"body / body"``.
    """

    def __init__(
        self, model, posture, low, high, *, floor, self_collision, clearance, radius, meshes=None
    ):
        self.model, self.floor, self.clearance = model, floor, float(clearance)
        if not float(radius) >= 0 or not self.clearance >= 0:
            raise ValueError(
                f"capsule radius and clearance must be >= 0 m, got {radius} and {clearance}"
            )
        q0 = torch.as_tensor(np.asarray(posture, dtype=np.float64))
        built = _capsules(model, q0, float(radius), meshes)
        self.capsules = [c for c, _ in built]
        owner = [k for _, k in built]
        self.frames = list(dict.fromkeys(f for c in self.capsules for f in (c.start, c.end)))
        where = {f: i for i, f in enumerate(self.frames)}
        self._start = torch.tensor([where[c.start] for c in self.capsules])
        self._end = torch.tensor([where[c.end] for c in self.capsules])
        self._r = torch.tensor([c.radius for c in self.capsules], dtype=torch.float64)
        #: per frame, the largest radius of the capsules that end there
        self._end_r = torch.zeros(len(self.frames), dtype=torch.float64)
        for c in self.capsules:
            for f in (c.start, c.end):
                self._end_r[where[f]] = max(float(self._end_r[where[f]]), c.radius)
        self.floor_points: list[str] = []
        if floor is not None:
            g = torch.Generator().manual_seed(0)
            lo, hi = (torch.as_tensor(np.asarray(x, dtype=np.float64)) for x in (low, high))
            qs = lo + (hi - lo) * torch.rand(_N_SAMPLES, len(lo), generator=g, dtype=lo.dtype)
            z = self._origins(torch.cat([q0[None], qs]))[..., 2]
            moves = (z.amax(0) - z.amin(0)) > _FIXED_HEIGHT
            self.floor_points = [f for f, m in zip(self.frames, moves.tolist(), strict=True) if m]
        self._floor_idx = torch.tensor([where[f] for f in self.floor_points], dtype=torch.long)
        #: per floor point, the radius kept to the floor
        self.floor_radius = self._end_r[self._floor_idx]
        self.pairs: list[tuple[int, int]] = []
        self.skipped: list[str] = []
        self._need: list[float] = []
        if self_collision:
            self._choose_pairs(model.parents, owner, q0, meshes)
        self._i = torch.tensor([i for i, _ in self.pairs], dtype=torch.long)
        self._j = torch.tensor([j for _, j in self.pairs], dtype=torch.long)
        self._need_t = torch.tensor(self._need, dtype=torch.float64)

    def _choose_pairs(self, parents, owner, q0, meshes) -> None:
        """The non-adjacent capsule pairs and the distance each keeps between its segments.

        Without ``meshes``: the radii plus the clearance, or, for capsules closer than the
        clearance at ``q0``, half their distance there; capsules that overlap at ``q0`` are left
        out. With them: the pairs whose bodies' geometry ``meshes`` checks, apart by the
        radii plus the clearance, or, where the capsules (which hold the geometry, so are
        larger) are that close at ``q0``, by no less than `_KEEP` below their distance there.
        """
        n = len(self.capsules)
        cand = []
        for i in range(n):
            for j in range(i + 1, n):
                a, b = owner[i], owner[j]
                adjacent = a == b or (b >= 0 and parents[b] == a) or (a >= 0 and parents[a] == b)
                if not adjacent:
                    cand.append((i, j))
        if not cand:
            return
        ends = self._origins(q0[None])[0]
        i, j = (torch.tensor(x) for x in zip(*cand, strict=True))
        dist = _segment_distance(
            ends[self._start[i]], ends[self._end[i]], ends[self._start[j]], ends[self._end[j]]
        )
        for (a, b), d in zip(cand, dist.tolist(), strict=True):
            ca, cb = self.capsules[a], self.capsules[b]
            need = ca.radius + cb.radius + self.clearance
            if meshes is not None:
                ids = [meshes.body_id(None if owner[k] < 0 else self.capsules[k].body)
                       for k in (a, b)]  # fmt: skip
                if meshes.checks_pair(*ids):
                    self.pairs.append((a, b))
                    self._need.append(min(need, d - _KEEP))
            elif d > ca.radius + cb.radius + 1e-6:
                self.pairs.append((a, b))
                self._need.append(min(need, 0.5 * (d + ca.radius + cb.radius)))
            else:
                self.skipped.append(f"{ca.body} / {cb.body}")

    def _origins(self, q: torch.Tensor) -> torch.Tensor:
        """``(n, n_frames, 3)`` origins of `frames`, m."""
        return self.model.forward_kinematics(q, self.frames)[..., :3, 3]

    @property
    def kinds(self) -> tuple[str, ...]:
        """The constraints in use: ``"floor"`` and / or ``"collision"``."""
        return tuple(k for k, on in (("floor", self.floor_points), ("collision", self.pairs)) if on)

    def required(self, kind: str) -> list[float]:
        """The distance between surfaces each column of ``violations(q)[kind]`` requires, m."""
        if kind == "floor":
            return [self.clearance] * len(self.floor_points)
        return [n - float(self._r[i] + self._r[j]) for n, (i, j) in
                zip(self._need, self.pairs, strict=True)]  # fmt: skip

    def labels(self, kind: str) -> list[str]:
        """What each column of ``violations(q)[kind]`` is: a frame, or ``"body / body"``."""
        if kind == "floor":
            return list(self.floor_points)
        return [f"{self.capsules[i].body} / {self.capsules[j].body}" for i, j in self.pairs]

    def violations(self, q: torch.Tensor) -> dict[str, torch.Tensor]:
        """``{"floor": (n, n_points), "collision": (n, n_pairs)}`` (those in use): the
        required distance less the actual one, m (> 0: violated); differentiable in q."""
        ends = self._origins(q)
        out = {}
        if self.floor_points:
            z = ends[:, self._floor_idx, 2]
            out["floor"] = self.floor + self.clearance + self.floor_radius - z
        if self.pairs:
            s, e = ends[:, self._start], ends[:, self._end]
            i, j = self._i, self._j
            dist = _segment_distance(s[:, i], e[:, i], s[:, j], e[:, j])
            out["collision"] = self._need_t - dist
        return out

    def describe(self) -> str:
        """One line: what is checked."""
        parts = []
        if self.floor_points:
            parts.append(f"the floor at z = {self.floor:g} m ({len(self.floor_points)} points)")
        if self.pairs:
            parts.append(f"{len(self.pairs)} pairs of non-adjacent links")
        what = " and ".join(parts) or "nothing"
        lo, hi = float(self._r.min()), float(self._r.max())
        size = f"{lo:.3g} m" if hi - lo < 1e-9 else f"{lo:.3g}-{hi:.3g} m"
        return f"capsules of radius {size} along the links, {self.clearance:g} m clear of {what}"


def safe_posture(
    geometry: CapsuleGeometry, q_start, low, high, *, room: float = _POSTURE_ROOM, steps=100
):
    """The posture nearest ``q_start`` where the capsules are ``room`` beyond the clearance
    from the floor (and no closer than required in the pairs they check); ``q_start`` itself
    when it already is.

    A quadratic penalty on the violations, its weight raised over rounds, plus the squared
    distance to ``q_start`` (rad), minimised by LBFGS from ``q_start``.

    Args:
        geometry: the `CapsuleGeometry` (its floor and pairs).
        q_start: ``(n_dof,)`` the preferred posture (e.g. the middle of the limits).
        low, high: ``(n_dof,)`` the position limits (the posture stays 0.1 % inside them).
        room: m, aimed at beyond the floor's clearance.
        steps: LBFGS iterations per round.

    Returns:
        ``(n_dof,)`` numpy posture (at least clear of the floor, if not by ``room``), or None
        when no posture near ``q_start`` keeps the clearance.
    """
    lo, hi = (torch.as_tensor(np.asarray(x, dtype=np.float64)) for x in (low, high))
    q0 = torch.as_tensor(np.asarray(q_start, dtype=np.float64))
    inner_lo, inner_hi = lo + 1e-3 * (hi - lo), hi - 1e-3 * (hi - lo)
    aim = {"floor": float(room), "collision": 0.0}

    def worst(q, kinds=("floor",)) -> float:
        v = geometry.violations(q[None])
        return max((float(v[k].max()) for k in kinds if k in v), default=-1.0)

    if worst(q0) <= -aim["floor"]:
        return q0.numpy()
    u = torch.zeros_like(q0, requires_grad=True)  # q = q0 + u, rad
    for weight in (1e2, 1e4, 1e6):
        opt = torch.optim.LBFGS([u], lr=1.0, max_iter=steps, line_search_fn="strong_wolfe")

        def closure(weight=weight, opt=opt):
            opt.zero_grad()
            q = torch.minimum(torch.maximum(q0 + u, inner_lo), inner_hi)
            v = geometry.violations(q[None])
            pen = sum((torch.relu(x + aim[k]) ** 2).sum() for k, x in v.items()) / room**2
            loss = (u * u).sum() + weight * pen
            loss.backward()
            return loss

        opt.step(closure)
    with torch.no_grad():
        q = torch.minimum(torch.maximum(q0 + u, inner_lo), inner_hi)
    return q.numpy() if worst(q, ("floor", "collision")) < 0 else None


class Geometry:
    """The floor and self-collision constraints of an excitation starting at a posture.

    `violations` (the optimiser's, differentiable) are the capsules'; `check` (the dense-grid
    check's) is the description's collision geometry through MuJoCo where it has some (with
    the frame origins against the floor, clearance only), else the capsules.

    Attributes:
        capsules: the `CapsuleGeometry`.
        meshes: the `torchjfa.excitation._meshes.MeshGeometry`, or None.
        note: why ``meshes`` is None ("" when it is not).
    """

    def __init__(self, model, limits, posture, *, use_meshes: bool = True) -> None:
        from ._meshes import mesh_geometry

        floor = limits.floor
        kw = {"floor": floor, "self_collision": limits.self_collision,
              "clearance": limits.clearance}  # fmt: skip
        lo, hi = limits.position_low, limits.position_high
        self.meshes, self.note = None, "not asked for"
        if use_meshes:
            self.meshes, self.note = mesh_geometry(model, posture, lo, hi, **kw)
        self.capsules = CapsuleGeometry(model, posture, lo, hi, radius=limits.capsule_radius,
                                        meshes=self.meshes, **kw)  # fmt: skip
        self.posture = np.asarray(posture, dtype=np.float64)
        self._witness: list = []

    @property
    def kinds(self) -> tuple[str, ...]:
        """The constraints in use (``"floor"``, ``"collision"``)."""
        both = set(self.capsules.kinds) | set(self.meshes.kinds if self.meshes else ())
        return tuple(k for k in ("floor", "collision") if k in both)

    def violations(self, q: torch.Tensor) -> dict[str, torch.Tensor]:
        """The capsules' `CapsuleGeometry.violations`, with the witness points'
        (`add_witness`) after the capsule pairs (m; differentiable)."""
        out = self.capsules.violations(q)
        if self._witness:
            frames = list(dict.fromkeys(f for w in self._witness for f in (w[0], w[2])))
            T = self.capsules.model.forward_kinematics(q, frames)
            where = {f: i for i, f in enumerate(frames)}

            def point(f, p):
                Tf = T[:, where[f]]
                return Tf[:, :3, :3] @ torch.as_tensor(p, dtype=q.dtype) + Tf[:, :3, 3]

            cols = [need - (point(fa, pa) - point(fb, pb)).norm(dim=-1)
                    for fa, pa, fb, pb, need in self._witness]  # fmt: skip
            extra = torch.stack(cols, 1)
            out["collision"] = (
                torch.cat([out["collision"], extra], 1) if "collision" in out else extra
            )
        return out

    def add_witness(self, frame_a: str, point_a, frame_b: str, point_b, need: float) -> None:
        """Keep two points fixed to two frames (the closest points of their bodies' collision
        geometry where it came too close, ``point_*`` in the frames' coordinates, m) ``need``
        m apart in the optimiser's constraints: a cut where the capsules let the geometry
        through (`torchjfa.excitation._problem.repair_geometry`)."""
        self._witness.append((frame_a, np.asarray(point_a, dtype=np.float64), frame_b,
                              np.asarray(point_b, dtype=np.float64), float(need)))  # fmt: skip

    def check(self, q: torch.Tensor) -> dict[str, torch.Tensor]:
        """The dense-grid check's violations, m: the collision geometry's where there is
        some (floor: the frame origins first, then the bodies' geometry), else the capsules'."""
        if self.meshes is None:
            return self.capsules.violations(q)
        with torch.no_grad():
            out = self.meshes.violations(q)
            caps = self.capsules.violations(q)
        if "floor" in caps:
            origins = caps["floor"] - self.capsules.floor_radius
            out["floor"] = torch.cat([origins, out["floor"]], 1) if "floor" in out else origins
        return out

    def labels(self, kind: str) -> list[str]:
        """What each column of ``check(q)[kind]`` is."""
        if self.meshes is None:
            return self.capsules.labels(kind)
        mesh = self.meshes.labels(kind) if kind in self.meshes.kinds else []
        if kind == "floor":
            return [f"{f} (origin)" for f in self.capsules.labels("floor")] + mesh
        return mesh

    def required(self, kind: str) -> list[float]:
        """The distance between surfaces each column of ``check(q)[kind]`` requires, m."""
        if self.meshes is None:
            return self.capsules.required(kind)
        mesh = self.meshes.required(kind) if kind in self.meshes.kinds else []
        if kind == "floor":
            return self.capsules.required("floor") + mesh
        return mesh

    @property
    def skipped(self) -> list[str]:
        """The pairs left out (touching at the posture), of the geometry checked."""
        return self.meshes.skipped if self.meshes is not None else self.capsules.skipped

    def describe(self) -> list[str]:
        """Lines: what the optimiser keeps clear, what the check measures, what is left out."""
        lines = [f"optimised with {self.capsules.describe()}"]
        if self.meshes is not None:
            lines.append(f"checked with {self.meshes.describe()} and the frame origins")
            if self.meshes.missing:
                lines.append(
                    f"collision meshes MuJoCo could not use: {', '.join(self.meshes.missing)}"
                )
        else:
            lines.append(f"checked with the capsules: {self.note}")
        if self.skipped:
            lines.append("left out (touching at the posture): "
                         + ", ".join(self.skipped))  # fmt: skip
        return lines

    def check_posture(self) -> None:
        """Raise a ``ValueError`` naming what is below the floor at the posture."""
        q = torch.as_tensor(self.posture)[None]
        v = self.check(q).get("floor")
        if v is None or float(v.max()) <= 0:
            return
        names = self.labels("floor")
        low = [f"{names[i]} ({float(v[0, i]):.3g} m too low)" for i in
               torch.nonzero(v[0] > 0).flatten().tolist()]  # fmt: skip
        raise ValueError(
            f"at the posture, {', '.join(low)} within {self.capsules.clearance:g} m of the floor "
            f"at z = {self.capsules.floor:g} m (or below it); give another --posture (posture), "
            "the floor's height (--floor) or drop it (--no-floor)"
        )


def start_geometry(model, limits, posture, *, movable: bool):
    """The posture an excitation starts from and its `Geometry`.

    Args:
        model, limits: the robot and its `Limits` (floor, self-collision, clearance, radius).
        posture: ``(n_dof,)`` the posture asked for (or the middle of the limits).
        movable: the posture is a default that may move (`safe_posture`) away from the floor.

    Returns:
        ``(posture, geometry, moved)``.

    Raises:
        ValueError: when the posture (moved, if movable) does not clear the floor.
    """
    q0 = np.asarray(posture, dtype=np.float64)
    geometry = Geometry(model, limits, q0)
    moved = False
    if movable and limits.floor is not None:
        safe = safe_posture(geometry.capsules, q0, limits.position_low, limits.position_high)
        if safe is None:
            raise ValueError(
                "no posture near the middle of the position limits keeps the arm "
                f"{limits.clearance:g} m above the floor at z = {limits.floor:g} m; give a "
                "--posture (posture), the floor's height (--floor) or drop it (--no-floor)"
            )
        moved = bool(np.any(safe != q0))
        if moved:
            q0 = safe
            geometry = Geometry(model, limits, q0)  # the pairs left out, at the new posture
    geometry.check_posture()
    return q0, geometry, moved

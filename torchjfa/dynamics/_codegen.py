"""The regressor as generated C++: one straight-line program per robot, constants folded.

`RigidBodyModel.regressor(..., compiled=True)` runs this instead of `_rnea.regressor_fast`.
The maths is `_rnea`'s (world frame, Plücker axes and velocities at the world origin, then every
(ancestor joint j, body i) pair; see its module docstring), written out per sample as scalar
expressions while walking the tree in Python, with the tree's constants folded in: fixed
rotations, joint axes and offsets become literals, and products with 0 or +-1 disappear (entries
within 1e-14 of 0 or +-1, such as ``cos(pi/2)`` in a URDF ``rpy``, are snapped, which moves the
result by about 1e-16 relative). A body's own joint has a constant axis in the body frame, so
those pairs cost nothing to set up. The 7-DoF Panda arm comes out at about 3,500 multiply/adds
per sample, against some 330 batched torch ops (each a pass over memory) in the eager path.

The program is emitted as C++ over ``W``-sample vectors (GCC/Clang vector extensions: 8 doubles
or 16 floats, one AVX-512 register), each block of ``W`` samples assembled in a tile of ``W``
whole output rows (structural zeros included) and copied out row by row, so the batch-first
output is written once, contiguously. Sines and cosines come from torch (``torch.sin``/``cos``,
the same values as the eager path). `torchjfa.dynamics._kernel` compiles, caches and calls it.

Why not ``torch.compile``: inductor (CPU) splits the same folded program into hundreds of loops
(one per zero column of the stacked output, groups of at most ``max_fusion_size`` nodes),
vectorises only a batch-last output (a batch-first one goes scalar), takes minutes to compile,
and with the transpose into the ``(B, n, n_params)`` layout reaches about Pinocchio's rate.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ._tree import KinematicTree

__all__ = ["kernel_source", "LANES"]

_SNAP = 1e-14
LANES = {torch.float64: 8, torch.float32: 16}  # samples per C++ vector, one AVX-512 register
_CTYPES = {torch.float64: "double", torch.float32: "float"}


# ----------------------------------------------------------------------------- scalar algebra
# A value is a Python float (a constant of the tree) or a `_Sym` (a named C++ vector temporary).
class _Sym:
    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = name


class _Emitter:
    """Writes one ``const V tN = <expr>;`` statement per operation on symbols."""

    def __init__(self, dtype: torch.dtype) -> None:
        self.lines: list[str] = []
        self.f32 = dtype == torch.float32
        self._loads: dict[tuple[str, int], _Sym] = {}

    def lit(self, x: float) -> str:
        if self.f32:
            return f"{float(np.float32(x))!r}f"
        return repr(float(x))

    def new(self, expr: str) -> _Sym:
        s = _Sym(f"t{len(self.lines)}")
        self.lines.append(f"const V {s.name} = {expr};")
        return s

    def load(self, array: str, k: int) -> _Sym:
        key = (array, k)
        if key not in self._loads:
            self._loads[key] = self.new(f"LD({array}, {k})")
        return self._loads[key]

    def _name(self, a) -> str:
        return a.name if isinstance(a, _Sym) else self.lit(a)

    def mul(self, a, b):
        if not isinstance(a, _Sym):
            if not isinstance(b, _Sym):
                return a * b
            a, b = b, a
        if not isinstance(b, _Sym):
            if b == 0.0:
                return 0.0
            if b == 1.0:
                return a
            if b == -1.0:
                return self.new(f"-{a.name}")
        return self.new(f"{a.name} * {self._name(b)}")

    def add(self, a, b):
        if not isinstance(a, _Sym):
            if not isinstance(b, _Sym):
                return a + b
            a, b = b, a
        if not isinstance(b, _Sym) and b == 0.0:
            return a
        return self.new(f"{a.name} + {self._name(b)}")

    def sub(self, a, b):
        if not isinstance(b, _Sym):
            return self.add(a, -b)
        if not isinstance(a, _Sym) and a == 0.0:
            return self.new(f"-{b.name}")
        return self.new(f"{self._name(a)} - {b.name}")

    def sum(self, *terms):
        out = terms[0]
        for t in terms[1:]:
            out = self.add(out, t)
        return out

    # 3-vectors are tuples of 3 values, 3 x 3 matrices tuples of 3 rows
    def mv(self, A, v):
        return tuple(self.sum(*(self.mul(A[r][k], v[k]) for k in range(3))) for r in range(3))

    def mtv(self, A, v):
        return tuple(self.sum(*(self.mul(A[k][r], v[k]) for k in range(3))) for r in range(3))

    def mm(self, A, B):
        return tuple(
            tuple(self.sum(*(self.mul(A[r][k], B[k][c]) for k in range(3))) for c in range(3))
            for r in range(3)
        )

    def cross(self, a, b):
        m, s = self.mul, self.sub
        return (
            s(m(a[1], b[2]), m(a[2], b[1])),
            s(m(a[2], b[0]), m(a[0], b[2])),
            s(m(a[0], b[1]), m(a[1], b[0])),
        )

    def vadd(self, *vs):
        return tuple(self.sum(*comps) for comps in zip(*vs, strict=True))

    def vscale(self, a, s):
        return tuple(self.mul(x, s) for x in a)

    def dot(self, a, b):
        return self.sum(*(self.mul(x, y) for x, y in zip(a, b, strict=True)))


def _snap(x) -> float:
    x = float(x)
    if abs(x) < _SNAP:
        return 0.0
    if abs(abs(x) - 1.0) < _SNAP:
        return math.copysign(1.0, x)
    return x


def _cvec(v) -> tuple[float, ...]:
    return tuple(_snap(x) for x in np.asarray(v, dtype=np.float64))


def _cmat(M) -> tuple[tuple[float, ...], ...]:
    return tuple(_cvec(row) for row in np.asarray(M, dtype=np.float64))


# ----------------------------------------------------------------------------- the program
def _program(tree: KinematicTree, friction: tuple[str, ...], em: _Emitter) -> dict:
    """Emit the regressor of one sample; returns ``{(row j, column): value}`` (non-zero only).

    Reads ``q``, ``qd``, ``qdd``, ``sn`` (sin q) and ``cs`` (cos q) through ``em.load``.
    """
    per = 10 + len(friction)
    entries = _pair_entries(tree, _forward(tree, em), per, em)
    for k in range(len(tree.parent)):
        for f, kind in enumerate(friction):
            entries[(k, k * per + 10 + f)] = {
                "viscous": ("qd", k),
                "coulomb": ("sign", k),
                "armature": ("qdd", k),
                "offset": 1.0,
            }[kind]
    return entries


def _forward(tree: KinematicTree, em: _Emitter) -> dict[str, list]:
    """Emit the world-frame kinematics of every body (`_rnea`'s forward pass), joint by joint.

    Returns:
        Lists over joints: ``R`` body-to-world rotation, ``pos`` body origin, ``z`` joint axis,
        ``m`` the axis' moment about the world origin (revolute joints), and the body's spatial
        velocity (``w``, ``v``) and acceleration (``dw``, ``dv``) at the world origin.
    """
    n = len(tree.parent)
    zero3 = (0.0, 0.0, 0.0)
    ident = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    minus_g = tuple(-x for x in _cvec(tree.gravity))
    ap_all = [_cvec(a) for a in tree.axis_point]
    R, pos, z, m, w, v, dw, dv = ([None] * n for _ in range(8))
    for k in range(n):
        p = tree.parent[k]
        if p < 0:
            Rp, pp, wp, vp, dwp, dvp = ident, zero3, zero3, zero3, zero3, minus_g
        else:
            Rp, pp, wp, vp, dwp, dvp = R[p], pos[p], w[p], v[p], dw[p], dv[p]
        F = np.asarray(tree.rot_fixed[k], dtype=np.float64)
        u = np.asarray(tree.axis[k], dtype=np.float64)
        zk = em.mv(Rp, _cvec(F @ u))  # the joint axis, world frame
        z[k] = zk
        qdk, qddk = em.load("qd", k), em.load("qdd", k)
        if tree.joint_types[k] == "revolute":
            # F @ Rot(u, q) = F u u^T + cos q F (1 - u u^T) + sin q F [u]x   (Rodrigues)
            uu = np.outer(u, u)
            K = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
            A, Bc, G = _cmat(F @ uu), _cmat(F @ (np.eye(3) - uu)), _cmat(F @ K)
            s, c = em.load("sn", k), em.load("cs", k)
            M = tuple(
                tuple(
                    em.sum(A[r][cc], em.mul(Bc[r][cc], c), em.mul(G[r][cc], s)) for cc in range(3)
                )
                for r in range(3)
            )
            R[k] = em.mm(Rp, M)
            point = _cvec(tree.pos_fixed[k] + F @ tree.axis_point[k])
            o = em.vadd(pp, em.mv(Rp, point))  # a point of the axis, world frame
            pos[k] = em.vadd(o, em.vscale(em.mv(R[k], ap_all[k]), -1.0))
            m[k] = em.cross(o, zk)  # the axis' moment about the world origin
            zq, mq = em.vscale(zk, qdk), em.vscale(m[k], qdk)
            w[k] = em.vadd(wp, zq)
            v[k] = em.vadd(vp, mq)
            dw[k] = em.vadd(dwp, em.vscale(zk, qddk), em.cross(wp, zq))
            dv[k] = em.vadd(dvp, em.vscale(m[k], qddk), em.cross(wp, mq), em.cross(vp, zq))
        else:
            R[k] = em.mm(Rp, _cmat(F))
            base = em.vadd(pp, em.mv(Rp, _cvec(tree.pos_fixed[k])))
            pos[k] = em.vadd(base, em.vscale(zk, em.load("q", k)))
            zq = em.vscale(zk, qdk)
            w[k], dw[k] = wp, dwp
            v[k] = em.vadd(vp, zq)
            dv[k] = em.vadd(dvp, em.vscale(zk, qddk), em.cross(wp, zq))
    return {"R": R, "pos": pos, "z": z, "m": m, "w": w, "v": v, "dw": dw, "dv": dv}


def _pair_entries(tree: KinematicTree, kin: dict[str, list], per: int, em: _Emitter) -> dict:
    """Emit the 10 inertial columns of every (ancestor joint j, body i) pair.

    Args:
        kin: `_forward`'s lists.
        per: parameters per joint (10 + the friction terms).

    Returns:
        ``{(row j, column): value}``.
    """
    revolute = [t == "revolute" for t in tree.joint_types]
    zero3 = (0.0, 0.0, 0.0)
    u_all = [_cvec(u) for u in tree.axis]
    ap_all = [_cvec(a) for a in tree.axis_point]
    R, pos, z, m = kin["R"], kin["pos"], kin["z"], kin["m"]
    w, v, dw, dv = kin["w"], kin["v"], kin["dw"], kin["dv"]
    ancestors = tree.ancestors()
    entries = {}
    for i in range(len(tree.parent)):
        Ri, pi = R[i], pos[i]
        vo = em.vadd(v[i], em.cross(w[i], pi))  # velocity of the body origin
        acc = em.vadd(dv[i], em.cross(dw[i], pi), em.cross(w[i], vo))  # its acceleration, -g in
        o, a, accb = em.mtv(Ri, w[i]), em.mtv(Ri, dw[i]), em.mtv(Ri, acc)  # body frame
        for j in ancestors[i]:
            # joint j's Plücker axis at body i's origin, body i's frame: (sab, slb)
            if j == i:
                if revolute[i]:
                    sab = u_all[i]
                    slb = em.vscale(em.cross(u_all[i], ap_all[i]), -1.0)
                else:
                    sab, slb = zero3, u_all[i]
            elif revolute[j]:
                sab = em.mtv(Ri, z[j])
                slb = em.mtv(Ri, em.vadd(m[j], em.cross(z[j], pi)))
            else:
                sab, slb = zero3, em.mtv(Ri, z[j])
            x = em.cross(sab, o)
            yh = em.vadd(em.cross(accb, sab), em.cross(slb, a), em.cross(o, em.cross(o, slb)))
            mul, s_ = em.mul, em.sum
            cols = (
                em.dot(slb, accb),
                yh[0],
                yh[1],
                yh[2],
                s_(mul(sab[0], a[0]), mul(x[0], o[0])),
                s_(mul(sab[0], a[1]), mul(sab[1], a[0]), mul(x[0], o[1]), mul(x[1], o[0])),
                s_(mul(sab[1], a[1]), mul(x[1], o[1])),
                s_(mul(sab[0], a[2]), mul(sab[2], a[0]), mul(x[0], o[2]), mul(x[2], o[0])),
                s_(mul(sab[1], a[2]), mul(sab[2], a[1]), mul(x[1], o[2]), mul(x[2], o[1])),
                s_(mul(sab[2], a[2]), mul(x[2], o[2])),
            )
            for col, val in enumerate(cols):
                entries[(j, i * per + col)] = val
    return entries


def kernel_source(tree: KinematicTree, friction: tuple[str, ...], dtype: torch.dtype) -> str:
    """The C++ source of the regressor kernel of one robot, friction layout and dtype.

    The kernel is ``void regressor(q, qd, qdd, sn, cs, out, B)``: inputs ``(B, n)`` row-major
    (``sn``, ``cs`` the sine and cosine of q), ``out`` the ``(B, n, n * per)`` regressor, every
    entry written.
    """
    if dtype not in LANES:
        raise ValueError(f"the compiled regressor supports float64 and float32, got {dtype}")
    em = _Emitter(dtype)
    entries = _program(tree, tuple(friction), em)
    n = len(tree.parent)
    per = 10 + len(friction)
    ncol = n * n * per
    stores, consts = [], []
    for (j, col), val in sorted(entries.items()):
        idx = j * n * per + col
        if isinstance(val, _Sym):
            stores.append(f"ST({idx}, {val.name});")
        elif isinstance(val, tuple):  # joint terms read the velocity or acceleration directly
            src = f"{'qdd' if val[0] == 'qdd' else 'qd'}[l * {n} + {val[1]}]"
            expr = f"(T)(({src} > 0) - ({src} < 0))" if val[0] == "sign" else src
            stores.append(f"for (int l = 0; l < W; ++l) tile[l][{idx}] = {expr};")
        elif val != 0.0:
            consts.append(f"for (int l = 0; l < W; ++l) tile[l][{idx}] = {em.lit(val)};")
    body = "\n    ".join(em.lines + stores)
    init = "\n    ".join(consts)
    T, W = _CTYPES[dtype], LANES[dtype]
    return f"""// torchjfa: generated regressor kernel ({n} joints, friction {tuple(friction)}, {T})
#include <cstdint>
#include <cstring>
typedef {T} T;
typedef T V __attribute__((vector_size({W} * sizeof(T))));
enum {{ N = {n}, W = {W}, NC = {ncol} }};

static inline V ld(const T* p) {{
    V v;
    for (int l = 0; l < W; ++l) v[l] = p[l * N];
    return v;
}}
#define LD(a, k) ld(a + (k))
#define ST(i, v) for (int l = 0; l < W; ++l) tile[l][i] = v[l]

// W samples: inputs W rows of N, outputs W rows of NC in tile (zeros left untouched)
static void block(const T* __restrict q, const T* __restrict qd, const T* __restrict qdd,
                  const T* __restrict sn, const T* __restrict cs, T (*__restrict tile)[NC]) {{
    (void)q;
    {body}
}}

extern "C" void regressor(const T* q, const T* qd, const T* qdd, const T* sn, const T* cs,
                          T* out, int64_t B) {{
    T (*tile)[NC] = new T[W][NC]();
    {init}
    int64_t b = 0;
    for (; b + W <= B; b += W) {{
        block(q + b * N, qd + b * N, qdd + b * N, sn + b * N, cs + b * N, tile);
        std::memcpy(out + b * NC, tile, sizeof(T) * W * NC);
    }}
    const int64_t rest = B - b;
    if (rest > 0) {{
        T pad[5][W * N] = {{}};
        const T* src[5] = {{q, qd, qdd, sn, cs}};
        for (int a = 0; a < 5; ++a) std::memcpy(pad[a], src[a] + b * N, sizeof(T) * rest * N);
        block(pad[0], pad[1], pad[2], pad[3], pad[4], tile);
        std::memcpy(out + b * NC, tile, sizeof(T) * rest * NC);
    }}
    delete[] tile;
}}
"""

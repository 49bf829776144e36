"""`identify_payload`: the inertial parameters of a rigid body fixed to a link (a gripper, a
tool, a part), from loaded logs and an identified robot, or from loaded and unloaded runs.

A payload fixed to ``link`` moves with the joint body that carries the link (`body_names`; a
URDF flange or tool link is lumped into the last body). Its 10 parameters in the link's frame,
``pi_L = (m, m c, I_o)`` (``I_o`` about the link frame's origin), enter the torques as extra
inertial parameters of that body: ``pi_B = A pi_L``, with ``A`` the linear map of the
pseudo-inertia under the link's fixed pose in the body, ``J_B = T J_L T^T`` (`transform_map`).
So the payload's regressor is ``Z = Y_B A`` (``Y_B`` the body's 10 columns of the robot's
regressor), and

* against the identified robot (``unloaded=None``): ``tau - Y theta = Z pi_L + e``, the loaded
  logs' torques less the identified model's prediction;
* with unloaded runs: the robot's parameters are fitted again, together with the payload's,
  on both kinds of run, ``tau_unloaded = Y theta + e`` and ``tau_loaded = Y theta + Z pi_L +
  e`` (one regression on the stacked rows): what the robot's model gets wrong is common to both
  kinds and cancels in ``pi_L``, and the runs need not be aligned in time.

Both are linear regressions over stacked rows, fitted on the flow's shared stages: the rows'
`Moments` per joint and per contiguous block come from `stream_moments` (the robot's regressor;
the payload's columns and right-hand side are linear maps of its moments, `mapped_moments`, so
no regression matrix is formed), each joint's rows are weighted by its inverse residual variance
in a first unweighted fit with ``options.weighting="residual"`` (`weighted_joints`, with the
floor `JOINT_WEIGHT_FLOOR` of `identify`'s weights; ``"none"``: unweighted), the estimator is
``options.estimator`` (`make_estimator`: least squares by default; one that takes an input
noise learns it, none is given). Either estimate is then made physically consistent: the
closest payload in the data's (weighted) metric ``Z^T W Z`` with a positive semidefinite
pseudo-inertia, inside ``bounds`` when the user gives a region the payload lies in (`Bounds`: a
sphere or a box in the link's frame), a semidefinite program (`consistent_payload`). Spreads
come from the delete-one-block jackknife (`torchjfa.estimators.jackknife`) over
``options.jackknife`` contiguous blocks of the logs (0: none); a parameter whose spread is large
against its scale, or that the motion leaves free, is marked as not determined
(`Payload.determined`). Each log is prepared as `identify` prepares it (the identified model's
cut-off, the rest at the ends dropped); the last ``options.validation`` of each loaded log is
held out to judge the torques with and without the payload.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from ..dynamics import ParameterLayout, RigidBodyModel
from ..dynamics._parameters import inertial_from_vector, pseudo_inertia
from ..estimators import LinearEstimator, jackknife
from ..physical import inertial_from_pseudo_inertia
from ._fit import make_estimator
from ._options import IdentificationError, Options
from ._prepare import concatenate, identified_model, read_prepared, several, split_held_out
from ._stream import mapped_moments, stream_moments, weighted_joints

__all__ = [
    "DETERMINED_SPREAD",
    "Bounds",
    "Payload",
    "identify_payload",
    "payload_regressor",
    "transform_map",
    "write_with_payload",
]


#: the layout of one body's 10 parameters and no joint terms (the payload's)
ONE_BODY = ParameterLayout(("payload",), ())
#: the names of the payload's 10 parameters, in order
PARAMETERS = ("m", "hx", "hy", "hz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
#: a parameter whose spread exceeds this share of its scale is reported as not determined
DETERMINED_SPREAD = 0.2
#: a direction of the column-scaled normal matrix whose eigenvalue is below this share of the
#: largest is one the data leave free (`torchjfa.estimators.OLS`'s ``rcond``: the directions
#: least squares treats as unidentifiable)
_FREE_RCOND = 1e-12


@dataclass(frozen=True)
class Bounds:
    """A region of the link's frame the payload's mass lies in: a sphere (``centre``, ``radius``)
    or an axis-aligned box (``low``, ``high``), metres.

    The conditions are linear in the payload's pseudo-inertia ``J = [[Sigma, h], [h^T, m]]``
    (``Sigma`` the second moments about the link's origin): for a sphere ``int (r^2 - |x -
    c|^2) dm >= 0``, for a box ``int (x_k - low_k) (high_k - x_k) dm >= 0`` per axis (with ``J
    >= 0``, exact for the sphere; for the box they bound each axis' spread, which keeps the
    centre of mass inside).
    """

    kind: str
    values: tuple[float, ...]

    @classmethod
    def parse(cls, text: str) -> Bounds:
        """``"sphere:R"`` (about the link's origin), ``"sphere:X,Y,Z,R"`` or
        ``"box:XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX"``, metres in the link's frame.

        Raises:
            IdentificationError: on anything else.
        """
        kind, _, rest = str(text).partition(":")
        try:
            values = tuple(float(v) for v in rest.split(",")) if rest else ()
        except ValueError:
            values = ()
        if kind == "sphere" and len(values) == 1:
            values = (0.0, 0.0, 0.0, *values)
        ok = (kind == "sphere" and len(values) == 4 and values[3] > 0) or (
            kind == "box" and len(values) == 6 and all(values[k] < values[k + 3] for k in range(3))
        )
        if not ok:
            raise IdentificationError(
                f"bounds {text!r}: give sphere:R, sphere:X,Y,Z,R (R > 0) or "
                "box:XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX (each min below its max), metres in the "
                "link's frame"
            )
        return cls(kind, values)

    def matrices(self) -> list:
        """The ``(4, 4)`` matrices ``Q`` with ``tr(J Q) >= 0`` the conditions."""
        import numpy as np

        if self.kind == "sphere":
            c, r = np.array(self.values[:3]), self.values[3]
            Q = np.zeros((4, 4))
            Q[:3, :3] = -np.eye(3)
            Q[:3, 3] = Q[3, :3] = c
            Q[3, 3] = r * r - c @ c
            return [Q]
        out = []
        for k in range(3):
            lo, hi = self.values[k], self.values[k + 3]
            Q = np.zeros((4, 4))
            Q[k, k] = -1.0
            Q[k, 3] = Q[3, k] = 0.5 * (lo + hi)
            Q[3, 3] = -lo * hi
            out.append(Q)
        return out

    def __str__(self) -> str:
        return f"{self.kind}:{','.join(f'{v:g}' for v in self.values)}"


def transform_map(T: torch.Tensor) -> torch.Tensor:
    """``(10, 10)`` the linear map of inertial parameters ``(m, h, I_o)`` from a frame to
    another in which the first frame has the pose ``T`` ``(4, 4)``: ``J' = T J T^T``."""
    T = T.to(torch.float64)
    basis = pseudo_inertia(torch.eye(10, dtype=torch.float64))  # (10, 4, 4)
    moved = T @ basis @ T.T
    return inertial_from_pseudo_inertia(moved).T  # column k: the image of e_k


def payload_regressor(model: RigidBodyModel, link: str):
    """``(joint index, A (10, 10))``: the joint whose body carries ``link`` and the map of the
    payload's parameters in ``link``'s frame to that body's (see the module).

    Raises:
        IdentificationError: if ``link`` is no frame of the description, or is fixed to the
            root (a payload there moves with nothing).
    """
    if link not in model.frame_names:
        raise IdentificationError(
            f"no frame {link!r} in the description; its frames include "
            f"{', '.join(model.frame_names[-6:])}"
        )
    carrier = None
    for j, (joint, body) in enumerate(zip(model.joint_names, model.body_names, strict=True)):
        if link == body or link in model.lumped_bodies[joint]:
            carrier = j
    if carrier is None:
        raise IdentificationError(
            f"{link!r} is fixed to the robot's base: a payload there moves with no joint"
        )
    q0 = torch.zeros(model.n_dof, dtype=torch.float64)
    poses = model.forward_kinematics(q0, [model.body_names[carrier], link])
    T = torch.linalg.solve(poses[0], poses[1])  # the link's pose in the body's frame
    return carrier, transform_map(T)


@dataclass(eq=False)
class Payload:
    """What `identify_payload` found, in the frame of ``link``.

    Attributes:
        link: the frame the payload is fixed to.
        mass: kg. com: ``(3,)`` centre of mass, m. inertia: ``(3, 3)`` about the centre of
            mass, kg m^2.
        theta: ``(10,)`` the consistent parameters ``(m, m c, I_o)`` in the link's frame.
        theta_hat: ``(10,)`` the least-squares estimate before the projection.
        std: ``(10,)`` spreads of ``theta_hat``: a delete-one-block jackknife over contiguous
            blocks of the logs (filtered rows are correlated; least-squares standard errors on
            the rows would understate them); NaN with ``options.jackknife=0``.
        determined: ``(10,)`` bool: the spread at most `DETERMINED_SPREAD` of the parameter's
            scale (the mass for ``m``, ``m L`` for ``h``, ``m L^2`` for ``I_o``, ``L`` the
            payload's radius of gyration about the link's origin, at least 1 cm; not judged
            without spreads); an undetermined parameter takes the value the consistency (and
            ``bounds``) leave closest to the data.
        bounds: the region the payload was kept inside, or None.
        rms_without, rms_with: ``(n_dof,)`` held-out torque RMS of the robot model alone and
            with the payload, N m.
        how: how the estimate was made (for the report).
    """

    link: str
    mass: float
    com: torch.Tensor
    inertia: torch.Tensor
    theta: torch.Tensor
    theta_hat: torch.Tensor
    std: torch.Tensor
    determined: torch.Tensor
    bounds: Bounds | None
    rms_without: torch.Tensor
    rms_with: torch.Tensor
    how: str

    def markdown(self, brief: bool = False) -> str:
        """A short report: the verdict (mass, centre of mass, held-out torques without and
        with the payload, what the logs do not determine), then, unless ``brief``, the
        parameters with their spreads and the principal moments."""
        m_std = float(self.std[0])
        c_std = (self.std[1:4] / max(self.mass, 1e-12)).tolist()
        com = ", ".join(
            f"{c:.4f} +- {e:.2g}" for c, e in zip(self.com.tolist(), c_std, strict=True)
        )
        without, with_ = float(self.rms_without.mean()), float(self.rms_with.mean())
        loose = [n for n, ok in zip(PARAMETERS, self.determined.tolist(), strict=True) if not ok]
        lines = [
            f"# Payload on {self.link}",
            "",
            f"- mass {self.mass:.4g} kg +- {m_std:.2g} (jackknife spread of the estimate)"
            if m_std == m_std
            else f"- mass {self.mass:.4g} kg (no jackknife spread: jackknife=0)",
            f"- centre of mass ({com}) m in {self.link}'s frame",
            f"- held-out torque RMS, mean over joints: {without:.4g} N m with the robot model "
            f"alone, {with_:.4g} N m with the payload ({with_ / max(without, 1e-300):.2f}x)",
            "- every parameter determined by the logs"
            if not loose
            else f"- not determined by the logs (not excited, or a spread above "
            f"{DETERMINED_SPREAD:.0%} of its scale): {', '.join(loose)}; they take the "
            "consistent values closest to the data",
            f"- how: {self.how}" + (f"; kept inside {self.bounds}" if self.bounds else ""),
        ]
        if brief:
            return "\n".join(lines)
        principal = torch.linalg.eigvalsh(self.inertia).tolist()
        lines += [
            "",
            f"## Parameters in {self.link}'s frame",
            "",
            "| parameter | consistent | least squares | spread | determined |",
            "|---|---|---|---|---|",
            *(
                f"| {n} | {float(v):.4g} | {float(h):.4g} | {float(e):.2g} | "
                f"{'yes' if ok else 'no'} |"
                for n, v, h, e, ok in zip(
                    PARAMETERS,
                    self.theta,
                    self.theta_hat,
                    self.std,
                    self.determined.tolist(),
                    strict=True,
                )
            ),
            "",
            "m in kg, h = m c in kg m, I about the frame's origin in kg m^2.",
            "Principal moments about the centre of mass: "
            + ", ".join(f"{v:.4g}" for v in principal)
            + " kg m^2.",
            "",
            "Held-out torque RMS per joint, N m (robot alone / with the payload): "
            + ", ".join(
                f"{a:.3g} / {b:.3g}"
                for a, b in zip(self.rms_without.tolist(), self.rms_with.tolist(), strict=True)
            ),
        ]
        return "\n".join(lines) + "\n"

    def summary(self) -> dict:
        """JSON-ready numbers: ``mass``, ``com``, ``inertia`` and their spreads."""
        return {
            "link": self.link,
            "mass": self.mass,
            "mass_std": float(self.std[0]),
            "com": self.com.tolist(),
            "inertia": self.inertia.tolist(),
            "theta": self.theta.tolist(),
            "theta_hat": self.theta_hat.tolist(),
            "theta_hat_std": self.std.tolist(),
            "determined": dict(zip(PARAMETERS, self.determined.tolist(), strict=True)),
            "bounds": None if self.bounds is None else str(self.bounds),
            "held_out_rms_without": self.rms_without.tolist(),
            "held_out_rms_with": self.rms_with.tolist(),
            "how": self.how,
        }


def _prepared(logs, model, options, cutoff):
    """Each log read and prepared, split into its training head and held-out tail."""
    heads, tails = [], []
    for source in several(logs):
        _, data = read_prepared(source, model, options, cutoff)
        head, tail = split_held_out(data, options.validation, cutoff)
        heads.append(head)
        tails.append(tail)
    if not heads:
        raise IdentificationError("no loaded log given")
    return concatenate(heads), concatenate(tails)


def identify_payload(
    identified,
    loaded,
    *,
    link: str,
    unloaded=None,
    options: Options | None = None,
    bounds: Bounds | str | None = None,
) -> Payload:
    """The payload fixed to ``link`` from loaded logs (see the module).

    Args:
        identified: the robot's ``model.npz`` (`torchjfa identify`), or ``(model, theta)``.
        loaded: a log or logs with the payload mounted (as `torchjfa.identify` reads them:
            ``options`` gives the columns, the drive gains of currents, ...).
        link: the frame the payload is fixed to (e.g. the flange, ``"ee_link"``).
        unloaded: logs without it, or None (see the module).
        options: `Options`: reading, ``filter``, ``velocity``, ``validation``, ``trim_rest``;
            ``estimator`` (and its ``estimator_options``), ``weighting`` (``"residual"``: each
            joint's rows by its inverse residual variance, ``"none"``), ``jackknife`` (blocks
            of the spreads, 0: none) and ``compute``.
        bounds: a region of the link's frame the payload lies in (`Bounds` or its text, e.g.
            ``"sphere:0.15"``), or None.

    Raises:
        IdentificationError: on a link that carries nothing, or logs of other joints.
        torchjfa.data.LogError: on a log that cannot be read or prepared.
    """
    options = Options() if options is None else options
    bounds = Bounds.parse(bounds) if isinstance(bounds, str) else bounds
    ident = identified_model(identified)
    model, theta, cutoff = ident.model, ident.theta, ident.cutoff_hz
    carrier, A = payload_regressor(model, link)
    select = torch.zeros(model.n_params, 10, dtype=torch.float64)  # (p, 10): Z = Y select
    select[model.layout.split(torch.arange(model.n_params))[0][carrier]] = A
    train, held = _prepared(loaded, model, options, cutoff)
    estimator = make_estimator(options)
    n_blocks = int(estimator.cv) if estimator.needs_folds else max(int(options.jackknife), 1)
    stream = {"per_joint": True, **options.compute.stream()}
    loaded_rows = stream_moments(model, train, n_folds=n_blocks, **stream)
    if unloaded is None:  # tau - Y theta = Z pi
        blocks = [[mapped_moments(m, select, theta) for m in b] for b in loaded_rows]
        how = "the loaded logs' torques less the identified robot's prediction"
    else:  # [tau; tau_u] = [[Z, Y], [0, Y]] (pi, theta)
        free, _ = _prepared(unloaded, model, options, cutoff)
        free_rows = stream_moments(model, free, n_folds=n_blocks, **stream)
        eye = torch.eye(model.n_params, dtype=torch.float64)
        with_, without = torch.cat([select, eye], 1), torch.cat([0 * select, eye], 1)
        blocks = [
            [
                mapped_moments(m, with_) + mapped_moments(u, without)
                for m, u in zip(b, c, strict=True)
            ]
            for b, c in zip(loaded_rows, free_rows, strict=True)
        ]
        how = "loaded and unloaded runs together, the robot's parameters fitted again"
    folds, w = weighted_joints(blocks, options.weighting)
    total = sum(folds[1:], folds[0].copy())
    estimator.fit_moments(folds if estimator.needs_folds else total)
    pi_hat = estimator.coef_.detach().to(torch.float64).cpu()[:10]
    std = torch.full((10,), float("nan"), dtype=torch.float64)
    if options.jackknife:
        std = jackknife(estimator, folds)[1].cpu()[:10]
    metric = total.xtx.cpu()[:10, :10]  # Z^T W Z: the unloaded rows have no payload columns
    pi = consistent_payload(pi_hat, metric, bounds)
    mass, com, inertia = inertial_from_vector(pi)
    rms_without, rms_with = _held_out_rms(model, held, select, theta, pi, options)
    how += f"; {_name(estimator, options)}" + (
        ", each joint's rows weighted by its residual level" if w is not None else ""
    )
    return Payload(
        link, float(mass), com, inertia, pi, pi_hat, std, _determined(pi, std, total.xtx.cpu()),
        bounds, rms_without, rms_with, how,
    )  # fmt: skip


def _held_out_rms(model, held, select, theta, pi, options):
    """``(n_dof,)`` twice: the held-out torque RMS of the robot model alone and with the
    payload, N m (from the held-out rows' moments per joint)."""
    rows = stream_moments(model, held, per_joint=True, **options.compute.stream())
    parts = [mapped_moments(m.to("cpu"), select, theta) for m in rows]
    without = torch.stack([m.yty / m.n for m in parts]).clamp_min(0.0).sqrt()
    with_ = torch.stack([m.rss(pi) / m.n for m in parts]).clamp_min(0.0).sqrt()
    return without, with_


def _name(estimator: LinearEstimator, options: Options) -> str:
    """The estimator's name for ``Payload.how``."""
    name = options.estimator if isinstance(options.estimator, str) else type(estimator).__name__
    return "least squares (ols)" if name == "ols" else f"estimator {name}"


def _scale(pi: torch.Tensor) -> tuple[float, float]:
    """``(m_s, L)``: the payload's mass and radius of gyration about the link's origin (at
    least 1 cm, at most 1 m), its units."""
    m = max(abs(float(pi[0])), 1e-6)
    trace = abs(float(pi[4] + pi[6] + pi[9]))
    return m, min(max((trace / (2 * m)) ** 0.5, 0.01), 1.0)


def _determined(pi: torch.Tensor, std: torch.Tensor, xtx: torch.Tensor) -> torch.Tensor:
    """``(10,)`` bool: the parameter is estimable from the rows whose normal matrix is ``xtx``
    (payload columns first; its unit vector has no part in the null space: a column the
    motion never excites has one) and its spread is at most `DETERMINED_SPREAD` of its scale
    (not judged where there is no spread, NaN)."""
    m, L = _scale(pi)
    unit = torch.tensor([m, *(m * L,) * 3, *(m * L * L,) * 6], dtype=torch.float64)
    norms = torch.diagonal(xtx).clamp_min(0.0).sqrt().clamp_min(1e-300)
    ev, V = torch.linalg.eigh(xtx / norms[:, None] / norms[None, :])  # columns of unit norm
    null = V[:, ev <= _FREE_RCOND * ev[-1]].T  # (k, n_cols)
    free = null[:, :10].norm(dim=0) > 1e-6 if null.numel() else torch.zeros(10, dtype=torch.bool)
    excited = torch.diagonal(xtx)[:10] > 0
    spread_ok = (std <= DETERMINED_SPREAD * unit) | std.isnan()
    return excited & ~free & spread_ok


def consistent_payload(pi_hat, metric, bounds: Bounds | None = None) -> torch.Tensor:
    """``(10,)`` the physically consistent payload closest to ``pi_hat`` in ``metric`` (the
    payload's normal matrix ``Z^T Z``): positive semidefinite pseudo-inertia, inside
    ``bounds``; a semidefinite program (cvxpy, Clarabel), a 1e-8 tie-break towards zero in
    the directions the data leave free.

    Raises:
        IdentificationError: if no payload fits inside the bounds (e.g. they exclude every
            mass) or the solver fails.
    """
    import numpy as np

    from ..physical._convex import MARGIN, _body_lmis, _cvxpy, psd_factor, solve_quietly

    cp = _cvxpy()
    m_s, L = _scale(pi_hat)
    S = np.array([m_s, *(m_s * L,) * 3, *(m_s * L * L,) * 6])
    basis = pseudo_inertia(torch.eye(10, dtype=torch.float64)).numpy()  # (10, 4, 4)
    H = S[:, None] * metric.numpy() * S[None, :]
    unit = max(float(np.trace(H)) / 10, 1e-300)
    R = psd_factor(H / unit)
    x = cp.Variable(10)
    x_hat = pi_hat.numpy() / S
    constraints = _body_lmis(cp, x, ONE_BODY, "log-cholesky", torch.from_numpy(S), MARGIN)
    for Q in [] if bounds is None else bounds.matrices():
        coef = np.array([np.trace(basis[k] @ Q) for k in range(10)]) * S / (m_s * L * L)
        constraints.append(coef @ x >= 0)
    cost = cp.sum_squares(R @ (x - x_hat)) + 1e-8 * cp.sum_squares(x)
    problem = cp.Problem(cp.Minimize(cost), constraints)
    solve_quietly(cp, problem)
    if problem.status not in ("optimal", "optimal_inaccurate") or x.value is None:
        raise IdentificationError(
            f"no consistent payload {'inside ' + str(bounds) if bounds else ''} fits the "
            f"logs (solver status {problem.status})"
        )
    return torch.as_tensor(x.value * S)


def write_with_payload(identified, payload: Payload, folder) -> Path:
    """The identified robot's description with the payload attached to its link, written into
    ``folder`` as ``robot_with_payload.urdf`` (a link ``payload`` fixed to ``payload.link``)
    or ``robot_with_payload.xml`` (a body ``payload`` inside the link's body, which must be an
    MJCF body), as the robot's description is; returns the path. Reloading it gives the robot
    with the payload lumped into the body that carries it.

    Raises:
        IdentificationError: for an MJCF link that is not a body, or a name already taken.
    """
    import tempfile
    import xml.etree.ElementTree as ET

    ident = identified_model(identified)
    model, theta = ident.model, ident.theta
    urdf = model.source_format == "urdf"
    with tempfile.TemporaryDirectory() as tmp:
        written = Path(tmp) / ("robot.urdf" if urdf else "robot.xml")
        (model.write_urdf if urdf else model.write_mjcf)(theta, written)
        root = ET.fromstring(written.read_text())
    names = {el.get("name") for el in root.iter() if el.get("name")}
    if "payload" in names:
        raise IdentificationError("the description already has an element named 'payload'")
    c = payload.com.tolist()
    I = payload.inertia  # noqa: E741  (about the centre of mass, the link's axes)
    xyz = " ".join(repr(float(x)) for x in c)
    if urdf:
        link = ET.SubElement(root, "link", name="payload")
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "origin", xyz=xyz, rpy="0 0 0")
        ET.SubElement(inertial, "mass", value=repr(payload.mass))
        ET.SubElement(inertial, "inertia", **{
            f"i{a}": repr(float(I[i, j]))
            for a, (i, j) in {"xx": (0, 0), "xy": (0, 1), "xz": (0, 2), "yy": (1, 1),
                              "yz": (1, 2), "zz": (2, 2)}.items()
        })  # fmt: skip
        joint = ET.SubElement(root, "joint", name="payload_fixed", type="fixed")
        ET.SubElement(joint, "parent", link=payload.link)
        ET.SubElement(joint, "child", link="payload")
    else:
        bodies = [el for el in root.iter("body") if el.get("name") == payload.link]
        if len(bodies) != 1:
            raise IdentificationError(
                f"{payload.link!r} is not one named MJCF body: attach the payload to a body"
            )
        body = ET.SubElement(bodies[0], "body", name="payload")
        six = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
        ET.SubElement(body, "inertial", pos=xyz, mass=repr(payload.mass),
                      fullinertia=" ".join(repr(float(x)) for x in six))  # fmt: skip
    ET.indent(root, space="  ")
    path = Path(folder) / f"robot_with_payload.{'urdf' if urdf else 'xml'}"
    path.write_text(ET.tostring(root, encoding="unicode") + "\n")
    return path

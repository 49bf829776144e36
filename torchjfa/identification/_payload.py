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
  logs' torques less the identified model's prediction, by least squares;
* with unloaded runs: the robot's parameters are fitted again, together with the payload's,
  on both kinds of run, ``tau_unloaded = Y theta + e`` and ``tau_loaded = Y theta + Z pi_L +
  e`` (least squares on the stacked rows): what the robot's model gets wrong is common to both
  kinds and cancels in ``pi_L``, and the runs need not be aligned in time.

Either estimate is then projected onto a physically consistent body (positive definite
pseudo-inertia, `torchjfa.physical.project` with the payload's moments as the metric). Each
log is prepared as `identify` prepares it (the identified model's cut-off, the rest at the
ends dropped); the last ``options.validation`` of each loaded log is held out to judge the
torques with and without the payload.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from ..data import DEFAULT_CUTOFF_HZ, JointLog
from ..dynamics import ParameterLayout, RigidBodyModel
from ..dynamics._parameters import inertial_from_vector, pseudo_inertia
from ..physical import inertial_from_pseudo_inertia, project
from ._evaluate import _identified
from ._options import IdentificationError, Options
from ._prepare import concatenate, read_prepared, several

__all__ = [
    "Payload",
    "identify_payload",
    "payload_regressor",
    "transform_map",
    "write_with_payload",
]


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
        std: ``(10,)`` least-squares standard errors of ``theta_hat``.
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
    rms_without: torch.Tensor
    rms_with: torch.Tensor
    how: str

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
            "held_out_rms_without": self.rms_without.tolist(),
            "held_out_rms_with": self.rms_with.tolist(),
            "how": self.how,
        }


def _prepared(logs, model, options, cutoff):
    """Each log read and prepared, split into its training head and held-out tail."""
    heads, tails = [], []
    for source in several(logs):
        _, data = read_prepared(source, model, options, cutoff)
        head, tail = data.split(options.validation, gap=int(4.0 / cutoff * data.info["rate_hz"]))
        heads.append(head)
        tails.append(tail)
    if not heads:
        raise IdentificationError("no loaded log given")
    return concatenate(heads), concatenate(tails)


def _rows(model, log: JointLog):
    """``(Y (n d, p), tau (n d,))`` of a prepared log."""
    Y = model.regressor(log.q, log.qd, log.qdd)
    return Y.reshape(-1, model.n_params), log.tau.reshape(-1)


def identify_payload(
    identified,
    loaded,
    *,
    link: str,
    unloaded=None,
    options: Options | None = None,
) -> Payload:
    """The payload fixed to ``link`` from loaded logs (see the module).

    Args:
        identified: the robot's ``model.npz`` (`torchjfa identify`), or ``(model, theta)``.
        loaded: a log or logs with the payload mounted (as `torchjfa.identify` reads them:
            ``options`` gives the columns, the drive gains of currents, ...).
        link: the frame the payload is fixed to (e.g. the flange, ``"ee_link"``).
        unloaded: logs without it, or None (see the module).
        options: `Options` (reading, ``filter``, ``velocity``, ``validation``, ``trim_rest``).

    Raises:
        IdentificationError: on a link that carries nothing, or logs of other joints.
        torchjfa.data.LogError: on a log that cannot be read or prepared.
    """
    options = Options() if options is None else options
    model, theta, stored = _identified(identified)
    cutoff = float(stored) if stored else DEFAULT_CUTOFF_HZ
    j, A = payload_regressor(model, link)
    cols = model.layout.split(torch.arange(model.n_params))[0][j]
    train, held = _prepared(loaded, model, options, cutoff)
    Y, tau = _rows(model, train)
    Z = Y[:, cols] @ A
    if unloaded is None:
        X, y = Z, tau - Y @ theta
        how = "the loaded logs' torques less the identified robot's prediction"
    else:
        free, _ = _prepared(unloaded, model, options, cutoff)
        Yu, tau_u = _rows(model, free)
        X = torch.cat([torch.cat([Z, Y], 1), torch.cat([torch.zeros_like(Yu[:, :10]), Yu], 1)])
        y = torch.cat([tau, tau_u])
        how = "loaded and unloaded runs together, the robot's parameters fitted again"
    sol, *_ = torch.linalg.lstsq(X, y.unsqueeze(1), driver="gelsd")
    sol = sol.flatten()
    resid = y - X @ sol
    dof = max(1, X.shape[0] - X.shape[1])
    cov = torch.linalg.pinv(X.T @ X) * float(resid @ resid) / dof
    pi_hat, std = sol[:10], cov.diagonal()[:10].clamp_min(0).sqrt()
    metric = Z.T @ Z
    single = ParameterLayout((link,), ())
    pi = project(pi_hat, layout=single, metric=metric, parametrization="log-cholesky").theta
    mass, com, inertia = inertial_from_vector(pi)
    Yh, tau_h = _rows(model, held)
    base = tau_h - Yh @ theta
    without = base.reshape(-1, model.n_dof)
    with_ = (base - (Yh[:, cols] @ A) @ pi).reshape(-1, model.n_dof)
    return Payload(
        link, float(mass), com, inertia, pi, pi_hat, std,
        without.pow(2).mean(0).sqrt(), with_.pow(2).mean(0).sqrt(), how,
    )  # fmt: skip


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

    model, theta, _ = _identified(identified)
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

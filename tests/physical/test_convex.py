"""The projection's certificate: `project` reaches the optimum of the same convex problem solved
by a semidefinite solver (cvxpy with Clarabel, an interior-point method), on the shipped robots
and the example-robot-data arms, at scales 1e-3 to 1e3, and the description's values where
the data are silent.

The data: random excitation of each robot (q, qd, qdd drawn per sample), torques from an
inconsistent parameter vector (the description's with its masses flipped in sign and its
inertias scaled, plus noise), so that the unconstrained estimate is far from consistent and
the projection has work to do. The cost (eq. 8 plus the ridge and prior terms) is recomputed
here by hand; the projection's must lie within 1e-6 above the semidefinite optimum and the
solver's answer no further than its own accuracy above the projection's.
"""

import importlib.metadata
from pathlib import Path

import pytest
import torch

import torchjfa
from torchjfa.dynamics import RigidBodyModel
from torchjfa.estimators import OLS
from torchjfa.physical import check, parameter_scales, project
from torchjfa.physical._convex import CERTIFY_TOL, certify, project_convex
from torchjfa.sim import model_path

pytest.importorskip("cvxpy")

ERD = {
    "ur5": ("ur_description/urdf/ur5_robot.urdf", ()),
    "talos_left_arm": ("talos_data/robots/talos_left_arm.urdf", ()),
    "kinova": ("kinova_description/robots/kinova.urdf", ()),
    "ur3": ("ur_description/urdf/ur3_robot.urdf", ()),
    "ur10": ("ur_description/urdf/ur10_robot.urdf", ()),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", ()),
    "z1": ("z1_description/urdf/z1.urdf", ()),
    "so100": ("so_arm_description/urdf/so100.urdf", ()),
}
#: `project`'s default tie-break weight: without it a direction the data do not reach can
#: lower the cost without end (a body's mass running to thousands of kilograms), and no
#: solver reaches an optimum that is not there
RIDGE = 1e-8
#: how far above a consistent point the semidefinite solver's answer may come out (its own
#: accuracy): an exact optimum of the closure lies below every consistent point
REFERENCE_ACCURACY = 1e-5
TERMS = ("viscous", "coulomb", "offset", "armature")


def _model(name: str) -> RigidBodyModel:
    if name in ("head", "arm"):
        return RigidBodyModel.from_mjcf(str(model_path(name)), friction=TERMS)
    if name in torchjfa.robots.available():
        path = torchjfa.robots.path(name)
        build = RigidBodyModel.from_urdf if path.endswith(".urdf") else RigidBodyModel.from_mjcf
        return build(path, friction=TERMS)
    try:
        importlib.metadata.distribution("example-robot-data")
        path = torchjfa.robots.example_robot_data_path(ERD[name][0])
    except (importlib.metadata.PackageNotFoundError, FileNotFoundError):
        pytest.skip(f"example-robot-data has no {name}")
    return RigidBodyModel.from_urdf(path, friction=TERMS, fixed_joints=ERD[name][1])


def _problem(model: RigidBodyModel, seed: int = 0, n: int = 400):
    """``(moments, theta_hat)``: random excitation, torques of an inconsistent theta."""
    g = torch.Generator().manual_seed(seed)
    d = model.n_dof
    q, qd, qdd = (torch.randn(n, d, generator=g, dtype=torch.float64) for _ in range(3))
    inertial, friction = model.layout.split(model.nominal_theta.clone())
    inertial[:, 0] *= -1.0  # negative masses
    inertial[:, 4:] *= 3.0
    friction[:] = torch.rand(friction.shape, generator=g, dtype=torch.float64) - 0.3
    theta = model.layout.join(inertial, friction)
    Y = model.regressor(q, qd, qdd)
    tau = Y @ theta + 0.05 * torch.randn(n, d, generator=g, dtype=torch.float64)
    moments = model.moments(q, qd, qdd, tau)
    theta_hat = OLS(fit_intercept=False).fit_moments(moments).coef_.to(torch.float64)
    return moments, theta_hat


def _objective(theta, theta_hat, M, weight=0.0, prior=None, w=None, ridge=RIDGE) -> float:
    """Eq. 8 plus the ridge and prior terms, by hand (``weight`` already times ``tr(M) /
    d``)."""
    delta = theta - theta_hat
    f = float(delta @ (M @ delta)) + ridge * float(torch.diagonal(M).mean()) * float(theta @ theta)
    if prior is not None:
        f += weight * float((w * (theta - prior) ** 2).sum())
    return f


@pytest.mark.parametrize("name", ["head", "arm", "panda_arm", "branched_tree", *ERD])
def test_the_projection_reaches_the_semidefinite_optimum(name):
    model = _model(name)
    moments, theta_hat = _problem(model)
    assert not check(theta_hat, model).ok
    kw = {"layout": model, "moments": moments, "ridge": RIDGE}
    result = project(theta_hat, **kw, parametrization="log-cholesky")
    assert check(result.theta, model).ok
    # the convex problem solved to its optimum by the interior-point solver alone (SCS, a
    # first-order solver, stops 1e-4 to 1e-1 outside the set on these problems: no reference),
    # its variables in the units of the projection's answer (units only: the same problem)
    convex = project_convex(theta_hat, **kw, parametrization="log-cholesky", reference=result.theta)
    M = moments.xtx
    f, f_star = (_objective(t, theta_hat, M) for t in (result.theta, convex.theta))
    assert f == pytest.approx(float(result.objective), rel=1e-9)
    assert -REFERENCE_ACCURACY * f_star <= f - f_star <= CERTIFY_TOL * f_star
    assert certify(result, convex)[0]


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_the_certificate_and_the_answer_do_not_depend_on_the_units(scale):
    """The projection of s theta_hat is s times theta_hat's, at s = 1e-3 .. 1e3 (eq. 8 and the
    consistent set are invariant under s): certified at every scale, so both costs lie in
    [f*, f* (1 + tol)] of the same optimum f* and differ by at most tol f*."""
    model = _model("ur5")
    moments, theta_hat = _problem(model, seed=1)
    kw = {"layout": model, "moments": moments, "ridge": RIDGE, "parametrization": "log-cholesky"}
    ref = project(theta_hat, **kw)
    scaled = project(scale * theta_hat, **kw)
    ok, gap = certify(scaled, project_convex(scale * theta_hat, **kw, reference=scaled.theta))
    assert ok and gap >= -REFERENCE_ACCURACY, gap
    M = moments.xtx
    f_ref = _objective(ref.theta, theta_hat, M)
    f_scaled = _objective(scaled.theta / scale, theta_hat, M)
    assert abs(f_scaled - f_ref) <= CERTIFY_TOL * f_ref


def test_the_description_fills_what_the_data_leave_undetermined():
    """With the description as a prior, a body the data do not see keeps the description's
    mass (never a near-zero mass where the description has kilograms), at the certified
    optimum."""
    model = _model("head")
    moments, theta_hat = _problem(model, seed=2)
    names = list(model.parameter_names)
    m0 = names.index("neck_pan.m")  # the first joint's body: its mass acts on no torque
    assert float(moments.xtx[m0, m0]) == 0.0
    scale = parameter_scales(model.parameter_names, model.nominal_theta, moments)
    kw = {
        "layout": model,
        "moments": moments,
        "ridge": 0.0,
        "parametrization": "log-cholesky",
        "prior": model.nominal_theta,
        "prior_weight": 1.0,
        "prior_scale": scale,
    }
    result = project(theta_hat, **kw)
    ok, gap = certify(result, project_convex(theta_hat, **kw, reference=result.theta))
    assert ok and gap >= -REFERENCE_ACCURACY, gap
    nominal = float(model.nominal_theta[m0])
    assert nominal > 1.0
    assert float(result.theta[m0]) == pytest.approx(nominal, rel=1e-2)


PANDA_LOG = Path(__file__).resolve().parents[3] / "shared" / "data" / "panda_gaz2019"


@pytest.mark.skipif(not (PANDA_LOG / "torques.txt").is_file(), reason="no real Panda log")
@pytest.mark.parametrize("prior", [False, True])
def test_the_certificate_holds_on_the_real_panda_log(prior):
    """A real log's least-squares estimate (the Panda's link-side torques, the default joint
    terms, the default cut-off) projected with and without the description as a prior: at the
    semidefinite optimum within the certificate's tolerance."""
    from real_panda import load_panda

    from torchjfa.data import DEFAULT_CUTOFF_HZ, prepare
    from torchjfa.identification import load_model

    model = load_model("panda_arm")
    log = prepare(load_panda(PANDA_LOG), cutoff_hz=DEFAULT_CUTOFF_HZ, period_s=None)
    moments = model.moments(log.q, log.qd, log.qdd, log.tau)
    theta_hat = OLS(fit_intercept=False).fit_moments(moments).coef_.to(torch.float64)
    kw = {"layout": model, "moments": moments, "ridge": RIDGE, "parametrization": "log-cholesky"}
    if prior:
        scale = parameter_scales(model.parameter_names, model.nominal_theta, moments)
        kw.update(prior=model.nominal_theta, prior_weight=1.0, prior_scale=scale)
    result = project(theta_hat, **kw)
    assert check(result.theta, model).ok
    ok, gap = certify(result, project_convex(theta_hat, **kw, reference=result.theta))
    assert ok and gap >= -REFERENCE_ACCURACY, gap

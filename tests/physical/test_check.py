"""`check` against criteria written out here from first principles, on hand-made bodies built
from point masses (so their true inertial parameters are known independently of the library)."""

import numpy as np
import pytest
import torch
from _bodies import VANISHING_MASSES, make_layout, vanishing_mass_theta

from torchjfa.dynamics import ParameterLayout
from torchjfa.physical import check

LAYOUT1 = ParameterLayout(("j",), ("viscous",))


def _vector(m, h, inertia):
    """The 10 inertial parameters in the library's order: m, h, Ixx, Ixy, Iyy, Ixz, Iyz, Izz."""
    return [m, *h, *(inertia[i, j] for i, j in ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2)))]


def _from_points(points, weights):
    """The 10 inertial parameters of point masses, summed directly (no library code)."""
    points = np.asarray(points, dtype=float)
    weights = np.asarray(weights, dtype=float)
    m = weights.sum()
    h = (weights[:, None] * points).sum(0)
    inertia = np.zeros((3, 3))
    for w, p in zip(weights, points, strict=True):
        inertia += w * ((p @ p) * np.eye(3) - np.outer(p, p))
    return _vector(m, h, inertia)


def _from_com_inertia(m, com, inertia_c):
    com = np.asarray(com, dtype=float)
    inertia = np.asarray(inertia_c, dtype=float) + m * (
        (com @ com) * np.eye(3) - np.outer(com, com)
    )
    return _vector(m, m * com, inertia)


def _criteria(pi, friction):
    """Independent criteria: (mass > 0, I_c PSD, triangle inequalities, J PSD, friction >= 0),
    with principal moments and the pseudo-inertia computed by numpy."""
    m, h = pi[0], np.array(pi[1:4])
    io = np.array([[pi[4], pi[5], pi[7]], [pi[5], pi[6], pi[8]], [pi[7], pi[8], pi[9]]])
    out = {"mass": m > 0, "friction": all(f >= 0 for f in friction)}
    # pseudo-inertia = second moment of the mass distribution, [[S, h], [h^T, m]] with
    # S = tr(I_o)/2 1 - I_o
    S = 0.5 * np.trace(io) * np.eye(3) - io
    J = np.block([[S, h[:, None]], [h[None, :], np.array([[m]])]])
    eig_j = np.linalg.eigvalsh(J)
    out["J"] = eig_j[0] >= -1e-12 * eig_j[-1]
    if m > 0:
        c = h / m
        ic = io - m * ((c @ c) * np.eye(3) - np.outer(c, c))
        a, b, cc = np.sort(np.linalg.eigvalsh(ic))
        tol = 1e-12 * max(abs(cc), 1.0)
        out["inertia"] = a >= -tol
        out["triangle"] = (a + b >= cc - tol) and (a + cc >= b - tol) and (b + cc >= a - tol)
    else:
        out["inertia"] = out["triangle"] = False
    return out


def _report_flags(report):
    return {
        "mass": bool(report.mass_ok[0]),
        "inertia": bool(report.inertia_ok[0]),
        "triangle": bool(report.triangle_ok[0]),
        "J": bool(report.pseudo_inertia_ok[0]),
        "friction": bool(report.friction_ok[0]),
    }


rng = np.random.default_rng(0)
BODIES = {
    "point mass": (_from_points([[0.1, -0.2, 0.3]], [1.5]), [0.1]),
    "thin rod": (
        _from_points([[0.0, 0.0, z] for z in np.linspace(-0.5, 0.5, 11)], [0.2] * 11),
        [0.1],
    ),
    "box corners": (
        _from_points(
            [[x, y, z] for x in (-0.1, 0.2) for y in (-0.3, 0.1) for z in (0.0, 0.4)], [0.5] * 8
        ),
        [0.2],
    ),
    "random cloud": (_from_points(rng.normal(size=(7, 3)) * 0.2, rng.uniform(0.1, 1.0, 7)), [0.0]),
    "violates triangle only": (
        _from_com_inertia(2.0, [0.1, 0.0, 0.0], np.diag([1.0, 1.0, 3.0])),
        [0.1],
    ),
    "negative mass": (_from_com_inertia(-1.0, [0.0, 0.1, 0.0], np.diag([0.1, 0.1, 0.1])), [0.1]),
    "indefinite inertia": (
        _from_com_inertia(1.0, [0.0, 0.0, 0.2], np.diag([0.1, -0.05, 0.1])),
        [0.1],
    ),
    "negative friction": (_from_points([[0.1, 0.0, 0.0], [0.0, 0.2, 0.1]], [1.0, 2.0]), [-0.3]),
}


@pytest.mark.parametrize("name", list(BODIES))
def test_check_matches_written_out_criteria(name):
    pi, friction = BODIES[name]
    theta = torch.tensor(pi + friction, dtype=torch.float64)
    report = check(theta, LAYOUT1)
    expected = _criteria(pi, friction)
    assert _report_flags(report) == expected
    assert report.ok == all(expected.values())
    assert report.weakly_ok == (expected["mass"] and expected["inertia"] and expected["friction"])


def test_expected_verdicts_of_hand_made_bodies():
    verdict = {
        name: check(torch.tensor(pi + f, dtype=torch.float64), LAYOUT1).ok
        for name, (pi, f) in BODIES.items()
    }
    assert verdict == {
        "point mass": True,
        "thin rod": True,
        "box corners": True,
        "random cloud": True,
        "violates triangle only": False,
        "negative mass": False,
        "indefinite inertia": False,
        "negative friction": False,
    }
    tri = check(torch.tensor(BODIES["violates triangle only"][0] + [0.1]), LAYOUT1)
    assert bool(tri.inertia_ok[0]) and tri.weakly_ok and not tri.ok
    assert float(tri.triangle_margin[0]) == pytest.approx(1.0 + 1.0 - 3.0)


def test_reported_values_match_numpy():
    pi, f = BODIES["random cloud"]
    report = check(torch.tensor(pi + f, dtype=torch.float64), LAYOUT1)
    m, h = pi[0], np.array(pi[1:4])
    io = np.array([[pi[4], pi[5], pi[7]], [pi[5], pi[6], pi[8]], [pi[7], pi[8], pi[9]]])
    c = h / m
    ic = io - m * ((c @ c) * np.eye(3) - np.outer(c, c))
    np.testing.assert_allclose(report.principal_moments[0].numpy(), np.linalg.eigvalsh(ic))
    assert float(report.mass[0]) == pytest.approx(m)


def test_point_mass_is_on_the_boundary():
    # a point mass is physical but its pseudo-inertia is singular: passes with the default
    # relative tolerance, fails the strict test tol=0 only through rounding, never by much
    pi, f = BODIES["point mass"]
    report = check(torch.tensor(pi + f, dtype=torch.float64), LAYOUT1)
    assert report.ok
    assert abs(float(report.pseudo_inertia_min_eig[0])) < 1e-12
    np.testing.assert_allclose(report.principal_moments[0].numpy(), 0.0, atol=1e-12)


def test_several_bodies_and_table():
    layout = ParameterLayout(("shoulder", "elbow", "wrist"), ("viscous", "coulomb", "offset"))
    names = ["box corners", "negative mass", "violates triangle only"]
    theta = torch.tensor(
        [v for n in names for v in BODIES[n][0] + [0.1, 0.2, -5.0]], dtype=torch.float64
    )
    report = check(theta, layout)
    assert report.body_ok.tolist() == [True, False, False]
    assert report.body_weakly_ok.tolist() == [True, False, True]
    assert report.friction_ok.all()  # a negative offset is allowed
    text = str(report)
    for name in layout.joint_names:
        assert name in text
    assert "no (m" in text and "physically consistent: no" in text


def test_bad_input():
    with pytest.raises(ValueError, match="shape"):
        check(torch.zeros(5), LAYOUT1)
    with pytest.raises(ValueError, match="tol"):
        check(torch.zeros(11), LAYOUT1, tol=-1.0)
    with pytest.raises(TypeError, match="ParameterLayout"):
        check(torch.zeros(11), object())


@pytest.mark.parametrize("m", VANISHING_MASSES)
def test_vanishing_mass_with_a_first_moment_gets_a_verdict(m):
    # h / m overflows (1e180 m and more): the check works with m I_c = m I_o - (|h|^2 - h h^T)
    layout = make_layout(3)
    theta = vanishing_mass_theta(layout, m, torch.Generator().manual_seed(0))
    report = check(theta, layout)
    assert report.body_ok.tolist() == [True, False, True]
    assert not bool(report.inertia_ok[1]) and not bool(report.pseudo_inertia_ok[1])
    assert bool(torch.isfinite(report.pseudo_inertia_min_eig).all())
    if m > 0:
        # I_c = I_o - (|h|^2 1 - h h^T) / m: principal moments -|h|^2 / m (twice) and ~0,
        # |h|^2 = 0.14, finite however large
        expected = -0.14 / m
        torch.testing.assert_close(
            report.principal_moments[1, :2],
            torch.tensor([expected, expected], dtype=torch.float64),
            rtol=1e-6,
            atol=0,
        )
    else:
        assert bool(torch.isnan(report.principal_moments[1]).all())  # no centre of mass
    assert "physically consistent: no (1 of 3 bodies fail" in str(report)


def test_huge_bodies_are_checked_like_their_scaled_copies():
    layout = make_layout(3)
    theta = vanishing_mass_theta(layout, 1.0, torch.Generator().manual_seed(1))
    ref = check(theta, layout)
    for s in (1e-300, 1e300):
        report = check(s * theta, layout)
        assert report.body_ok.tolist() == ref.body_ok.tolist()
        torch.testing.assert_close(report.pseudo_inertia_min_eig / s, ref.pseudo_inertia_min_eig)

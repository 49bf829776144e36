"""A description is checked before it is used: numbers that are not finite are refused in one
line, and bodies whose own inertials are not physically consistent (a mass that is not
positive, an inertia that is not, a broken triangle inequality) are named and not used as the
projection's prior."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import pytest

from torchjfa.dynamics import RigidBodyModel
from torchjfa.identification import (
    IdentificationWarning,
    Options,
    description_problems,
    identify,
)
from torchjfa.robots import path as robot_path

_LINK = """
  <link name="l{k}">
    <inertial>
      <origin xyz="0 0 0.1"/>
      <mass value="{mass}"/>
      <inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/>
    </inertial>
  </link>
  <joint name="j{k}" type="revolute">
    <parent link="l{parent}"/><child link="l{k}"/>
    <origin xyz="0 0 0.2"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="10" velocity="2"/>
  </joint>"""


def _chain(*bodies: tuple) -> str:
    """A URDF chain: a base link, then one link per ``(mass, ixx, iyy, izz)`` (kg, kg m^2)."""
    links = "".join(
        _LINK.format(k=k + 1, parent=k, mass=m, ixx=a, iyy=b, izz=c)
        for k, (m, a, b, c) in enumerate(bodies)
    )
    return f'<robot name="chain"><link name="l0"/>{links}\n</robot>'


def test_each_inconsistent_body_is_named_with_what_breaks(tmp_path):
    path = tmp_path / "chain.urdf"
    path.write_text(
        _chain(
            (1.0, 0.01, 0.01, 0.01),  # consistent
            (0.0, 0.01, 0.01, 0.01),  # no mass
            (1.0, -0.01, 0.02, 0.02),  # a negative principal moment
            (1.0, 0.01, 0.01, 0.05),  # 0.01 + 0.01 < 0.05
        )
    )
    problems = description_problems(RigidBodyModel.from_urdf(str(path)))
    assert len(problems) == 3
    assert problems[0].startswith("l2 (joint j2): mass 0 kg")
    assert problems[1].startswith("l3 (joint j3): principal moments -0.01, 0.02, 0.02 kg m^2")
    assert problems[2] == (
        "l4 (joint j4): principal moments 0.01, 0.01, 0.05 kg m^2 break the triangle inequality"
    )
    path.write_text(_chain((1.0, 0.01, 0.01, 0.01), (2.0, 0.02, 0.03, 0.04)))
    assert description_problems(RigidBodyModel.from_urdf(str(path))) == []
    path.write_text(_chain(*[(0.0, 0.0, 0.0, 0.0)] * 3))  # a description of kinematics only
    assert description_problems(RigidBodyModel.from_urdf(str(path))) == [
        "every body: mass 0 kg or less (no inertials given)"
    ]


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_a_number_that_is_not_finite_is_refused_in_one_line(tmp_path, value, capsys):
    from torchjfa.cli import main

    path = tmp_path / "chain.urdf"
    text = _chain((1.0, 0.01, 0.01, 0.01))
    path.write_text(text.replace('mass value="1.0"', f'mass value="{value}"'))
    with pytest.raises(ValueError, match=f"mass='{value}' is not a finite number"):
        RigidBodyModel.from_urdf(str(path))
    assert main(["excite", str(path), "--out", str(tmp_path / "traj")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a finite number" in err and "l1" in err


@pytest.fixture(scope="module")
def broken_panda(tmp_path_factory):
    """panda_arm's URDF with link 1's ixx raised to 5 kg m^2 (its principal moments then break
    the triangle inequality), and a short simulated log of the true panda_arm."""
    from torchjfa.cli import main

    folder = tmp_path_factory.mktemp("broken")
    text = Path(robot_path("panda_arm")).read_text()
    link = re.search(r'<link name="panda_link1".*?</link>', text, re.S).group(0)
    first = re.search(r"<inertia [^>]*>", link).group(0)
    urdf = folder / "broken.urdf"
    urdf.write_text(text.replace(first, re.sub(r'ixx="[^"]+"', 'ixx="5.0"', first)))
    log = folder / "log.csv"
    assert main(["simulate", "panda_arm", "--out", str(log), "--n-samples", "3000", "--quiet"]) == 0
    return urdf, log


def _run(urdf, log, **options):
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", IdentificationWarning)
        ident = identify(str(urdf), str(log), Options(cutoff=20.0, bias_correction=0, **options))
    return ident, [str(w.message) for w in seen]


def test_an_inconsistent_description_is_no_prior_unless_a_weight_is_given(broken_panda):
    ident, seen = _run(*broken_panda)
    assert ident.result.prior_weight is None  # "auto": no prior
    (line,) = [w for w in ident.warnings if "not physically consistent" in w]
    assert "panda_link1 (joint panda_joint1)" in line and "triangle inequality" in line
    assert "--description-prior W" in line and line in seen
    ident, _ = _run(*broken_panda, description_prior=10.0)
    assert ident.result.prior_weight == 10.0
    (line,) = [w for w in ident.warnings if "not physically consistent" in w]
    assert "with the weight 10.0 given" in line


def test_a_logged_joint_the_robot_lacks_is_named_before_its_missing_columns(tmp_path):
    """A joint the description does not have, logged without velocities beside joints with
    them: the stranger is named, not its missing velocity column alone."""
    import numpy as np

    import torchjfa.robots
    from torchjfa.data import LogError
    from torchjfa.identification import read

    model = RigidBodyModel.from_urdf(torchjfa.robots.path("panda_arm"))
    t = np.arange(0.0, 2.0, 0.01)
    cols = {"t": t}
    for k, j in enumerate(model.joint_names):
        cols[f"q_{j}"], cols[f"qd_{j}"], cols[f"tau_{j}"] = np.sin(t * k), t, t
    cols["q_gripper"] = cols["tau_gripper"] = t
    path = tmp_path / "log.csv"
    np.savetxt(path, np.column_stack(list(cols.values())), delimiter=",",
               header=",".join(cols), comments="")  # fmt: skip
    with pytest.raises(LogError, match=r"joint\(s\) \['gripper'\] are in the log but the robot"):
        read(path, model)

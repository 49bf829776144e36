"""Small robot descriptions shared by tests in several folders."""

# a planar 2R arm in the vertical x-z plane (axes along y, gravity along -z), l1 = 0.4 m
TWO_LINK = """<?xml version="1.0"?>
<robot name="two_link">
  <link name="base"/>
  <link name="l1"><inertial><origin xyz="0.2 0 0"/><mass value="1.0"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.02"/></inertial></link>
  <link name="l2"><inertial><origin xyz="0.15 0.01 0"/><mass value="0.5"/>
    <inertia ixx="0.004" ixy="0" ixz="0" iyy="0.006" iyz="0" izz="0.005"/></inertial></link>
  <joint name="j1" type="continuous"><parent link="base"/><child link="l1"/>
    <axis xyz="0 1 0"/></joint>
  <joint name="j2" type="continuous"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.4 0 0"/><axis xyz="0 1 0"/></joint>
</robot>
"""


# example-robot-data's Go2: its feet and a standing pose (thighs 0.8 rad, calves -1.5 rad)
GO2_FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
GO2_STANCE = {f"{leg}_{j}_joint": v for leg in ("FL", "FR", "RL", "RR") for j, v in
              (("thigh", 0.8), ("calf", -1.5))}  # fmt: skip


def erd_path(relative: str) -> str:
    """A robot file of the installed example-robot-data; the test is skipped without it."""
    import importlib.metadata

    import pytest

    import torchjfa.robots

    try:
        importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    try:
        return torchjfa.robots.example_robot_data_path(relative)
    except FileNotFoundError:
        pytest.skip(f"this example-robot-data has no {relative}")

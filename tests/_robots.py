"""Small robot descriptions shared by tests in several folders."""

import numpy as np

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


class PinocchioFreeFlyer:
    """Pinocchio's free-flyer model of a URDF, with our joint order mapped onto its own."""

    def __init__(self, pin, path: str, model):
        self.pin = pin
        self.pm = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer())
        self.pd = self.pm.createData()
        assert sorted(list(self.pm.names)[2:]) == sorted(model.joint_names)
        self.ids = [self.pm.getJointId(n) for n in model.joint_names]
        joints = [self.pm.joints[j] for j in self.ids]
        assert all(j.nq == 1 and j.nv == 1 for j in joints)
        self.iq = np.array([*range(7), *(j.idx_q for j in joints)])
        self.iv = np.array([*range(6), *(j.idx_v for j in joints)])
        # theta columns: the free flyer's body (joint 1), then each joint's body in our order
        self.cols = np.array(
            [*range(10), *(c for j in self.ids for c in range(10 * (j - 1), 10 * j))]
        )

    def state(self, q, v, a):
        qp, vp, ap = np.zeros(self.pm.nq), np.zeros(self.pm.nv), np.zeros(self.pm.nv)
        qp[self.iq], vp[self.iv], ap[self.iv] = q, v, a
        return qp, vp, ap

    def regressor(self, q, v, a) -> np.ndarray:
        Y = self.pin.computeJointTorqueRegressor(self.pm, self.pd, *self.state(q, v, a))
        return Y[np.ix_(self.iv, self.cols)]

    def rnea(self, q, v, a) -> np.ndarray:
        return self.pin.rnea(self.pm, self.pd, *self.state(q, v, a))[self.iv]

    def crba(self, q) -> np.ndarray:
        M = self.pin.crba(self.pm, self.pd, self.state(q, 0 * q[:-1], 0 * q[:-1])[0])
        M = np.triu(M) + np.triu(M, 1).T
        return M[np.ix_(self.iv, self.iv)]

    def theta(self) -> np.ndarray:
        inertias = self.pm.inertias
        return np.concatenate(
            [inertias[j].toDynamicParameters() for j in range(1, self.pm.njoints)]
        )

    def frame_jacobians(self, q, frames) -> list[np.ndarray]:
        """Each frame's ``LOCAL_WORLD_ALIGNED`` Jacobian, ``(6, 6 + n)`` in our order, at q."""
        pin, pm, pd = self.pin, self.pm, self.pd
        qp = self.state(q, np.zeros(len(q) - 1), np.zeros(len(q) - 1))[0]
        pin.computeJointJacobians(pm, pd, qp)
        pin.updateFramePlacements(pm, pd)
        return [
            pin.getFrameJacobian(pm, pd, pm.getFrameId(f), pin.LOCAL_WORLD_ALIGNED)[:, self.iv]
            for f in frames
        ]

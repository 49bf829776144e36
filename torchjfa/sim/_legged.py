"""A legged robot standing on the ground and moving its body, simulated in MuJoCo.

`simulate_legged` compiles a floating-base URDF (example-robot-data's quadrupeds and humanoids,
or your own) with a free joint on its root link, a sphere at each foot frame and a floor, and
holds a standing pose with joint PD control while every joint follows a slow sum of sines
around it; the feet stay on the ground (mostly) while the body sways. With ``step``, a
quadruped also steps in place: each foot in turn leaves the ground while the body leans away
from it. It records what a
legged robot's log holds, in the floating-base state convention of
`torchjfa.dynamics.FloatingBaseModel`: the base pose and twist, joint positions, velocities
and torques, which feet touch the ground, and the wrench each foot receives from it
(``mj_contactForce``, in world axes, the moment taken about the foot frame's origin). The
simulated robot can differ from the description (``perturb``), so that identification has
something to find; `SimulatedLeggedLog.theta` is its true parameter vector.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np

from .._util import progress_bar
from ..data import LeggedLog
from ..dynamics import FloatingBaseModel
from ..dynamics._mjcf import strip_urdf_for_mujoco
from ..dynamics._tree import quat_matrix, transform_inertial_np

__all__ = ["LEGGED_NOISE", "SimulatedLeggedLog", "simulate_legged"]

#: the sensor noise of `SimulatedLeggedLog.noisy` at scale 1, standard deviations: base position
#: (m), each base quaternion component, joint positions (rad), joint torques (N m), contact
#: forces (N) and moments (N m), and an IMU's gyroscope (rad/s) and accelerometer (m/s^2)
LEGGED_NOISE = {
    "base_position": 1e-3,
    "base_quaternion": 2e-3,
    "joint_position": 2e-4,
    "joint_torque": 0.2,
    "force": 1.0,
    "moment": 0.02,
    "gyro": 5e-3,
    "accelerometer": 0.05,
}

#: the joints' sway about the stance, rad (`simulate_legged`'s default amplitude), and with
#: stepping
SWAY, STEP_SWAY = 0.15, 0.05
_TIMESTEP = 0.001  # s
_KP, _KD = 100.0, 3.0  # N m/rad, N m s/rad: stiff enough to stand, soft enough to sway
_RAMP = 2.0  # s over which the motion grows from the standing pose
_SETTLE = 2.5  # s simulated before recording


@dataclass
class SimulatedLeggedLog(LeggedLog):
    """A `torchjfa.data.LeggedLog` from `simulate_legged`, with ``a`` (the simulator's
    accelerations) and the simulated robot's truth.

    Attributes:
        theta: the simulated robot's parameters in `torchjfa.dynamics.FloatingBaseModel`'s
            layout without joint terms.
    """

    theta: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def noisy(self, scale: float = 1.0, seed: int = 0) -> LeggedLog:
        """The log as sensors would give it: Gaussian noise of `LEGGED_NOISE` times ``scale``
        on the base pose (the quaternion normalised again), the joint positions, the joint
        torques, the contact wrenches and the IMU's readings; no velocities or accelerations
        (`torchjfa.data.prepare_legged` differentiates the pose, or reads the IMU), no truth.

        Raises:
            ValueError: on a negative or non-finite ``scale``.
        """
        if not 0 <= scale < float("inf"):
            raise ValueError(f"the noise scale must be finite and >= 0, got {scale}")
        rng, sd = np.random.default_rng(seed), {k: scale * v for k, v in LEGGED_NOISE.items()}
        T = len(self.t)
        q = self.q.copy()
        q[:, :3] += rng.normal(scale=sd["base_position"], size=(T, 3))
        quat = q[:, 3:7] + rng.normal(scale=sd["base_quaternion"], size=(T, 4))
        q[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        q[:, 7:] += rng.normal(scale=sd["joint_position"], size=q[:, 7:].shape)
        tau = self.tau + rng.normal(scale=sd["joint_torque"], size=self.tau.shape)
        w_sd = np.array([sd["force"]] * 3 + [sd["moment"]] * 3)
        wrench = {k: w + w_sd * rng.normal(size=w.shape) for k, w in self.wrench.items()}
        imu_sd = {"w": sd["gyro"], "a": sd["accelerometer"]}
        imu = {k: x + rng.normal(scale=imu_sd[k], size=x.shape) for k, x in self.imu.items()}
        return LeggedLog(self.t.copy(), q, None, None, tau, dict(self.contact), wrench,
                         self.joint_names, dict(self.info), imu)  # fmt: skip


def _spec(path: str, feet: Sequence[str], radius: float, size=None) -> mujoco.MjSpec:
    root = strip_urdf_for_mujoco(
        ET.parse(path).getroot(), fusestatic="false", balanceinertia="false"
    )
    spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
    base = spec.worldbody.first_body()
    base.add_freejoint(name="torchjfa_base")
    bodies = {b.name: b for b in spec.bodies}
    missing = [f for f in feet if f not in bodies]
    if missing:
        raise ValueError(f"no link named {missing} in {path!r} (the feet must be links)")
    corners = [(0.0, 0.0)] if size is None else [
        (sx * size[0] / 2, sy * size[1] / 2) for sx in (-1, 1) for sy in (-1, 1)
    ]  # fmt: skip
    for foot in feet:
        for x, y in corners:
            bodies[foot].add_geom(
                type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0], pos=[x, y, 0.0], mass=0.0
            )
    spec.worldbody.add_geom(
        name="torchjfa_floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[10, 10, 0.1]
    )
    for joint in spec.joints:
        if joint.type == mujoco.mjtJoint.mjJNT_HINGE or joint.type == mujoco.mjtJoint.mjJNT_SLIDE:
            motor = spec.add_actuator()
            motor.name = f"torchjfa_motor_{joint.name}"
            motor.target = joint.name
            motor.trntype = mujoco.mjtTrn.mjTRN_JOINT
    spec.option.timestep = _TIMESTEP
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    # the contact forces solved to round-off, so that the log's equations of motion hold to
    # about 1e-9 of its forces (MuJoCo's default tolerance leaves about 1e-5)
    spec.option.tolerance = 1e-14
    spec.option.iterations = 200
    return spec


def _perturb(spec: mujoco.MjSpec, scale: float, rng: np.random.Generator) -> mujoco.MjModel:
    """Compile ``spec`` with each body's mass and principal inertias scaled by ``1 + scale *
    U(-1, 1)`` and its centre of mass shifted by ``scale * 5 cm * N(0, 1)`` per axis (a
    physical body stays physical). The new inertials go into the spec and it is compiled
    again, so that MuJoCo's compile-time flags (an inertial frame equal to the body frame)
    follow them."""
    mj = spec.compile()
    for b in range(1, mj.nbody):
        if mj.body_mass[b] <= 0:
            continue
        body = spec.body(mj.body(b).name)
        body.mass = float(mj.body_mass[b]) * (1.0 + scale * rng.uniform(-1, 1))
        body.inertia = np.array(mj.body_inertia[b]) * (1.0 + scale * rng.uniform(-1, 1))
        body.iquat = np.array(mj.body_iquat[b])
        body.fullinertia = np.full(6, np.nan)
        body.ipos = np.array(mj.body_ipos[b]) + scale * 0.05 * rng.normal(size=3)
        body.explicitinertial = True
    return spec.compile()


def _theta(mj: mujoco.MjModel, model: FloatingBaseModel) -> np.ndarray:
    """The simulated robot's parameters in the model's layout: each body's inertial about its
    frame, summed into the moving body (or the base) that carries it."""
    tree = model.joints._tree
    owner = dict(zip(tree.frame_names, tree.frame_owner, strict=True))
    where = dict(zip(tree.frame_names, range(len(tree.frame_names)), strict=True))
    base = np.zeros(10)
    bodies = np.zeros((model.n_dof, 10))
    for b in range(1, mj.nbody):
        name = mj.body(b).name
        if name not in owner:
            continue
        m, c = float(mj.body_mass[b]), np.array(mj.body_ipos[b])
        R = quat_matrix(mj.body_iquat[b])
        Ic = R @ np.diag(mj.body_inertia[b]) @ R.T
        own = np.array([m, 0, 0, 0, Ic[0, 0], Ic[0, 1], Ic[1, 1], Ic[0, 2], Ic[1, 2], Ic[2, 2]])
        pi = transform_inertial_np(own, np.eye(3), c)  # about the body frame's origin
        f = where[name]
        pi = transform_inertial_np(pi, tree.frame_rot[f], tree.frame_pos[f])
        if owner[name] < 0:
            base += pi
        else:
            bodies[owner[name]] += pi
    return np.concatenate([base, bodies.reshape(-1)])


def _foot_wrenches(
    mj: mujoco.MjModel, data: mujoco.MjData, foot_body: Mapping[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Which feet touch, ``(n_feet,)``, and the ground's wrench on each, ``(n_feet, 6)``: force
    and moment about the foot body's origin, world axes."""
    on, wrench = np.zeros(len(foot_body)), np.zeros((len(foot_body), 6))
    f6 = np.zeros(6)
    for c in range(data.ncon):
        con = data.contact[c]
        for gid, sign in ((con.geom1, -1.0), (con.geom2, 1.0)):
            k = foot_body.get(int(mj.geom_bodyid[gid]))
            if k is None:
                continue
            mujoco.mj_contactForce(mj, data, c, f6)
            f = sign * (con.frame.reshape(3, 3).T @ f6[:3])  # MuJoCo's: on geom2 from geom1
            lever = con.pos - data.xpos[mj.geom_bodyid[gid]]
            wrench[k, :3] += f
            wrench[k, 3:] += np.cross(lever, f)
            on[k] = 1.0
    return on, wrench


def _gains(model: FloatingBaseModel, q0: np.ndarray, gains) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's PD gains: ``gains``, capped at ``I / dt^2`` and ``I / dt`` with
    ``I`` the joint's effective inertia at the stance with every other joint and the base
    free, ``1 / (M^-1)_jj`` of the description's mass matrix (the semi-implicit Euler step
    is stable below ``4 I / dt^2`` and ``2 I / dt``: room for a perturbed
    body)."""
    kp, kd = (float(g) for g in gains)
    if not (kp > 0 and kd >= 0):
        raise ValueError(f"gains must be kp > 0 and kd >= 0, got {gains}")
    q = np.concatenate([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], q0])
    inertia = 1.0 / np.diag(np.linalg.inv(model.mass_matrix(q).numpy()))[6:]
    return np.minimum(kp, inertia / _TIMESTEP**2), np.minimum(kd, inertia / _TIMESTEP)


def simulate_legged(
    robot: str | os.PathLike,
    feet: Sequence[str],
    stance: Mapping[str, float],
    *,
    seconds: float = 20.0,
    rate: float = 200.0,
    amplitude: float | Mapping[str, float] | None = None,
    foot_radius: float = 0.02,
    foot_size: tuple[float, float] | None = None,
    gains: tuple[float, float] = (_KP, _KD),
    perturb: float = 0.0,
    truth_seed: int = 0,
    seed: int = 0,
    imu: str | None = None,
    step: float = 0.0,
    progress: bool = False,
) -> LeggedLog:
    """Simulate a legged robot standing and swaying its body (the module).

    Args:
        robot: a floating-base URDF (its root link is the base).
        feet: the links that touch the ground (a sphere of ``foot_radius`` at each origin,
            or four with ``foot_size``).
        stance: joint -> position (rad) of the standing pose; joints not named stay at 0. The
            base starts level, its height such that the lowest foot touches the ground.
        seconds: recorded time, s (after 2.5 s of settling and growing motion).
        rate: recorded samples per second (the simulation runs at 1 kHz).
        amplitude: each joint's motion about the stance, rad: a sum of two sines with random
            frequencies (0.2-0.8 Hz) and phases; hip joints (named ``*hip*``) move 40 % of it.
            Or joint -> amplitude, rad: the joints not named hold the stance (a humanoid's
            legs, say). Default `SWAY` rad, `STEP_SWAY` with ``step``.
        foot_radius: m.
        foot_size: ``(length, width)``, m, of flat feet: a sphere at each corner of that
            rectangle, centred on the foot frame's origin in its x-y plane (a sole frame), so
            that each foot takes a moment; None: point feet.
        gains: the joints' PD gains, N m/rad and N m s/rad (raise them for a heavy robot);
            each joint's are capped where its inertia at the stance is too small for them to
            stay stable at the simulation's 1 ms step (a wrist's).
        perturb: the simulated robot's bodies differ from the description by this fraction
            (masses and principal inertias scaled by up to ``1 +- perturb``, centres of mass
            moved by ``perturb * 5 cm`` per axis); 0 simulates the description.
        truth_seed: the perturbation's random seed (one robot per seed).
        seed: the motion's random seed.
        imu: a link fixed to the base that carries an IMU: its gyroscope and accelerometer
            (MuJoCo's ``gyro`` and ``accelerometer`` sensors at the link's origin, in its
            axes) are recorded as ``imu`` (`torchjfa.data.IMU_COLUMNS`); None: no IMU.
        step: stepping in place, for a robot on point feet: each foot in turn is lifted by
            this height, m, over a slot of 2 s, while every leg leans the body away from it
            (by 30 % of the foot's horizontal distance from the feet's centre), from the
            feet's position Jacobians at the stance; 0: every foot stays down. A foot in the
            air is what lets contact flags alone determine the total mass.
        progress: show a progress bar.

    Returns:
        A `SimulatedLeggedLog`.

    Raises:
        ValueError: on unknown feet or joints, non-positive times or rates, or a robot that
            falls (its base below the feet's height).
    """
    if not seconds > 0 or not rate > 0 or rate > 1.0 / _TIMESTEP:
        raise ValueError(f"seconds must be > 0 and rate in (0, 1000] Hz, got {seconds}, {rate}")
    if not 0.0 <= float(step) < float("inf"):
        raise ValueError(f"step must be a finite height >= 0 m, got {step}")
    if amplitude is None:
        amplitude = STEP_SWAY if step else SWAY
    path = os.fspath(robot)
    model = FloatingBaseModel.from_urdf(path, friction=())
    unknown = sorted(set(stance) - set(model.joint_names))
    if unknown:
        raise ValueError(f"stance names {unknown}, which are not joints of {path!r}")
    spec = _spec(path, tuple(feet), foot_radius, foot_size)
    if imu is not None:
        _add_imu(spec, model, imu, path)
    mj = (
        _perturb(spec, float(perturb), np.random.default_rng(truth_seed))
        if perturb
        else spec.compile()
    )
    rng = np.random.default_rng(seed)
    data = mujoco.MjData(mj)
    joints = model.joint_names
    qadr = np.array([mj.jnt_qposadr[mj.joint(j).id] for j in joints])
    vadr = np.array([mj.jnt_dofadr[mj.joint(j).id] for j in joints])
    q0 = np.array([float(stance.get(j, 0.0)) for j in joints])
    # the base's height: the lowest foot on the floor
    feet_z = model.joints.forward_kinematics(q0, list(feet))[..., 2, 3].numpy()
    data.qpos[:7] = [0.0, 0.0, foot_radius - float(feet_z.min()), 1.0, 0.0, 0.0, 0.0]
    data.qpos[qadr] = q0
    mujoco.mj_forward(mj, data)
    freq = rng.uniform(0.2, 0.8, size=(len(joints), 2))
    phase = rng.uniform(0.0, 2 * np.pi, size=(len(joints), 2))
    if isinstance(amplitude, Mapping):
        unknown = sorted(set(amplitude) - set(joints))
        if unknown:
            raise ValueError(f"amplitude names {unknown}, which are not joints of {path!r}")
        amp = np.array([float(amplitude.get(j, 0.0)) for j in joints])
    else:
        amp = np.array([amplitude * (0.4 if "hip" in j else 1.0) for j in joints])
    kp, kd = _gains(model, q0, gains)
    lifts = _lifts(model, q0, tuple(feet), float(step))
    foot_body = {mj.body(f).id: k for k, f in enumerate(feet)}
    every = max(1, round(1.0 / (rate * _TIMESTEP)))
    n_steps = round((_SETTLE + seconds) / _TIMESTEP)
    rec: dict[str, list] = {k: [] for k in ("t", "q", "v", "a", "tau", "on", "w", "imu")}
    base_id = mj.body(spec.worldbody.first_body().name).id
    with progress_bar(total=n_steps, desc="simulating", unit="step", enabled=progress) as bar:
        for step in range(n_steps):
            t = step * _TIMESTEP
            ramp = min(1.0, t / _RAMP)
            wave = 0.6 * np.sin(2 * np.pi * freq[:, 0] * t + phase[:, 0]) + 0.4 * np.sin(
                2 * np.pi * freq[:, 1] * t + phase[:, 1]
            )
            target = q0 + ramp * amp * wave + _stepping(lifts, t - _SETTLE)
            data.ctrl[:] = kp * (target - data.qpos[qadr]) - kd * data.qvel[vadr]
            mujoco.mj_step(mj, data)
            bar.update(1)
            if t < _SETTLE or step % every:
                continue
            mujoco.mj_forward(mj, data)  # accelerations and contacts of the recorded state
            rec["t"].append(t - _SETTLE)
            _record(rec, mj, data, base_id, qadr, vadr, foot_body)
            if data.qpos[2] < foot_radius:
                raise ValueError(
                    f"the robot fell at t = {t - _SETTLE:.2f} s (base height {data.qpos[2]:.3f} m): "
                    "lower the amplitude or the step, or check the stance"
                )
    on, wrench, sensed = np.array(rec["on"]), np.array(rec["w"]), np.array(rec["imu"])
    return SimulatedLeggedLog(
        t=np.array(rec["t"]),
        q=np.array(rec["q"]),
        v=np.array(rec["v"]),
        a=np.array(rec["a"]),
        tau=np.array(rec["tau"]),
        contact={foot: on[:, k] for k, foot in enumerate(feet)},
        wrench={foot: wrench[:, k] for k, foot in enumerate(feet)},
        joint_names=joints,
        info={"robot": path, "perturb": float(perturb), "seed": seed, "rate_hz": rate},
        imu={} if imu is None else {"w": sensed[:, :3], "a": sensed[:, 3:6]},
        theta=_theta(mj, model),
    )


#: a stepping cycle: each foot in turn gets a slot of this many seconds: the body leans away
#: from it, the foot lifts and comes down, and the body comes back
_STEP_SLOT = 2.0
#: how far the body leans away from the lifted foot, as a fraction of the foot's distance
#: from the feet's centre
_LEAN = 0.3


def _lifts(model: FloatingBaseModel, q0: np.ndarray, feet: tuple[str, ...], height: float):
    """``(len(feet), 2, n)`` joint offsets: for each foot, the lean of every leg that moves
    the body away from it, and the lift of its own leg by ``height`` m, from the feet's
    position Jacobians at the stance (least-squares inverse kinematics)."""
    if height == 0.0:
        return None
    q = np.concatenate([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], q0])
    J = model.frame_jacobian(q, list(feet)).numpy()[:, :3, 6:]  # (k, 3, n)
    pos = model.joints.forward_kinematics(q0, list(feet))[..., :3, 3].numpy()
    centre = pos.mean(0)
    out = np.zeros((len(feet), 2, model.n_dof))
    for k in range(len(feet)):
        lean = _LEAN * (pos[k] - centre) * np.array([1.0, 1.0, 0.0])
        for j in range(len(feet)):
            # the body away from foot k is every stance foot towards it, relative to the body
            out[k, 0] += np.linalg.pinv(J[j]) @ lean
        out[k, 1] = np.linalg.pinv(J[k]) @ np.array([0.0, 0.0, height])
    return out


def _stepping(lifts, t: float) -> np.ndarray | float:
    """The joint offset of the stepping cycle at time ``t`` (s, from the recording's start;
    none before it): a slot per foot, the lean rising over its first 30 % and falling over its
    last 30 %, the lift a bump over the 40 % between."""
    if lifts is None or t < 0.0:
        return 0.0
    k = int(t // _STEP_SLOT) % len(lifts)
    u = (t % _STEP_SLOT) / _STEP_SLOT
    lean = min(1.0, u / 0.3, (1.0 - u) / 0.3)
    lift = np.sin(np.pi * (u - 0.3) / 0.4) ** 2 if 0.3 <= u <= 0.7 else 0.0
    return lean * lifts[k, 0] + lift * lifts[k, 1]


def _record(rec: dict, mj, data, base_id: int, qadr, vadr, foot_body) -> None:
    """Append the state MuJoCo holds (after ``mj_forward``) to ``rec``: pose, twist and
    accelerations in the floating-base convention, torques, contacts, the IMU's sensors."""
    R = data.xmat[base_id].reshape(3, 3)
    w = data.qvel[3:6].copy()
    v_lin = R.T @ data.qvel[:3]  # MuJoCo's free joint: world-axis linear velocity
    a_lin = R.T @ data.qacc[:3] - np.cross(w, v_lin)
    rec["q"].append(np.concatenate([data.qpos[:3], data.qpos[[4, 5, 6, 3]], data.qpos[qadr]]))
    rec["v"].append(np.concatenate([v_lin, w, data.qvel[vadr]]))
    rec["a"].append(np.concatenate([a_lin, data.qacc[3:6], data.qacc[vadr]]))
    rec["tau"].append(data.qfrc_actuator[vadr].copy())
    on, wrench = _foot_wrenches(mj, data, foot_body)
    rec["on"].append(on)
    rec["w"].append(wrench)
    rec["imu"].append(data.sensordata[:6].copy())


def _add_imu(spec: mujoco.MjSpec, model: FloatingBaseModel, link: str, path: str) -> None:
    """A site at ``link``'s origin with a gyroscope and an accelerometer (sensordata[:6])."""
    model.base_frame(link)  # fixed to the base, or a ValueError naming why not
    bodies = {b.name: b for b in spec.bodies}
    if link not in bodies:
        raise ValueError(f"no link named {link!r} in {path!r} to carry the IMU")
    site = bodies[link].add_site(name="torchjfa_imu")
    for kind in (mujoco.mjtSensor.mjSENS_GYRO, mujoco.mjtSensor.mjSENS_ACCELEROMETER):
        spec.add_sensor(type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=site.name)

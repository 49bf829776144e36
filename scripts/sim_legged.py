"""A simulated Go2 standing and swaying: the library's floating-base fit against least squares.

    python scripts/sim_legged.py             # 60 s of training data
    python scripts/sim_legged.py --smoke     # 8 s, a check
    python scripts/sim_legged.py --write-docs  # and into docs/benchmarks.md

The robot is example-robot-data's Go2 with every body perturbed by up to 20 %
(`torchjfa.sim.simulate_legged`, ``perturb=0.2``): the description is not the truth. Two logs of
the same robot with different motions: one identifies, the other (noise-free) judges. The
training log gets sensor noise (`torchjfa.sim.SimulatedLeggedLog.noisy`: base position 1 mm,
quaternion components 2e-3, joint angles 2e-4 rad, joint torques 0.2 N m, foot forces 1 N and
moments 0.02 N m, IMU gyroscope 5e-3 rad/s and accelerometer 0.05 m/s^2) and no velocities.
Each kind of contact information is fitted twice: with the base's motion differentiated from
the pose, and with it from the IMU on the Go2's ``imu`` link (``--imu-frame imu``); the
reference is prepared the same way.

A third training log has the robot step in place (``step=0.05``: each foot in turn leaves the
ground for a moment, the sway smaller), identified from contact flags alone: with a foot in
the air the weight is no longer left wholly to the unknown contact forces.

Two kinds of contact information, each with two fits:

* forces (the feet's measured wrenches): every row, judged by the held-out joint torques' RMS;
* flags (which foot touches when): the rows with the feet's forces projected out (point
  feet), judged by the held-out projected rows' RMS;
* reference: least squares on Pinocchio's free-flyer regressor and frame Jacobians (an
  independent implementation) from the whole training log prepared at the cut-off torchjfa
  chose, no joint terms, no prior, nothing physically consistent;
* torchjfa: `torchjfa.identification.identify_legged` with its defaults (the cut-off chosen
  on the training part, rows weighted, joint friction terms, the description prior, every
  body consistent), which holds out the last 20 % of the training log for its own report.

Printed per row: the held-out RMS and its ratio to the reference, the total mass's error,
whether every body is physically consistent, and each body's mass error (the base first).
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import replace

import _benchmarks_page as page
import numpy as np
import torch

import torchjfa.robots
from torchjfa.data import edge_seconds, prepare_legged
from torchjfa.dynamics import FloatingBaseModel
from torchjfa.identification import (
    IdentificationWarning,
    Options,
    contact_equations,
    identify_legged,
)
from torchjfa.sim import simulate_legged

FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
STANCE = {f"{leg}_{j}_joint": v for leg in ("FL", "FR", "RL", "RR") for j, v in
          (("thigh", 0.8), ("calf", -1.5))}  # fmt: skip
#: the smoke run's cut-off (its 8 s are too short to choose one)
CUTOFF_HZ = 10.0
#: the stepping log's foot lift, m (`simulate_legged`'s ``step``)
STEP = 0.05


class PinocchioRows:
    """The regression rows from Pinocchio: ``Y`` of its free flyer in our order, and the
    right-hand side from the measured wrenches or the point-foot null-space projector."""

    def __init__(self, path: str, model: FloatingBaseModel):
        import pinocchio as pin

        self.pin = pin
        self.pm = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer())
        self.pd = self.pm.createData()
        ids = [self.pm.getJointId(n) for n in model.joint_names]
        self.iq = np.array([*range(7), *(self.pm.joints[j].idx_q for j in ids)])
        self.iv = np.array([*range(6), *(self.pm.joints[j].idx_v for j in ids)])
        self.cols = np.array([*range(10), *(c for j in ids for c in range(10 * (j - 1), 10 * j))])
        self.feet = [self.pm.getFrameId(f) for f in FEET]

    def rows(self, log, kind: str) -> tuple[np.ndarray, np.ndarray]:
        pin, pm, pd = self.pin, self.pm, self.pd
        A, b = [], []
        for s in range(len(log.t)):
            qp, vp, ap = np.zeros(pm.nq), np.zeros(pm.nv), np.zeros(pm.nv)
            qp[self.iq], vp[self.iv], ap[self.iv] = log.q[s], log.v[s], log.a[s]
            Y = pin.computeJointTorqueRegressor(pm, pd, qp, vp, ap)[np.ix_(self.iv, self.cols)]
            pin.computeJointJacobians(pm, pd, qp)
            pin.updateFramePlacements(pm, pd)
            J = [
                pin.getFrameJacobian(pm, pd, f, pin.LOCAL_WORLD_ALIGNED)[:, self.iv]
                for f in self.feet
            ]
            y = np.concatenate([np.zeros(6), log.tau[s]])
            if kind == "forces":
                y = y + sum(Jk.T @ log.wrench[f][s] for Jk, f in zip(J, FEET, strict=True))
            else:
                on = [Jk[:3] for Jk, f in zip(J, FEET, strict=True) if log.contact[f][s]]
                if on:
                    Ja = np.concatenate(on)
                    P = np.eye(len(y)) - np.linalg.pinv(Ja) @ Ja
                    Y, y = P @ Y, P @ y
            A.append(Y)
            b.append(y)
        return np.concatenate(A), np.concatenate(b)


def judge(model, test, kind: str):
    """``rms(theta)``: the held-out rows' RMS (joint torques with forces, projected rows with
    flags), N m."""
    if kind == "forces":
        Y, y = contact_equations(model, test.q, test.v, test.a, test.tau, wrenches=test.wrench)
        Y, y = Y[:, 6:], y[:, 6:]
    else:
        Y, y = contact_equations(model, test.q, test.v, test.a, test.tau, contacts=test.contact)
    return lambda theta: float((Y @ torch.as_tensor(theta) - y).pow(2).mean().sqrt())


def command(name: str, doc: str, run_, argv=None) -> int:
    """The command line of a legged benchmark ``name`` (its module docstring ``doc``):
    ``--seconds``, ``--smoke`` (8 s) and ``--write-docs``, then ``run_(seconds, smoke)``."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="training log, s")
    parser.add_argument("--smoke", action="store_true", help="8 s of training data, a check")
    page.add_option(parser)
    args = parser.parse_args(argv)
    with page.recording(name, name, args.write_docs, argv, smoke=args.smoke):
        return run_(8.0 if args.smoke else args.seconds, args.smoke)


def main(argv=None) -> int:
    return command("sim_legged", __doc__, run, argv)


def run(seconds: float, smoke: bool) -> int:
    """Simulate, identify and judge (the module); prints the table."""
    path = torchjfa.robots.example_robot_data_path("go2_description/urdf/go2.urdf")
    start = time.perf_counter()
    train = simulate_legged(path, FEET, STANCE, seconds=seconds, perturb=0.2, seed=1, imu="imu")
    test = simulate_legged(path, FEET, STANCE, seconds=5.0, perturb=0.2, seed=2)
    noisy = train.noisy(seed=0)
    steps = simulate_legged(path, FEET, STANCE, seconds=seconds, perturb=0.2, seed=1, step=STEP)
    stepping = steps.noisy(seed=0)
    print(f"simulated in {time.perf_counter() - start:.1f} s: {len(train.t)} training samples, "
          f"{len(test.t)} held out")  # fmt: skip
    truth = train.theta.reshape(-1, 10)[:, 0]
    bare = FloatingBaseModel.from_urdf(path, friction=())
    pinocchio = PinocchioRows(path, bare)
    print(f"{'contact information':20s} {'fit':10s} {'held-out RMS':>13s} {'ratio':>7s} "
          f"{'total mass error':>17s} {'consistent':>11s}")  # fmt: skip
    options = Options(cutoff=CUTOFF_HZ) if smoke else Options()
    imu_pose = bare.base_frame("imu")
    for kind, imu, moves in (("forces", False, noisy), ("flags", False, noisy),
                             ("forces", True, noisy), ("flags", True, noisy),
                             ("flags", False, stepping)):  # fmt: skip
        log = moves if kind == "forces" else replace(moves, wrench={})
        log = log if imu else replace(log, imu={})
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IdentificationWarning)
            ident = identify_legged(path, log, options.replace(imu_frame="imu" if imu else None))
        edge = edge_seconds(ident.cutoff_hz)
        keep = (log.t >= log.t[0] + edge) & (log.t <= log.t[-1] - edge)
        pose = {"imu_pose": imu_pose} if imu else {}
        prepared = prepare_legged(log, cutoff_hz=ident.cutoff_hz, **pose).select(keep)
        label = f"{kind} + IMU" if imu else (f"{kind}, stepping" if moves is stepping else kind)
        A, b = pinocchio.rows(prepared, kind)
        reference = np.linalg.lstsq(A, b, rcond=None)[0]
        base = judge(bare, test, kind)(reference)
        rms = judge(ident.model, test, kind)(ident.theta)
        for name, value, masses, ok in (
            ("reference", base, reference.reshape(-1, 10)[:, 0], "-"),
            ("torchjfa", rms, np.array(list(ident.masses().values())),
             "yes" if ident.consistent else "no"),
        ):  # fmt: skip
            err = 100.0 * (masses.sum() / truth.sum() - 1.0)
            print(f"{label:20s} {name:10s} {value:13.4f} {value / base:7.3f} {err:16.2f}% "
                  f"{ok:>11s}")  # fmt: skip
        links = 100.0 * (np.array(list(ident.masses().values())) / truth - 1.0)
        print(f"{'':20s} torchjfa at {ident.cutoff_hz:g} Hz ({ident.cutoff_how.split(':')[0]}); "
              f"each body's mass error, %: {' '.join(f'{e:+.0f}' for e in links)}")  # fmt: skip
    print(f"description (no fit): forces {judge(bare, test, 'forces')(bare.nominal_theta):.4f}"
          f", flags {judge(bare, test, 'flags')(bare.nominal_theta):.4f} N m RMS")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

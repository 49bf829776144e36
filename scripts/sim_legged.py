"""A simulated Go2 standing and swaying: the library's floating-base fit against least squares.

    python scripts/sim_legged.py             # 60 s of training data
    python scripts/sim_legged.py --smoke     # 8 s, a check

The robot is example-robot-data's Go2 with every body perturbed by up to 20 %
(`torchjfa.sim.simulate_legged`, ``perturb=0.2``): the description is not the truth. Two logs of
the same robot with different motions: one identifies, the other (noise-free) judges. The
training log gets sensor noise (`torchjfa.sim.SimulatedLeggedLog.noisy`: base position 1 mm,
quaternion components 2e-3, joint angles 2e-4 rad, joint torques 0.2 N m, foot forces 1 N and
moments 0.02 N m), then
`torchjfa.data.prepare_legged` differentiates its pose at a 10 Hz cut-off (no velocity is
logged), and its first and last second are dropped.

Two kinds of contact information, each with two fits:

* forces (the feet's measured wrenches): every row, judged by the held-out joint torques' RMS;
* flags (which foot touches when): the rows with the feet's forces projected out (the feet as
  flat contacts: a sphere's centre receives a moment), judged by the held-out projected rows'
  RMS;
* reference: least squares on Pinocchio's free-flyer regressor and frame Jacobians (an
  independent implementation), no prior, nothing physically consistent;
* torchjfa: `contact_moments`, least squares, then `consistent_floating` with the description
  prior of weight 1 (every body consistent, the base included).

Printed per row: the held-out RMS and its ratio to the reference, the total mass's error, and
whether every body is physically consistent.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import torch

import torchjfa.robots
from torchjfa.data import prepare_legged
from torchjfa.dynamics import FloatingBaseModel
from torchjfa.identification import consistent_floating, contact_equations, contact_moments
from torchjfa.sim import simulate_legged

FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
STANCE = {f"{leg}_{j}_joint": v for leg in ("FL", "FR", "RL", "RR") for j, v in
          (("thigh", 0.8), ("calf", -1.5))}  # fmt: skip
CUTOFF_HZ = 10.0
PRIOR_WEIGHT = 1.0


def trimmed(log, seconds: float):
    """The log without its first and last ``seconds`` (the filter's edges)."""
    keep = (log.t >= log.t[0] + seconds) & (log.t <= log.t[-1] - seconds)
    return replace(
        log, t=log.t[keep], q=log.q[keep], v=log.v[keep], a=log.a[keep], tau=log.tau[keep],
        contact={k: c[keep] for k, c in log.contact.items()},
        wrench={k: w[keep] for k, w in log.wrench.items()},
    )  # fmt: skip


class PinocchioRows:
    """The regression rows from Pinocchio: ``Y`` of its free flyer in our order, and the
    right-hand side from the measured wrenches or the flat-foot null-space projector."""

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
                on = [Jk for Jk, f in zip(J, FEET, strict=True) if log.contact[f][s]]
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
        Y, y = contact_equations(model, test.q, test.v, test.a, test.tau, contacts=test.contact,
                                 flat=FEET)  # fmt: skip
    return lambda theta: float((Y @ torch.as_tensor(theta) - y).pow(2).mean().sqrt())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="training log, s")
    parser.add_argument("--smoke", action="store_true", help="8 s of training data, a check")
    args = parser.parse_args(argv)
    seconds = 8.0 if args.smoke else args.seconds
    path = torchjfa.robots.example_robot_data_path("go2_description/urdf/go2.urdf")
    model = FloatingBaseModel.from_urdf(path, friction=())
    start = time.perf_counter()
    train = simulate_legged(path, FEET, STANCE, seconds=seconds + 2.0, perturb=0.2, seed=1)
    test = simulate_legged(path, FEET, STANCE, seconds=5.0, perturb=0.2, seed=2)
    prepared = trimmed(prepare_legged(train.noisy(seed=0), cutoff_hz=CUTOFF_HZ), 1.0)
    print(f"simulated and prepared in {time.perf_counter() - start:.1f} s: "
          f"{len(prepared.t)} training samples, {len(test.t)} held out")  # fmt: skip
    truth = float(train.theta.reshape(-1, 10)[:, 0].sum())
    pinocchio = PinocchioRows(path, model)
    print(f"{'contact information':20s} {'fit':10s} {'held-out RMS':>13s} {'ratio':>7s} "
          f"{'total mass error':>17s} {'consistent':>11s}")  # fmt: skip
    results = {}
    for kind, rows in (("forces", "all"), ("flags", "projected")):
        rms = judge(model, test, kind)
        A, b = pinocchio.rows(prepared, kind)
        reference = np.linalg.lstsq(A, b, rcond=None)[0]
        m = contact_moments(model, prepared, rows=rows, flat=FEET)
        hat = torch.linalg.lstsq(m.xtx, m.xty, driver="gelsd").solution
        theta, _, report = consistent_floating(model, m, hat, prior_weight=PRIOR_WEIGHT)
        base = rms(reference)
        for name, th, ok in (("reference", reference, None),
                             ("torchjfa", theta.numpy(), bool(report.body_ok.all()))):  # fmt: skip
            mass = float(np.asarray(th).reshape(-1, 10)[:, 0].sum())
            err = 100.0 * (mass / truth - 1.0)
            flag = "-" if ok is None else ("yes" if ok else "no")
            print(f"{kind:20s} {name:10s} {rms(th):13.4f} {rms(th) / base:7.3f} "
                  f"{err:16.2f}% {flag:>11s}")  # fmt: skip
            results[(kind, name)] = rms(th) / base
    print(f"description (no fit): forces {judge(model, test, 'forces')(model.nominal_theta):.4f}"
          f", flags {judge(model, test, 'flags')(model.nominal_theta):.4f} N m RMS")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
